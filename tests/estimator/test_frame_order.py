"""Tactile frames whose capture time is not after the previous frame's (out of order or duplicated):
dropped with a note, offline as live, the estimate that of the record without them."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from support.live import METHODS, feed, in_capture_order, same

from estimator.measure import estimate_grasp, measure_grasp
from estimator.stream import GraspStream
from teleop.record import GraspRecord


def note(count: int, finger: str = "left") -> str:
    return (f"dropped {count} tactile frames of finger {finger!r} whose capture time is not after the previous "
            "frame's (out of order or duplicated)")


def with_frames(record: GraspRecord, order: list[int], t_s: np.ndarray | None = None) -> GraspRecord:
    """``record`` with each finger's frames taken at positions ``order`` (as recorded), their capture
    times ``t_s`` when given (else the frames' own)."""
    streams = tuple(dataclasses.replace(s, t_s=s.t_s[order] if t_s is None else t_s,
                                        encoded=tuple(s.encoded[i] for i in order)) for s in record.frames)
    return dataclasses.replace(record, frames=streams, events={})


def loading_frames(record: GraspRecord, settings) -> np.ndarray:
    return measure_grasp(record, settings=settings, tactile=False).segment.frame_index


def estimates(record: GraspRecord, settings, calibration) -> list:
    measured = measure_grasp(record, settings=settings, calibration=calibration)
    return [estimate_grasp(measured, m, settings=settings) for m in METHODS]


def assert_same_but_noted(got: list, expected: list, text: str) -> None:
    """Each estimate of ``got`` is ``expected``'s, its reason noting ``text`` besides."""
    for a, b in zip(got, expected, strict=True):
        assert text in a.reason and text not in b.reason
        assert (a.method, a.state, a.e_pa, a.interval_pa) == (b.method, b.state, b.e_pa, b.interval_pa)
        assert a.reason.replace(f"; {text}", "") == b.reason


@pytest.mark.parametrize("name", ["steel_ball_bearing", pytest.param("stress_ball", marks=pytest.mark.slow)])
def test_swapped_frame_times_drop_the_frame_that_cannot_be_placed(settings, calibration, records, name):
    record = dataclasses.replace(records[name], events={})
    index = loading_frames(record, settings)
    i = int(index[index.size // 2 - 1])  # two loading frames, captured i then i + 1, stamped the other way round
    t = record.frames[0].t_s.copy()
    t[[i, i + 1]] = t[[i + 1, i]]
    swapped = with_frames(record, list(range(len(t))), t)
    # Frame i + 1, stamped before frame i, cannot be placed: the record without it, frame i at i + 1's time.
    kept = [k for k in range(len(t)) if k != i + 1]
    without = with_frames(swapped, kept)
    assert_same_but_noted(estimates(swapped, settings, calibration), estimates(without, settings, calibration),
                          note(1))
    segment = measure_grasp(swapped, settings=settings, tactile=False).segment
    assert "cleaned_timestamps" in segment.flags and i + 1 not in segment.frame_index


def test_a_repeated_or_late_frame_is_dropped_as_if_never_recorded(settings, calibration, records):
    record = dataclasses.replace(records["steel_ball_bearing"], events={})
    n = len(record.frames[0])
    i, j = (int(k) for k in loading_frames(record, settings)[:2])
    # Frame j recorded twice (the same time), and frame i once more after the last frame, at its own time.
    repeated = with_frames(record, [*range(j + 1), j, *range(j + 1, n), i])
    assert_same_but_noted(estimates(repeated, settings, calibration), estimates(record, settings, calibration),
                          note(2))


def test_a_live_stream_fed_frames_in_record_order_drops_the_same_frame_as_offline(settings, calibration, records):
    record = dataclasses.replace(records["steel_ball_bearing"], events={})
    i = int(loading_frames(record, settings)[0])
    t = record.frames[0].t_s.copy()
    t[[i, i + 1]] = t[[i + 1, i]]
    swapped = with_frames(record, list(range(len(t))), t)
    stream = GraspStream(settings=settings, calibration=calibration, methods=METHODS)
    # The frames come in the order they were recorded, each with its (swapped) capture time.
    for _, kind, body in in_capture_order(record):
        at = swapped.stream(body["finger"]).t_s[body["index"]] if kind == "frame" else None
        feed(stream, kind, body, at)
        if kind == "frame" and stream.segment():
            stream.estimate()  # provisional estimates along the way: nothing raises
    assert stream.frame_count == len(t)
    final = stream.estimate()
    offline = estimates(swapped, settings, calibration)
    assert all(same(a, b) for a, b in zip(final.estimates, offline, strict=True))
    assert all(note(1) in e.reason for e in final.estimates)
    assert i + 1 not in final.segment.frame_index
