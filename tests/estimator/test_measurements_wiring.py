"""What the analytical fits are handed from a grasp's measurements: the no-contact reference's frames,
the hold point, the noise of a binned grasp, the onset width guard, each fit's arguments, and how a
calibration made for another sensor is told apart and warned about."""

from __future__ import annotations

import logging
from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest

import estimator.analytical as analytical
import estimator.measurements as measurements
from estimator.errors import CalibrationError
from estimator.estimate import Estimate
from estimator.features import contact_features
from estimator.measurements import (
    REFERENCE_FRAMES,
    GraspMeasurements,
    calibration_sensor_mismatch,
    estimate_measurements,
    reference_indices,
)
from teleop.settings import SensorSettings

PITCH = 1e-3 / 11


def test_the_reference_is_the_last_frames_strictly_before_the_time():
    assert REFERENCE_FRAMES == 5
    t = np.array([0.0, 0.1, np.nan, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8])
    np.testing.assert_array_equal(reference_indices(t, 0.7), [3, 4, 5, 6, 7])  # 0.7 itself is not before
    np.testing.assert_array_equal(reference_indices(t, 0.25), [0, 1, 3])  # the NaN stamp is no frame
    assert reference_indices(t, 0.0).size == 0
    np.testing.assert_array_equal(reference_indices(np.array([-np.inf, 0.1, 0.2]), 0.3), [1, 2])  # nor -inf


def _measurements(**fields) -> GraspMeasurements:
    segment = SimpleNamespace(force_noise_n=0.01, width_noise_m=1e-5, onset_width_sigma_m=1e-4)
    empty = np.zeros(0)
    given = {"t_s": empty, "force_n": empty, "width_m": empty, "approach_m": empty, **fields}
    return GraspMeasurements(finger="left", sensor=SensorSettings(finger="left"), segment=segment,
                             finger_stiffness_n_per_m=1e4, object_poisson=0.4, **given)


def test_the_length_noise_is_the_pitch_of_the_binned_grid():
    sensor = SensorSettings(finger="left")
    assert _measurements().noise.length_m == pytest.approx(sensor.pixel_pitch_m)
    assert _measurements(depth_binning=3).noise.length_m == pytest.approx(3 * sensor.pixel_pitch_m)


def _hold_measurements(width_lag_s):
    depth = np.zeros((3, 20, 30))
    for i, size in enumerate((2, 3, 9)):  # cap areas 4, 9, 81 px: median 9, mean 31
        depth[i, 5:5 + size, 5:5 + size] = 5e-4
    hold = contact_features(depth, pixel_pitch_m=PITCH, contact_threshold_m=1e-4, smooth_px=0.0)
    loading = hold.take(np.array([0]))
    return _measurements(force_n=np.array([1.0]), approach_m=np.array([1e-4]), features=loading,
                         hold_force_n=np.array([5.0, 6.0, 100.0]), hold_approach_m=np.array([1e-3, 2e-3, 9e-3]),
                         hold_features=hold, width_lag_s=width_lag_s)


def test_the_hold_adds_the_median_of_its_frames_once_the_width_lag_is_corrected():
    m = _hold_measurements(width_lag_s=0.02)
    force, approach, f = measurements._with_hold_point(m, m.features)
    np.testing.assert_array_equal(force, [1.0, 6.0])
    np.testing.assert_array_equal(approach, [1e-4, 2e-3])
    assert f.cap_radius_m[1] == pytest.approx(np.sqrt(9 * PITCH**2 / np.pi))
    assert len(f) == 2 and f.touches_edge.dtype == bool


def test_the_hold_is_left_out_while_the_width_lag_is_not_corrected():
    m = _hold_measurements(width_lag_s=None)
    force, approach, f = measurements._with_hold_point(m, m.features)
    np.testing.assert_array_equal(force, [1.0])
    np.testing.assert_array_equal(approach, [1e-4])
    assert len(f) == 1


def test_a_zero_onset_width_refuses_the_fits_normalised_by_it(measured):
    zero = replace(measured, segment=replace(measured.segment, onset_width_m=0.0))
    for method in ("no_tactile", "elastic"):
        e = estimate_measurements(zero, method)
        assert e.state == "insufficient_data" and "no positive width at the contact onset (got 0 m)" in e.reason, method


