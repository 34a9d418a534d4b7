"""Sensors that cannot be right (estimator.faults): a dead or frozen camera, timestamps not in
seconds, a width that never moves or reads zero, on the grasps test_measure builds and on the
faults' own inputs: sample times, a synthetic grasp's phase, a reference image."""

from __future__ import annotations

import importlib.util
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from estimator.faults import RATE_FACTOR, camera_fault, checked_phase, period_fault
from estimator.load_phase import find_load_phase
from estimator.measure import estimate_grasp, measure_grasp
from teleop.catalogue import load_catalogue
from teleop.record import FrameStream, Samples
from teleop.sim.grasp import simulate_grasp
from teleop.sim.simulate import grasp_rng

_spec = importlib.util.spec_from_file_location("_measure_grasps", Path(__file__).with_name("test_measure.py"))
_grasps = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(_grasps)
build_record, calibration, SETTINGS, STEEL = _grasps.build_record, _grasps.calibration, _grasps.SETTINGS, _grasps.STEEL


def with_streams(record, *, images=None, frame_scale=1.0, time_scale=1.0, width=None):
    """``record`` with its frames replaced (``images``: frame index, frame -> image), frame times
    scaled by ``frame_scale``, every time by ``time_scale``, widths replaced by ``width`` (m)."""
    s = record.frames[0]
    frames = s if images is None else FrameStream.from_frames(
        s.finger, s.t_s, [images(i, s.frame(i)) for i in range(len(s))], encoding="png")
    frames = replace(frames, t_s=frames.t_s * frame_scale * time_scale)
    w = record.width_m
    return replace(record, frames=(frames,), force_n=Samples(record.force_n.t_s * time_scale, record.force_n.value),
                   width_m=Samples(w.t_s * time_scale, w.value if width is None else np.full(len(w), width)))


@pytest.mark.slow
def test_a_dead_or_frozen_camera_refuses_the_tactile_methods_naming_it(calibration):
    record = build_record(3e5)
    contact = measure_grasp(record, settings=SETTINGS, tactile=False).segment.t_contact_s
    first = record.frames[0].frame(0)
    dead = {
        "black": lambda i, image: np.zeros_like(image),
        "saturated": lambda i, image: np.full_like(image, 255),
        "bit-identical to its no-contact reference": lambda i, image: first,
        "loading frame at": lambda i, image: np.zeros_like(image) if record.frames[0].t_s[i] > contact else image,
    }
    for seen, images in dead.items():
        broken = with_streams(record, images=images)
        for method in ("series", "elastic", "hertz"):
            est = estimate_grasp(broken, method, settings=SETTINGS, calibration=calibration)
            assert not est and "camera of finger 'left'" in est.reason and seen in est.reason
        assert estimate_grasp(broken, "no_tactile", settings=SETTINGS)  # force and width still answer
    assert estimate_grasp(with_streams(record, images=lambda i, image: image), "series", settings=SETTINGS,
                          calibration=calibration)  # the same frames, lossless: measured


def test_timestamps_not_in_seconds_are_refused_naming_the_stream(calibration):
    record = build_record(3e5)
    est = estimate_grasp(with_streams(record, time_scale=1e9), "no_tactile", settings=SETTINGS)
    assert not est and "force samples come every 1.25e+07 s" in est.reason and "0.0125 s" in est.reason
    frames_ns = with_streams(record, frame_scale=1e9)
    est = estimate_grasp(frames_ns, "series", settings=SETTINGS, calibration=calibration)
    assert not est and est.reason.startswith("tactile frames of finger 'left' come every 3.33e+07 s")
    assert estimate_grasp(frames_ns, "no_tactile", settings=SETTINGS)
    assert estimate_grasp(with_streams(record, time_scale=10.0), "no_tactile", settings=SETTINGS)  # slow, not absurd


def test_a_width_that_never_moves_or_reads_zero_refuses_the_grasp(calibration):
    record = build_record(3e5)
    stuck = with_streams(record, width=record.width_m.value[0])
    for method in ("no_tactile", "series"):
        est = estimate_grasp(stuck, method, settings=SETTINGS, calibration=calibration)
        assert not est and "gripper widths stay within 0 mm of 49.87 mm over the whole record" in est.reason
        est = estimate_grasp(with_streams(record, width=0.0), method, settings=SETTINGS, calibration=calibration)
        assert not est and "gripper width 0 m at the contact onset" in est.reason
    # A rigid object stops the fingers at contact, but they closed onto it first.
    assert estimate_grasp(build_record(STEEL), "no_tactile", settings=SETTINGS)


def test_an_operators_moving_fingers_are_not_a_stuck_width_sensor(object_table):
    # The operator closes 7 mm onto a 75 mm cylinder; its moving fingers inflate the width noise
    # estimate to over a millimetre, which once made the widths look still.
    obj = next(o for o in load_catalogue(object_table) if o.name == "aluminum_cylinder_wide")
    record, _ = simulate_grasp(obj, settings=SETTINGS, rng=grasp_rng(6, obj, 1), seed=6, operator="sim")
    est = estimate_grasp(record, "no_tactile", settings=SETTINGS)
    assert "stay within" not in est.reason, est.reason


