"""Hostile series and options for the contact fits, the segmentation, the lags and the line fit:
each is refused with a FitError naming it, and valid inputs of any real dtype or order keep their
results."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from estimator.analytical import approach_per_finger, no_tactile
from estimator.errors import FitError
from estimator.lag import estimate_camera_lag
from estimator.linefit import fit_line
from estimator.load_phase import find_load_phase
from estimator.segment import align_frames, segment_grasp
from estimator.signals import clean_samples

FORCE = np.linspace(0.5, 5.0, 8)
APPROACH = np.linspace(1e-4, 1e-3, 8)


def grasp():
    tf = np.linspace(0, 2, 200)
    tw = np.linspace(0, 2, 60)
    return (tf, np.clip((tf - 0.5) * 5, 0, 4), tw, 0.05 - 0.01 * np.clip(tw - 0.5, 0, 0.8),
            np.linspace(0, 2, 40))


def segment(**options):
    tf, force, tw, width, frames = grasp()
    frames = options.pop("frame_t_s", frames)
    return segment_grasp(tf, force, tw, width, frames, **{"contact_force_n": 0.2, "n_frames": 8, **options})


# ------------------------------------------------------------------ 1. real series only


@pytest.mark.parametrize("values", [
    FORCE + 5j,
    np.array(["x"] * 8, dtype=object),
    np.array(["1"] * 8),
    np.ones(8, dtype=bool),
    [1.0, None, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0],
])
def test_non_real_series_are_refused_by_name(values):
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no ComplexWarning: refused before any cast
        with pytest.raises(FitError, match="no_tactile: force_n must be real numbers"):
            no_tactile(values, APPROACH, initial_width_m=0.05, pad_area_m2=2e-4)
        with pytest.raises(FitError, match="force_n"):
            approach_per_finger(APPROACH, values, onset_width_m=0.05, finger_stiffness_n_per_m=1e4)
        with pytest.raises(FitError, match="value"):
            clean_samples(np.arange(8.0), values)


def test_real_series_of_any_real_dtype_keep_their_results():
    reference = no_tactile(FORCE, APPROACH, initial_width_m=0.05, pad_area_m2=2e-4)
    for force in (list(FORCE), FORCE.astype(np.longdouble)):
        assert no_tactile(force, APPROACH, initial_width_m=0.05, pad_area_m2=2e-4) == reference
    ints = np.arange(8)
    for t in (ints, ints.astype(np.uint8), list(ints)):
        t_s, value = clean_samples(t, ints)
        assert t_s.dtype == value.dtype == np.float64
        assert np.array_equal(t_s, ints.astype(np.float64)) and np.array_equal(value, ints.astype(np.float64))


# ------------------------------------------------------------------ 2. segment_grasp / align_frames


@pytest.mark.parametrize(("options", "named"), [
    ({"frame_t_s": np.linspace(0, 2, 40)[None]}, "frame_t_s"),
    ({"frame_t_s": 1.0}, "frame_t_s"),
    ({"frame_t_s": np.array(["a"] * 40)}, "frame_t_s"),
    ({"n_frames": 2.5}, "n_frames"),
    ({"n_frames": True}, "n_frames"),
    ({"n_frames": 0}, "n_frames"),
    ({"n_frames": 10**12}, "n_frames"),
    ({"n_frames": 10_001}, "n_frames"),
    ({"contact_force_n": "1"}, "contact_force_n"),
    ({"contact_force_n": True}, "contact_force_n"),
    ({"stopped_s": "x"}, "stopped_s"),
    ({"max_force_n": -1.0}, "max_force_n"),
    ({"max_force_n": 0.0}, "max_force_n"),
    ({"max_width_m": float("nan")}, "max_width_m"),
    ({"max_width_m": "0.08"}, "max_width_m"),
])
def test_bad_segmentation_inputs_are_refused_by_name(options, named):
    with pytest.raises(FitError, match=named):
        segment(**options)


def test_align_frames_refuses_bad_frames_even_without_a_phase():
    tf, force, tw, width, frames = grasp()
    phase = find_load_phase(tf, force * 0, tw, width, contact_force_n=0.2)
    assert not phase
    with pytest.raises(FitError, match="frame_t_s"):
        align_frames(phase, frames[None], n_frames=3)
    with pytest.raises(FitError, match="n_frames"):
        align_frames(phase, frames, n_frames=np.float64(3))


def test_valid_segmentation_options_keep_their_results():
    reference = segment(stopped_s=1.3, max_force_n=30.0, max_width_m=0.08)
    assert reference
    same = segment(stopped_s=np.float64(1.3), max_force_n=np.float32(30.0), max_width_m=0.08,
                   n_frames=np.int64(8), frame_t_s=list(grasp()[4]))
    assert np.array_equal(same.frame_index, reference.frame_index)
    assert np.array_equal(same.sample, reference.sample)
    assert same.t_onset_s == reference.t_onset_s
    assert segment(stopped_s=float("nan")).t_onset_s == segment().t_onset_s  # a non-finite stop is no stop


# ------------------------------------------------------------------ 3. fit_line


X = np.linspace(1, 2, 6)


@pytest.mark.parametrize(("args", "systematic", "named"), [
    ((X, 2 * X[:3], np.ones(6)), (), "y"),
    ((X, 2 * X, np.ones(5)), (), "sigma_y"),
    ((X, 2 * X, np.ones(6)), (np.ones(3),), r"systematic_y\[0\]"),
    ((X[None], 2 * X, np.ones(6)), (), "x"),
    ((X, 2 * X + 1j, np.ones(6)), (), "y"),
])
def test_fit_line_refuses_malformed_series_by_name(args, systematic, named):
    with pytest.raises(FitError, match=f"fit_line: {named}"):
        fit_line(*args, through_origin=False, systematic_y=systematic)


def test_fit_line_takes_lists_and_keeps_its_results():
    on_arrays = fit_line(np.array([1.0, 2, 3]), np.array([2.0, 4.1, 6]), np.full(3, 0.1), through_origin=False,
                         systematic_y=(np.full(3, 0.05),))
    on_lists = fit_line([1.0, 2, 3], [2.0, 4.1, 6], [0.1, 0.1, 0.1], through_origin=False,
                        systematic_y=([0.05, 0.05, 0.05],))
    assert on_lists == on_arrays


def test_fit_line_on_unrepresentable_values_is_none_without_warnings():
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert fit_line(X * 1e300, 2 * X * 1e300, np.ones(6), through_origin=False) is None
        assert fit_line(X, 2 * X * 1e300, np.full(6, 1e300), through_origin=True) is None


# ------------------------------------------------------------------ 4. estimate_camera_lag


def camera():
    t = np.linspace(0, 1, 50)
    return t, np.where(t > 0.5, (t - 0.5) * 10, 0) + np.random.default_rng(0).normal(0, 1e-3, 50)


def test_camera_lag_does_not_depend_on_sample_order():
    t, change = camera()
    lag = estimate_camera_lag(t, change, t_onset_s=0.5)
    assert lag is not None
    assert estimate_camera_lag(t[::-1], change[::-1], t_onset_s=0.5) == lag
    order = np.random.default_rng(1).permutation(t.size)
    assert estimate_camera_lag(t[order], change[order], t_onset_s=0.5) == lag


def test_camera_lag_merges_duplicate_frames():
    t, change = camera()
    doubled = estimate_camera_lag(np.repeat(t, 2), np.repeat(change, 2), t_onset_s=0.5)
    assert doubled == estimate_camera_lag(t, change, t_onset_s=0.5)


@pytest.mark.parametrize(("options", "named"), [
    ({"max_lag_s": -1.0}, "max_lag_s"),
    ({"max_lag_s": float("nan")}, "max_lag_s"),
    ({"max_lag_s": 0.0}, "max_lag_s"),
    ({"t_onset_s": "0.5"}, "t_onset_s"),
    ({"t_onset_s": None}, "t_onset_s"),
    ({"t_onset_s": True}, "t_onset_s"),
])
def test_bad_camera_lag_options_are_refused_by_name(options, named):
    t, change = camera()
    with pytest.raises(FitError, match=f"estimate_camera_lag: {named}"):
        estimate_camera_lag(t, change, **{"t_onset_s": 0.5, **options})


def test_camera_lag_refuses_malformed_series_by_name():
    t, change = camera()
    with pytest.raises(FitError, match="frame_t_s and tactile_change must be 1-D"):
        estimate_camera_lag(t, change[:-1], t_onset_s=0.5)
    with pytest.raises(FitError, match="tactile_change must be real"):
        estimate_camera_lag(t, change + 1j, t_onset_s=0.5)
