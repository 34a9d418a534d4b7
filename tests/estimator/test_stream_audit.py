"""GraspStream behaviours pinned by a mutation audit: what ends the loading, what a stream refuses,
and what its export and notes say."""

from __future__ import annotations

import dataclasses
import re

import numpy as np
import pytest
from support.live import METHODS, feed, in_capture_order

from estimator import received
from estimator import stream as stream_module
from estimator.errors import FitError, PerceptionError
from estimator.stream import GraspStream


def fed(settings, calibration, record, *, repeat_frame: int | None = None, until_s: float = np.inf) -> GraspStream:
    """A stream fed ``record`` in capture order up to ``until_s``, the estimator finger's frame at
    position ``repeat_frame`` (when given) fed twice: a duplicate the segmentation skips."""
    stream = GraspStream(settings=settings, calibration=calibration, methods=METHODS)
    for t, kind, body in in_capture_order(record):
        if t > until_s:
            break
        if kind == "frame" and body["finger"] == stream.finger and body["index"] == repeat_frame:
            feed(stream, kind, body, t)
        feed(stream, kind, body, t)
    return stream


@pytest.fixture(scope="module")
def steel(records):
    return dataclasses.replace(records["steel_ball_bearing"], events={})


def test_a_repeated_frame_does_not_keep_a_settled_loading_from_ending(settings, calibration, steel):
    # Without a marker the loading ends once a frame newer than the peak came; a skipped duplicate
    # (NaN among the frame times) must not hide the frames that came after it.
    clean = fed(settings, calibration, steel)
    repeated = fed(settings, calibration, steel, repeat_frame=2)
    assert clean.loading_complete()
    assert repeated.frame_count == clean.frame_count + 1
    assert repeated.loading_complete()


def test_a_repeated_frame_before_contact_leaves_the_newest_data_time_finite(settings, calibration, steel):
    before = float(steel.stream(settings.sensing.finger).t_s[4])  # long before contact
    stream = fed(settings, calibration, steel, repeat_frame=1, until_s=before)
    segment = stream.segment()
    assert not segment
    assert stream.last_loading_frame_s(segment) == before


def test_a_stream_asked_for_no_method_is_refused(settings, calibration):
    with pytest.raises(FitError, match=r"methods \[\]: expected some of"):
        GraspStream(settings=settings, calibration=calibration, methods=())


def test_a_record_without_frames_of_the_estimator_finger_is_refused_naming_the_finger(settings, steel):
    finger = settings.sensing.finger
    others = dataclasses.replace(steel, frames=tuple(s for s in steel.frames if s.finger != finger))
    with pytest.raises(FitError, match=rf"SensingSettings.finger = {finger!r}: no frames from finger"):
        GraspStream.from_record(others, settings=settings)


def test_a_twin_for_another_finger_keeps_the_follow_mode(settings, calibration, steel):
    # An operator's grasp ends its loading only at its end, on every finger a model reads.
    stream = fed(settings, calibration, steel)
    stream.mark_follow()
    other = next(s.finger for s in stream.sensors if s.finger != stream.finger)
    twin = stream.for_finger(other, calibration=None)
    assert twin.follow and not twin.loading_complete()
    assert twin.to_record().provenance.style == "operator"


def with_early_frames(record, count: int):
    """``record`` with ``count`` copies of each finger's first frame at 30 Hz before it (out of contact)."""
    frames = tuple(dataclasses.replace(s, t_s=np.concatenate([s.t_s[0] - np.arange(count, 0, -1) / 30, s.t_s]),
                                       encoded=(s.encoded[0],) * count + tuple(s.encoded)) for s in record.frames)
    return dataclasses.replace(record, frames=frames)


def test_a_record_one_frame_past_the_cap_keeps_the_frames_live_would(settings, calibration, steel, monkeypatch):
    # Too few frames before contact to make room (though more than that in all): live counts the one past
    # the cap, not kept, and offline alike.
    record = with_early_frames(steel, 10)
    cap = max(len(s.t_s) for s in record.frames) - 1
    assert cap > received.PRE_CONTACT_FRAMES
    for module in (received, stream_module):
        monkeypatch.setattr(module, "MAX_GRASP_FRAMES", cap)
    offline = GraspStream.from_record(record, settings=settings, calibration=calibration)
    live = fed(settings, calibration, record)
    fingers = [s.finger for s in record.frames]
    not_kept = [live.frames_not_kept(finger) for finger in fingers]
    assert [offline.frames_not_kept(finger) for finger in fingers] == not_kept and max(not_kept) == 1
    kept = [{s.finger: s.t_s.tolist() for s in stream.to_record().frames} for stream in (offline, live)]
    assert kept[0] == kept[1]


