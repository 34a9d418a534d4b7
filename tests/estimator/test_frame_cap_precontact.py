"""A grasp whose frames before contact alone pass ``MAX_GRASP_FRAMES`` (an operator holding the dead-man for
minutes before touching the object) keeps, of them, only the last ones the no-contact reference needs: its
estimate rests on its contact frames, live and offline alike, and it keeps no more frames than the cap. A frame
refused live is dropped to make room in its turn, and never blocks the frames after it."""

from __future__ import annotations

import dataclasses
import re

import cv2
import numpy as np
import pytest
from support.live import METHODS, feed, in_capture_order, same

from estimator import received
from estimator import stream as stream_module
from estimator.errors import PerceptionError
from estimator.inference.sampling import sample_grasp, sample_stream
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


def test_the_segment_follows_the_frames_kept_while_old_ones_are_dropped(settings, calibration, records, cap):
    record = prepended(records["stress_ball"], 2.0 * cap / 30)
    items = in_capture_order(record)
    live = GraspStream(settings=settings, calibration=calibration, methods=METHODS)
    for t, kind, body in items:  # the force and widths first: the onset is known before the frames come
        if kind != "frame":
            feed(live, kind, body, t)
    compared = 0
    for t, kind, body in items:
        if kind != "frame" or body["finger"] != live.finger:
            continue
        try:
            feed(live, kind, body, t)
        except PerceptionError:
            continue
        segment = live.segment()  # as the service segments at every frame
        fresh = live.for_finger(live.finger, calibration=calibration).segment()  # the same frames, nothing cached
        if any("from before contact, not kept" in note for note in fresh.notes):
            assert np.array_equal(segment.frame_t_s, fresh.frame_t_s) and segment.notes == fresh.notes, t
            compared += 1
        if compared == 5:
            break
    assert compared == 5  # frames were dropped along the way


def test_a_refused_frame_dropped_once_in_contact_leaves_each_kept_frame_its_own_image(settings, calibration,
                                                                                       records, cap):
    # Two seconds before contact (its 4th frame garbled): the cap is reached in contact, and the garbled frame,
    # dropped then to make room, held no image: each frame kept keeps its own.
    record = prepended(records["stress_ball"], 2.0)
    live = GraspStream(settings=settings, calibration=calibration, methods=METHODS)
    for t, kind, body in in_capture_order(record):
        try:
            if feed(live, kind, body, t) and live.segment():
                live.measure_frames()
        except PerceptionError as exc:
            assert "frame 3 of finger 'left'" in str(exc)
    offline = GraspStream.from_record(record, settings=settings, calibration=calibration, methods=METHODS)
    assert live.frames_not_kept("left") == offline.frames_not_kept("left") > 0  # the cap was reached in contact
    final, measured = live.estimate().estimates, offline.estimate().estimates
    dropped = [re.search(r"its first (\d+) frames of finger 'left', from before contact, not kept", e.reason)
               for e in final]
    assert all(found and int(found[1]) > 3 for found in dropped)  # the garbled 4th frame among them
    assert any(e.state == "ok" for e in final)
    assert all(same(a, b) for a, b in zip(final, measured, strict=True))
    # A model's input, read from the images and depths the stream cached, is the record's of the frames kept.
    cached = sample_stream(live, n_frames=3, size_px=None)
    decoded = sample_grasp(live.to_record(), settings=settings, calibration=calibration, n_frames=3, size_px=None)
    assert cached and np.array_equal(cached.depth_m, decoded.depth_m)


def test_a_frame_refused_for_its_time_is_dropped_first_and_blocks_nothing(settings, calibration, cap):
    jpeg = cv2.imencode(".jpg", np.zeros((8, 8, 3), np.uint8))[1].tobytes()
    stream = GraspStream(settings=settings, calibration=calibration, methods=METHODS)
    other = next(s.finger for s in stream.sensors if s.finger != stream.finger)  # kept as it came, not decoded
    with pytest.raises(PerceptionError, match="not finite"):
        stream.add_frame(other, float("nan"), jpeg, "jpeg")  # refused: it takes a place among those kept
    times = [i / 30 for i in range(3 * cap)]  # an open gripper long before contact: no force yet
    for t in times:
        assert stream.add_frame(other, t, jpeg, "jpeg") is False
    assert stream.frames_not_kept(other) == 0  # room was made for every one, the refused frame's first
    assert stream.to_record().stream(other).t_s.tolist() == times[-cap:]  # none lost to the refused one


def test_once_a_frame_was_not_kept_no_later_one_makes_room(cap):
    """As a record's frames past those kept stay past them (Frames.of_record stops at the first frame with no
    room), live ones do: a later cut that would free room (the onset found again later) drops no frame."""
    frames = received.Frames()
    for i in range(cap):
        frames.add(i / 30, b"jpeg", "jpeg", where="test")
    assert frames.full
    assert not frames.make_room(lambda: 0.5)  # 15 frames before the cut: the reference needs them
    frames.not_kept += 1  # the new frame is counted, not kept (GraspStream.add_frame)
    assert not frames.make_room(lambda: np.inf)
    assert (frames.dropped, len(frames.t_s), frames.t_s[0]) == (0, cap, 0.0)
