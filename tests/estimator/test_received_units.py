"""What a grasp keeps of what it received (estimator.received), unit by unit: a record's samples shifted earlier
by a lag and their newest finite time whatever their order, a live batch refused unless its times and values are
finite and as many, the newest time over batches that come out of order; a record's frames past the cap kept as
live would keep them, the cut's frame itself not before the cut, and a grasp with no contact keeping its last."""

from __future__ import annotations

import numpy as np
import pytest

from estimator import received
from estimator.errors import PerceptionError
from estimator.received import Frames, Series
from teleop.record import FrameStream, Samples

CAP = 40  # frames a grasp keeps in these tests; PRE_CONTACT_FRAMES (30) of them from before the cut


@pytest.fixture
def cap(monkeypatch):
    monkeypatch.setattr(received, "MAX_GRASP_FRAMES", CAP)
    assert received.PRE_CONTACT_FRAMES == 30
    return CAP


def stream(n: int) -> FrameStream:
    """``n`` frames of one finger captured at 0, 1, 2, ... s (bytes never decoded here)."""
    return FrameStream("left", np.arange(float(n)), tuple(b"%d" % i for i in range(n)), "jpeg")


# --------------------------------------------------------------------------- Series


def test_a_records_samples_are_shifted_earlier_and_keep_their_newest_finite_time():
    series = Series.of(Samples(np.array([3.0, 1.0, np.nan, 2.0]), np.array([0.3, 0.1, 0.0, 0.2])), shift_s=0.5)
    assert series.samples().t_s[[0, 1, 3]].tolist() == [2.5, 0.5, 1.5]
    assert series.last_t_s == 2.5  # the newest, not the last recorded
    assert Series.of(Samples(np.array([np.nan]), np.array([1.0]))).last_t_s == -np.inf


def test_a_batch_is_refused_unless_its_times_and_values_are_finite_and_as_many():
    series = Series()
    with pytest.raises(PerceptionError, match="force: 2 timestamps but 1 values"):
        series.add(np.array([0.0, 0.1]), np.array([1.0]), "force")
    with pytest.raises(PerceptionError, match="force: timestamps and values must be finite"):
        series.add(np.array([0.0, 0.1]), np.array([1.0, np.nan]), "force")
    with pytest.raises(PerceptionError, match="must be finite"):
        series.add(np.array([np.inf]), np.array([1.0]), "force")
    assert series.t_s == [] and series.last_t_s == -np.inf


def test_the_newest_time_is_the_newest_over_batches_and_an_empty_batch_is_no_batch():
    series = Series()
    series.add(np.array([1.0, 2.0]), np.array([0.0, 0.0]), "width")
    series.add(np.array([0.5]), np.array([0.0]), "width")  # came late
    series.add(np.zeros(0), np.zeros(0), "width")
    assert series.last_t_s == 2.0 and len(series.t_s) == 2
    assert series.samples().t_s.tolist() == [1.0, 2.0, 0.5]  # in the order they came


# --------------------------------------------------------------------------- Frames.of_record


def test_a_frame_captured_at_the_cut_is_not_before_it(cap):
    # 31 frames before the cut at 31 s (0..30 s): the first may go, leaving 30; the frame at 31 s is not before it.
    frames = Frames.of_record(stream(60), keep_from_s=31.0)
    assert (frames.dropped, frames.t_s[0], len(frames.t_s), frames.not_kept) == (1, 1.0, CAP, 19)


def test_a_grasp_with_no_contact_keeps_its_last_frames(cap):
    frames = Frames.of_record(stream(60))  # no cut: every frame came before contact
    assert (frames.dropped, frames.t_s[0], frames.t_s[-1], frames.not_kept) == (20, 20.0, 59.0, 0)
    assert frames.encoded[0] == b"20" and frames.arrived == 60


def test_a_record_within_the_cap_keeps_every_frame_shifted(cap):
    frames = Frames.of_record(stream(CAP), shift_s=0.25, keep_from_s=0.0)
    assert (frames.dropped, frames.not_kept, frames.t_s[0], len(frames.t_s)) == (0, 0, -0.25, CAP)


def test_a_copy_keeps_its_counts(cap):
    frames = Frames.of_record(stream(60), keep_from_s=31.0)
    copied = frames.copy()
    assert (copied.dropped, copied.not_kept, copied.t_s) == (frames.dropped, frames.not_kept, frames.t_s)
    copied.t_s.append(99.0)
    assert frames.t_s[-1] == 40.0  # the copy's lists are its own


# --------------------------------------------------------------------------- Frames live


def live(times, refused=()) -> Frames:
    """Frames received live at ``times`` (s), those at ``refused`` refused where they came."""
    frames = Frames()
    for t in times:
        if t in refused:
            frames.count_refused(t)
        else:
            frames.add(t, b"jpeg", "jpeg", where="test")
    return frames


def test_room_is_made_from_the_oldest_frame_refused_or_not(cap):
    frames = live(np.arange(float(CAP)), refused=(3.0,))
    assert frames.full and frames.refused == [(3, 3.0)]
    assert frames.make_room(lambda: np.inf)
    assert (frames.dropped, frames.t_s[0], frames.refused) == (1, 1.0, [(3, 3.0)])  # frame 0, not the refused one
    frames.count_refused(40.0)  # refused as it came: its index is where it arrived, past the one dropped
    assert frames.refused == [(3, 3.0), (40, 40.0)]
    for t in (41.0, 42.0):
        assert frames.make_room(lambda: np.inf)
        frames.add(t, b"jpeg", "jpeg", where="test")
    assert frames.make_room(lambda: np.inf)  # frames 0-2 gone: the refused one is the oldest
    assert (frames.dropped, frames.t_s[0], frames.refused) == (4, 4.0, [(40, 40.0)])
    assert frames.arrived == 43


def test_a_refused_frame_before_the_cut_counts_for_the_reference(cap):
    # 31 frames before the cut at 31 s, one of them refused: the reference keeps its 30 when the oldest goes.
    frames = live(np.arange(float(CAP)), refused=(5.0,))
    assert frames.make_room(lambda: 31.0)
    assert not frames.make_room(lambda: 31.0)


def test_a_raw_frame_is_stored_as_png_and_follows_png_frames():
    frames = Frames()
    frames.check(0.0, "png", where="test")
    frames.encoding = "png"
    frames.check(0.1, "raw", where="test")  # a raw frame is kept as lossless PNG
    with pytest.raises(PerceptionError, match="test: jpeg after png frames"):
        frames.check(0.2, "jpeg", where="test")
    with pytest.raises(PerceptionError, match="test: capture time nan is not finite"):
        frames.check(np.nan, "png", where="test")