def test_widths_that_open_while_the_force_rises_are_refused_not_a_bound(calibration):
    record = build_record(3e5)
    w = record.width_m
    mirrored = replace(record, width_m=Samples(w.t_s, 2 * w.value[0] - w.value))  # the fingers open as they squeeze
    for method in ("no_tactile", "series"):  # no_tactile read them as a lower bound far above the truth
        est = estimate_grasp(mirrored, method, settings=SETTINGS, calibration=calibration)
        assert not est and "the widths open by" in est.reason and "do not follow the grasp" in est.reason
        assert "stiffer than resolved" not in est.reason
    assert estimate_grasp(record, "no_tactile", settings=SETTINGS).state == "ok"
    assert estimate_grasp(build_record(STEEL), "no_tactile", settings=SETTINGS)  # a stiff object still answers


def test_a_load_cell_with_its_sign_reversed_is_named_not_read_as_no_contact(calibration):
    record = build_record(3e5)
    f = record.force_n
    reversed_sign = replace(record, force_n=Samples(f.t_s, -f.value))
    for method in ("no_tactile", "series"):
        est = estimate_grasp(reversed_sign, method, settings=SETTINGS, calibration=calibration)
        assert not est and "is the load cell's sign reversed?" in est.reason and "no contact" not in est.reason
        assert "never rises by contact_force_n = 0.75 N" in est.reason
    # A grasp of air stays one: its force stays in its noise on both sides.
    air = replace(record, force_n=Samples(f.t_s, f.value * 0.01))
    est = estimate_grasp(air, "no_tactile", settings=SETTINGS)
    assert not est and est.reason.startswith("no contact") and "sign" not in est.reason
    # A cell offset at rest (untared) whose squeeze stays below contact is no reversed one.
    offset = replace(record, force_n=Samples(f.t_s, f.value * 0.01 - 2.0))
    est = estimate_grasp(offset, "no_tactile", settings=SETTINGS)
    assert not est and "sign" not in est.reason
    # Nor is a record that starts in contact, its first samples at the squeeze's force.
    from estimator.plausible import reversed_force

    squeezed = np.argmax(f.value >= 0.98 * f.value.max())  # the record starts at the hold
    released = np.concatenate([f.value[squeezed:], np.linspace(f.value[-1], 0.0, 20)])  # and let go
    assert not reversed_force(released, contact_force_n=0.75)


def test_samples_far_faster_than_the_rig_rate_are_not_seconds():
    t = np.arange(300) * (1 / 100.0) / (10 * RATE_FACTOR)  # far too close for 100 Hz
    assert "not in seconds" in period_fault(t, 100.0, "force samples")
    assert period_fault(np.arange(300) / 100.0, 100.0, "force samples") == ""


def test_two_times_say_nothing_about_the_rate():
    assert period_fault(np.array([0.0, 5.0, 5.0, np.nan]), 100.0, "force samples") == ""


def checked_grasp(width_closes_m, *, start_s=0.0):
    """The checked phase of a grasp rising 0 to 15 N over 1-2.5 s while the widths close ``width_closes_m``,
    its records starting at ``start_s``."""
    t = np.arange(start_s, 3.5, 0.01)
    force = np.interp(t, [0, 1, 2.5, 3.5], [0, 0, 15, 15])
    tw = np.arange(start_s, 3.5, 0.02)
    width = 0.05 - np.interp(tw, [0, 1, 2.5, 3.5], [0, 0, width_closes_m, width_closes_m])
    phase = find_load_phase(t, force, tw, width, contact_force_n=0.75)
    return checked_phase(phase, force_t_s=t, width_t_s=tw, force_hz=100.0, width_hz=50.0)


def test_widths_that_close_half_a_millimetre_are_a_gripper_that_moved():
    assert checked_grasp(0.5e-3)
    still = checked_grasp(0.05e-3)
    assert not still and "stay within" in still.reason


def test_still_widths_of_a_record_that_starts_in_contact_are_not_judged():
    phase = checked_grasp(0.0, start_s=1.5)  # the force record starts at 5 N: no quiet samples before the onset
    assert phase, phase.reason


def test_a_reference_without_cell_structure_is_not_correlated():
    # A fine checkerboard: texture on every pixel, but every 8 px cell has the same mean.
    board = ((np.indices((64, 96)).sum(axis=0) % 2) * 100 + 60).astype(np.uint8)
    reference = np.repeat(board[:, :, None], 3, axis=2)
    rng = np.random.default_rng(0)
    frames = [rng.integers(0, 256, reference.shape, dtype=np.uint8) for _ in range(3)]
    assert camera_fault(reference, frames, np.array([1.0, 1.1, 1.2]), "left") == ""
