"""Audit of :mod:`teleop.rig.camera_latency`: argument checks, unordered and gapped recordings, the
smallest tap, the search window's both ends, and the correlation reported at the lag found."""

from __future__ import annotations

import numpy as np
import pytest

from teleop.errors import TeleopError
from teleop.rig.camera_latency import image_change, measure_latency


def _tap(t, at_s, height, width_s=0.03):
    return height * np.exp(-0.5 * ((t - at_s) / width_s) ** 2)


def _signals(latency_s, *, duration_s=4.0, tap_n=2.0, change_peak=3.0):
    """(frame times, image change, force times, force) of one noiseless tap at 1.5 s seen ``latency_s`` late."""
    t = np.arange(0.0, duration_s, 0.001)
    return t, 1.0 + _tap(t, 1.5 + latency_s, change_peak), t, _tap(t, 1.5, tap_n)


@pytest.mark.parametrize("step_s", [0.0, -0.001, 0.3])
def test_a_grid_step_that_is_not_between_zero_and_the_window_is_refused_naming_it(step_s):
    with pytest.raises(TeleopError, match=r"step_s = .*expected 0 < step_s < max_lag_s"):
        measure_latency(*_signals(0.03), step_s=step_s)


def test_times_and_values_of_different_lengths_are_refused_naming_the_signal():
    t, change, tf, force = _signals(0.03)
    with pytest.raises(TeleopError, match=r"force: times and values must be 1-D of one length"):
        measure_latency(t, change, tf, force[:-1])
    with pytest.raises(TeleopError, match=r"frames: times and values must be 1-D of one length"):
        measure_latency(t[:, None], change[:, None], tf, force)


def test_samples_with_a_nan_value_or_stamp_are_left_out_not_spread_over_the_fit():
    t, change, tf, force = _signals(0.04)
    force, tf = force.copy(), tf.copy()
    force[100] = np.nan  # a dropped reading, far from the tap
    tf[200] = np.nan
    change = change.copy()
    change[300] = np.nan
    fit = measure_latency(t, change, tf, force)
    assert fit, fit.reason
    assert fit.latency_s == pytest.approx(0.04, abs=2e-4)


def test_samples_out_of_time_order_give_the_same_latency():
    t, change, tf, force = _signals(0.04)
    shuffle = np.random.default_rng(5).permutation(t.size)
    fit = measure_latency(t[shuffle], change[shuffle], tf[shuffle[::-1]], force[shuffle[::-1]])
    assert fit, fit.reason
    assert fit.latency_s == pytest.approx(0.04, abs=2e-4)


def test_a_noiseless_force_bump_below_the_smallest_tap_is_no_tap():
    fit = measure_latency(*_signals(0.03, tap_n=0.1))  # 0.1 N: under the 0.2 N minimum, though noise-free
    assert not fit and fit.reason.startswith("no tap in the force")
    assert fit.force_peak_n == pytest.approx(0.1, abs=1e-3)


def test_a_noiseless_image_change_below_the_smallest_tap_is_no_tap():
    fit = measure_latency(*_signals(0.03, change_peak=0.3))  # 0.3 levels: under the 0.5 minimum
    assert not fit and fit.reason.startswith("no tap in the image")


def test_a_negative_lag_beyond_the_search_window_is_refused_not_clipped():
    fit = measure_latency(*_signals(-0.35))
    assert not fit and "at the search limit" in fit.reason and np.isnan(fit.latency_s)


def test_a_negative_latency_inside_the_window_is_measured():
    fit = measure_latency(*_signals(-0.12))
    assert fit and fit.latency_s == pytest.approx(-0.12, abs=2e-4)


def test_a_stronger_camera_only_bump_outside_the_window_does_not_pull_the_lag_there():
    # The image's biggest event is 0.6 s after the tap: outside the +-0.3 s searched, so the tap at
    # +0.03 s is matched, and its fit refused for the extra bump (not "at the search limit").
    t, change, tf, force = _signals(0.03)
    fit = measure_latency(t, change + _tap(t, 2.1, 6.0), tf, force)
    assert not fit and "does not follow the force" in fit.reason
    assert fit.correlation < 0.7


@pytest.mark.parametrize("latency_s", [0.2, -0.2])
def test_the_correlation_is_the_signals_aligned_at_the_lag_found(latency_s):
    # A narrow tap 0.2 s late: unaligned, the two would hardly correlate.
    fit = measure_latency(*_signals(latency_s))
    assert fit, fit.reason
    assert fit.correlation > 0.99
    assert fit.latency_s == pytest.approx(latency_s, abs=2e-4)


def test_the_correlation_limit_is_the_one_given():
    t, change, tf, force = _signals(0.05)
    change = change + _tap(t, 3.0, 1.2)  # a smaller camera-only bump: the fit is good, not perfect
    correlation = measure_latency(t, change, tf, force, min_correlation=0.0).correlation
    assert 0.75 < correlation < 0.95
    assert measure_latency(t, change, tf, force, min_correlation=correlation - 0.01)
    refused = measure_latency(t, change, tf, force, min_correlation=correlation + 0.01)
    assert not refused and "does not follow the force" in refused.reason


def test_a_frame_of_another_shape_than_the_rest_frame_is_refused_naming_it():
    rest = np.full((4, 4, 3), 100, np.uint8)
    with pytest.raises(TeleopError, match=r"images\[1\] has shape \(4, 4, 1\): expected the reference's \(4, 4, 3\)"):
        image_change([rest, np.full((4, 4, 1), 100, np.uint8)], rest)


def test_an_image_darker_than_the_rest_frame_counts_its_difference_without_wrapping():
    rest = np.full((2, 2, 3), 10, np.uint8)
    assert image_change([np.zeros((2, 2, 3), np.uint8)], rest).tolist() == [10.0]
