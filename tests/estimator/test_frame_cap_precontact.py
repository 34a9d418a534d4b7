"""A grasp whose frames before contact alone pass ``MAX_GRASP_FRAMES`` (an operator holding the dead-man for
minutes before touching the object) keeps, of them, only the last ones the no-contact reference needs: its
estimate rests on its contact frames, live and offline alike, and it keeps no more frames than the cap."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from support.live import METHODS, feed, in_capture_order, same

from estimator import received
from estimator import stream as stream_module
from estimator.errors import PerceptionError
from estimator.measurements import REFERENCE_FRAMES, REFERENCE_GUARD_S
from estimator.stream import GraspStream
from teleop.record import Samples


def prepended(record, seconds: float):
    """``record`` (its end event dropped) after ``seconds`` of an open gripper out of contact: force noise,
    widths closing to the first, and the first frame of each finger again at 30 Hz (the left's fourth garbled)."""
    rng = np.random.default_rng(0)
    f, w = record.force_n, record.width_m
    tf, tw = np.arange(f.t_s[0] - seconds, f.t_s[0], 1 / 80), np.arange(w.t_s[0] - seconds, w.t_s[0], 0.1)
    frames = []
    for s in record.frames:
        t = np.arange(s.t_s[0] - seconds, s.t_s[0] - 1e-3, 1 / 30)
        before = [s.encoded[0]] * t.size
        if s.finger == "left":
            before[3] = b"not a jpeg"
        frames.append(dataclasses.replace(s, t_s=np.concatenate([t, s.t_s]), encoded=(*before, *s.encoded)))
    return dataclasses.replace(
        record, events={}, frames=tuple(frames),
        force_n=Samples(np.concatenate([tf, f.t_s]), np.concatenate([rng.normal(0, 0.015, tf.size), f.value])),
        width_m=Samples(np.concatenate([tw, w.t_s]), np.concatenate([np.linspace(0.08, w.value[0], tw.size), w.value])))


@pytest.fixture
def cap(monkeypatch, records):
    """A cap of the grasp's own frame count (the shipped one is far above it)."""
    n = len(records["stress_ball"].stream("left").t_s)
    for module in (received, stream_module):
        monkeypatch.setattr(module, "MAX_GRASP_FRAMES", n)
    return n


def test_a_long_approach_keeps_the_contact_frames_live_and_offline(settings, calibration, records, cap):
    record = prepended(records["stress_ball"], 2.0 * cap / 30)  # twice the cap before contact
    live = GraspStream(settings=settings, calibration=calibration, methods=METHODS)
    most = 0
    for t, kind, body in in_capture_order(record):
        try:
            if feed(live, kind, body, t) and live.segment():
                live.measure_frames()  # as the service does: frames measured while the first are dropped
        except PerceptionError as exc:
            assert "frame 3 of finger 'left'" in str(exc)
        most = max(most, live.frame_count, len(live._perception.images))
    assert most <= cap  # memory stays bounded
    result = live.estimate()
    assert result.loading_frames > 0, result.estimate.reason  # measured on the contact frames
    final = result.estimates
    offline = GraspStream.from_record(record, settings=settings, calibration=calibration, methods=METHODS)
    measured = offline.estimate().estimates
    assert any(e.state == "ok" for e in final) and all(same(a, b) for a, b in zip(final, measured, strict=True))
    for finger in ("left", "right"):
        assert live.frames_not_kept(finger) == offline.frames_not_kept(finger)
        assert live._frames[finger].dropped == offline._frames[finger].dropped > cap
    dropped = offline._frames["left"].dropped
    assert all(f"its first {dropped} frames of finger 'left', from before contact, not kept" in e.reason
               for e in final)
    # The record without the frames dropped gives the same floats, without the note.
    kept = dataclasses.replace(record, frames=tuple(
        dataclasses.replace(s, t_s=s.t_s[dropped:], encoded=s.encoded[dropped:]) for s in record.frames))
    alone = GraspStream.from_record(kept, settings=settings, calibration=calibration, methods=METHODS)
    for a, b in zip(measured, alone.estimate().estimates, strict=True):
        assert (a.method, a.state, a.e_pa, a.interval_pa) == (b.method, b.state, b.e_pa, b.interval_pa)
        assert "from before contact" not in b.reason


def test_frames_kept_keep_the_no_contact_reference(settings, records, cap):
    record = prepended(records["stress_ball"], 2.0 * cap / 30)
    stream = GraspStream.from_record(record, settings=settings, calibration=None, methods=METHODS)
    segment = stream.segment()
    assert segment.frame_index.size > 0
    before = np.flatnonzero(stream._frame_times() < segment.t_onset_s - REFERENCE_GUARD_S)
    assert before.size == received.PRE_CONTACT_FRAMES >= REFERENCE_FRAMES


def test_an_ordinary_grasp_keeps_every_frame(settings, records):
    record = records["steel_ball_bearing"]
    stream = GraspStream.from_record(record, settings=settings, calibration=None, methods=METHODS)
    assert stream.frame_count == len(record.stream("left").t_s) and not stream._frames["left"].dropped


def test_the_report_shows_the_loading_frames_of_a_grasp_with_dropped_frames(settings, records, cap):
    """``teleop report``'s moments are the record's frames: a segment's positions count from the first kept."""
    from teleop.system.report_data import GraspView, tactile_moments

    def moments(record):
        view = GraspView("g")
        view.record = record
        tactile_moments(view, settings=settings, calibrations={f: "no depth here" for f in ("left", "right")})
        return {(m.finger, m.name): (m.t_s, m.force_n) for m in view.moments}

    plain, long = moments(records["stress_ball"]), moments(prepended(records["stress_ball"], 2.0 * cap / 30))
    for key in (("left", "mid-loading"), ("left", "peak force")):
        assert long[key] == pytest.approx(plain[key], abs=1e-9), key