def test_frames_past_the_cap_are_counted_after_those_dropped_and_kept(settings, calibration, steel, monkeypatch):
    # Pre-contact frames dropped to make room, then frames past the cap: the note's count starts after both.
    record = with_early_frames(steel, 4 * received.PRE_CONTACT_FRAMES)
    finger = settings.sensing.finger
    cap = received.PRE_CONTACT_FRAMES + 5
    for module in (received, stream_module):
        monkeypatch.setattr(module, "MAX_GRASP_FRAMES", cap)
    notes = " ".join(GraspStream.from_record(record, settings=settings, calibration=calibration).segment().notes)
    dropped = re.search(rf"its first (\d+) frames of finger {finger!r}, from before contact, not kept", notes)
    past = re.search(rf"(\d+) frames of finger {finger!r} after its first (\d+) not kept", notes)
    assert dropped and past, notes
    assert int(past[2]) == int(dropped[1]) + cap
    assert int(past[2]) + int(past[1]) == len(record.stream(finger).t_s)


def test_a_follow_grasp_given_a_loading_end_marker_ends_its_loading_on_it(settings, calibration, records, steel):
    stream = fed(settings, calibration, steel)
    stream.mark_follow()
    assert not stream.loading_complete()  # no marker: only its end ends an operator's loading
    stream.mark_loading_end(records["steel_ball_bearing"].events["grasp_done"])
    assert stream.loading_complete()


@pytest.mark.parametrize("frames", [[-1], "count", [0, 0], [0.0], [[0]]], ids=["negative", "past_the_last", "repeated",
                                                                              "not_integers", "not_1d"])
def test_measuring_frames_that_are_not_distinct_loading_positions_is_refused(settings, calibration, steel, frames):
    stream = fed(settings, calibration, steel)
    count = stream.segment().frame_index.size
    frames = np.asarray([count] if frames == "count" else frames)
    with pytest.raises(FitError, match=rf"expected distinct positions 0..{count - 1} of the loading frames"):
        stream.measurements(stream.segment(), frames=frames, tactile=False)


def test_the_camera_lag_moves_the_estimator_fingers_frames_only(settings, steel):
    finger = settings.sensing.finger
    stream = GraspStream.from_record(steel, settings=settings, camera_lag_s=0.01)
    got = {s.finger: s.t_s for s in stream.to_record().frames}
    for s in steel.frames:
        np.testing.assert_allclose(got[s.finger], s.t_s - (0.01 if s.finger == finger else 0.0), rtol=0, atol=1e-12)


def test_hold_frames_are_measured_only_when_the_width_lag_was_corrected(settings, calibration, records):
    record = records["steel_ball_bearing"]  # the whole grasp: its hold too
    uncorrected = GraspStream.from_record(record, settings=settings, calibration=calibration).measurements()
    corrected = GraspStream.from_record(record, settings=settings, calibration=calibration, width_lag_s=0.0)
    assert uncorrected.hold_features is None
    assert corrected.measurements().hold_features is not None


def test_an_estimate_without_tactile_features_says_it_used_no_loading_frame(settings, calibration, steel):
    # No frame before contact: no no-contact reference, so no tactile features; the frames are not "used".
    finger = settings.sensing.finger
    contact_s = fed(settings, calibration, steel).segment().t_contact_s
    late = tuple(dataclasses.replace(s, t_s=s.t_s[s.t_s > contact_s],
                                     encoded=tuple(e for e, t in zip(s.encoded, s.t_s, strict=True) if t > contact_s))
                 if s.finger == finger else s for s in steel.frames)
    stream = fed(settings, calibration, dataclasses.replace(steel, frames=late))
    result = stream.estimate()
    assert result.segment.frame_t_s.size > 0 and stream.measurements().features is None
    assert result.loading_frames == 0
    assert result.t_data_s == float(stream.to_record().stream(finger).t_s.max())


def test_a_finger_whose_every_frame_was_refused_is_left_out_of_the_record(settings, calibration, steel):
    stream = GraspStream(settings=settings, calibration=calibration, methods=METHODS)
    with pytest.raises(PerceptionError, match=rf"frame 0 of finger {stream.finger!r}"):
        stream.add_frame(stream.finger, 1.0, b"not a jpeg", "jpeg")
    assert stream.frame_count == 0
    other = next(s for s in steel.frames if s.finger != stream.finger)
    assert not stream.add_frame(other.finger, 1.0, other.encoded[0], other.encoding)
    assert [s.finger for s in stream.to_record().frames] == [other.finger]


def test_a_record_frame_that_does_not_decode_is_skipped_though_segmented_before(settings, calibration, steel):
    finger = settings.sensing.finger
    i = int(GraspStream.from_record(steel, settings=settings).segment().frame_index[1])
    garbled = tuple(dataclasses.replace(s, encoded=(*s.encoded[:i], b"not a jpeg", *s.encoded[i + 1:]))
                    if s.finger == finger else s for s in steel.frames)
    record = dataclasses.replace(steel, frames=garbled)
    fresh = GraspStream.from_record(record, settings=settings, calibration=calibration, methods=METHODS).estimate()
    stream = GraspStream.from_record(record, settings=settings, calibration=calibration, methods=METHODS)
    assert i in stream.segment().frame_index  # segmented before the frame was found not to decode
    result = stream.estimate()
    assert i not in result.segment.frame_index and "skipped 1 frames" in result.estimate.reason
    assert [(e.state, e.e_pa, e.reason) for e in result.estimates] == [(e.state, e.e_pa, e.reason) for e in fresh.estimates]