def _calls(monkeypatch, name):
    calls = []

    def fake(*args, **kwargs):
        calls.append((args, kwargs))
        return Estimate.refuse(name, "recorded")

    monkeypatch.setattr(analytical, name, fake)
    return calls


def test_hertz_reads_the_cap_and_whether_the_cap_is_truncated(measured, monkeypatch):
    calls = _calls(monkeypatch, "hertz")
    f = replace(measured.features, cap_touches_edge=~measured.features.touches_edge)  # told apart
    estimate_measurements(replace(measured, width_lag_s=None, features=f), "hertz")
    (args, kwargs), = calls
    np.testing.assert_array_equal(args[3], f.cap_radius_m)
    np.testing.assert_array_equal(kwargs["truncated"], f.cap_touches_edge)
    np.testing.assert_array_equal(args[2], f.peak_depth_m)


def test_elastic_reads_the_threshold_area_and_whether_it_is_truncated(measured, monkeypatch):
    calls = _calls(monkeypatch, "elastic")
    f = replace(measured.features, cap_touches_edge=~measured.features.touches_edge)
    estimate_measurements(replace(measured, width_lag_s=None, features=f), "elastic")
    (args, kwargs), = calls
    np.testing.assert_array_equal(args[3], f.area_m2)
    np.testing.assert_array_equal(kwargs["truncated"], f.touches_edge)


@pytest.mark.parametrize("onset_width_m", [0.03, float("nan")])
def test_series_reads_the_cap_radius_and_the_force_only_with_an_onset_width(measured, monkeypatch, onset_width_m):
    calls = _calls(monkeypatch, "series")
    m = replace(measured, width_lag_s=None, segment=replace(measured.segment, onset_width_m=onset_width_m))
    estimate_measurements(m, "series")
    (_, kwargs), = calls
    np.testing.assert_array_equal(kwargs["contact_radius_m"], measured.features.cap_radius_m)
    if np.isfinite(onset_width_m):
        assert kwargs["initial_width_m"] == onset_width_m
        np.testing.assert_array_equal(kwargs["force_n"], measured.force_n)
    else:
        assert kwargs["initial_width_m"] is None and kwargs["force_n"] is None


def _calibration(**sensor):
    return SimpleNamespace(provenance={"sensor": sensor})


def test_a_calibration_of_another_finger_model_or_serial_is_told_apart():
    sensor = SensorSettings(finger="left", serial="GS-1")
    assert calibration_sensor_mismatch(_calibration(model=sensor.model, finger="left", serial="GS-1"), sensor) is None
    assert "finger 'right'" in calibration_sensor_mismatch(_calibration(finger="right"), sensor)
    assert "serial 'GS-2'" in calibration_sensor_mismatch(_calibration(serial="GS-2"), sensor)
    assert calibration_sensor_mismatch(_calibration(serial="GS-2"), SensorSettings(finger="left")) is None


def test_a_calibration_of_another_sensor_is_warned_about_once(monkeypatch, caplog):
    monkeypatch.setattr(measurements, "_WARNED", set())
    cal, sensor = _calibration(serial="GS-9"), SensorSettings(finger="left", serial="GS-1")
    with caplog.at_level(logging.WARNING, logger=measurements.__name__):
        for _ in range(3):
            measurements._check_calibration_sensor(cal, sensor)
    assert [r.getMessage().count("GS-9") for r in caplog.records] == [1]


@pytest.mark.parametrize(("ratio", "fits"), [(1.005, True), (1.05, False)])
def test_a_calibration_fits_a_sensor_only_within_one_percent_of_its_pixel_pitch(ratio, fits):
    sensor = SensorSettings(finger="left")
    cal = SimpleNamespace(provenance={}, image_shape=sensor.image_shape, pixel_pitch_m=ratio * sensor.pixel_pitch_m)
    if fits:
        measurements.check_calibration_fits(cal, sensor)
    else:
        with pytest.raises(CalibrationError, match="pixel pitch"):
            measurements.check_calibration_fits(cal, sensor)
