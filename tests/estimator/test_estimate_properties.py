"""Estimates are sound (finite, positive, with a reason) on any measurements and any force and width
series: property tests of :func:`~estimator.measure.estimate_grasp`."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from estimator.analytical import METHODS
from estimator.estimate import Estimate
from estimator.features import ContactFeatures
from estimator.measure import estimate_grasp
from estimator.measurements import GraspMeasurements
from estimator.segment import segment_grasp
from teleop.record import FrameStream, GraspRecord, Provenance, Samples
from teleop.settings import SensorSettings, Settings

SENSOR = SensorSettings(finger="left", gel_thickness_m=2e-2)
SETTINGS = Settings()
NU = 0.4


def assert_sound(est):
    assert isinstance(est, Estimate) and est.reason
    values = [v for v in (est.e_pa, *est.interval_pa) if v is not None]
    assert all(math.isfinite(v) and v > 0 for v in values)


def random_measurements(draw_floats):
    tf = np.arange(0, 1, 1 / 80)
    force = np.clip((tf - 0.3) * 40, 0, 20)
    tc = np.arange(0.01, 1, 1 / 30)
    seg = segment_grasp(tf, force, np.arange(0, 1, 0.1), 0.05 - np.arange(0, 1, 0.1) * 0.01, tc,
                        contact_force_n=0.75, n_frames=3)
    k = seg.frame_index.size
    values = np.array(draw_floats(6 * k), dtype=np.float64).reshape(6, k)
    features = ContactFeatures(
        peak_depth_m=values[0], area_m2=values[1], radius_m=values[2], cap_radius_m=values[3],
        curvature_radius_m=values[4], centroid_m=np.zeros((k, 2)), touches_edge=values[5] > 0,
        cap_touches_edge=values[5] > 1,
    )
    return GraspMeasurements(
        finger="left", sensor=SENSOR, segment=seg, finger_stiffness_n_per_m=2e5, object_poisson=NU,
        t_s=seg.frame_t_s, force_n=seg.frame_force_n, width_m=seg.frame_width_m,
        approach_m=np.array(draw_floats(k)), features=features,
    )


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.data(), st.sampled_from(METHODS))
def test_estimate_grasp_is_sound_on_any_measurements(data, method):
    def draw_floats(k):
        return data.draw(st.lists(st.floats(allow_nan=True, allow_infinity=True), min_size=k, max_size=k))

    est = estimate_grasp(random_measurements(draw_floats), method, settings=SETTINGS)
    assert_sound(est)


def tiny_stream(t_s):
    blank = np.zeros((4, 4, 3), dtype=np.uint8)
    return FrameStream.from_frames("left", t_s, [blank] * len(t_s), encoding="png")


@settings(max_examples=60, deadline=None)
@given(
    st.lists(st.floats(-5, 50) | st.just(math.nan), min_size=0, max_size=60),
    st.lists(st.floats(0.0, 0.08) | st.just(math.nan), min_size=0, max_size=12),
    st.floats(0.0, 0.05),
)
def test_estimate_grasp_is_sound_on_any_force_and_width(force, width, jitter):
    tf = np.arange(len(force)) / 80.0
    tw = np.arange(len(width)) / 10.0 + jitter
    record = GraspRecord(sensors=(SENSOR,), frames=(tiny_stream(np.arange(3) / 30.0),),
                         force_n=Samples(tf, np.array(force, dtype=float)),
                         width_m=Samples(tw, np.array(width, dtype=float)), provenance=Provenance("simulated"))
    assert_sound(estimate_grasp(record, "no_tactile", settings=SETTINGS))
