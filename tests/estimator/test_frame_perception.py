"""The per-grasp frame cache: the no-contact reference, capture times, dropped and undecodable frames."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from estimator.errors import PerceptionError
from estimator.frame_perception import FramePerception
from estimator.measurements import REFERENCE_FRAMES, REFERENCE_GUARD_S


def perception(n_frames=12):
    """A cache whose frames are already on the depth grid (as the stream fills them live): frame i is 10 * i
    everywhere; capture times 0.1 s apart."""
    fp = FramePerception(finger="left", sensor=None, binning=1, grid=None, grasp_id="g")
    fp.images = {i: np.full((6, 8, 3), 10 * i, np.uint8) for i in range(n_frames)}
    return fp, np.arange(n_frames) * 0.1


def onset_after(t_s):
    """A segment whose reference frames are those captured before ``t_s``."""
    return SimpleNamespace(t_onset_s=t_s + REFERENCE_GUARD_S)


def median_level_of_frames_before(count):
    return 10 * int(np.median(np.arange(count)[-REFERENCE_FRAMES:]))


def test_the_reference_follows_a_moved_onset_and_drops_what_was_measured():
    fp, frame_t = perception()
    fp.use_reference(None, frame_t, onset_after(0.55))  # frames 0..5
    first = fp.reference.copy()
    assert first.shape == (6, 8, 3)
    assert int(first[0, 0, 0]) == median_level_of_frames_before(6)
    fp.depth[7] = np.ones((6, 8), np.float32)  # a depth measured against the first reference
    fp.use_reference(None, frame_t, onset_after(0.85))  # frames 0..8
    assert int(fp.reference[0, 0, 0]) == median_level_of_frames_before(9)
    assert not np.array_equal(fp.reference, first)
    assert fp.depth == {}
    # The same onset again keeps the reference and what was measured against it.
    fp.depth[7] = np.ones((6, 8), np.float32)
    fp.use_reference(None, frame_t, onset_after(0.85))
    assert 7 in fp.depth


def test_frames_that_do_not_decode_have_no_capture_time():
    fp, frame_t = perception(4)
    fp.undecodable = {2: "bad jpeg"}
    times = fp.times(SimpleNamespace(times=lambda: frame_t.copy()))
    assert np.isnan(times[2])
    np.testing.assert_array_equal(np.delete(times, 2), np.delete(frame_t, 2))


def test_dropping_the_first_frame_moves_the_others_down():
    fp, _ = perception(6)
    fp.undecodable = {3: "bad"}
    fp.drop_first()
    assert sorted(fp.images) == [0, 1, 2, 3, 4]
    assert int(fp.images[0][0, 0, 0]) == 10  # was frame 1
    assert fp.undecodable == {2: "bad"}


def test_a_record_whose_frames_all_fail_to_decode_is_an_error():
    def on_grid(position, sensor, *, binning, where):
        raise PerceptionError(f"{where}: does not decode")

    record = SimpleNamespace(t_s=[0.1 * i for i in range(3)], source=object(), on_grid=on_grid)
    fp = FramePerception(finger="left", sensor=None, binning=1, grid=None, grasp_id="g")
    with pytest.raises(PerceptionError, match="does not decode"):
        fp.decode(record)
    assert len(fp.undecodable) == 3
