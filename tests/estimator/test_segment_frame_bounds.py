"""Where :mod:`estimator.segment` puts the edges of what it aligns on a grasp's loading phase: a frame
captured at the contact or the peak instant, a frame while the force falls back right after contact, the
frames of a noisy operator grasp, the hold's start, end and count, a peak frame known from a force sample at
its own instant, a sample spread in approach, and what a refused or frameless segment still says."""

from __future__ import annotations

import numpy as np
import pytest

from estimator.segment import sampling_axis, segment_grasp

PEAK_N = 20.0
FORCE_HZ = 80.0


def force_at(t, *, touch_s=0.5, load_s=0.3):
    return PEAK_N * np.clip((t - touch_s) / load_s, 0, 1) ** 1.5


def width_at(t):
    return 0.06 - 0.0375 * np.minimum(t, 0.8)


def grasp(*, duration=1.2):
    """Force at 80 Hz (touch at 0.5 s, 20 N peak at 0.8 s, then held), widths at 10 Hz, frames at 30 Hz."""
    tf = np.arange(0, duration, 1 / FORCE_HZ)
    tw = np.arange(0.003, duration, 1 / 10)
    return tf, force_at(tf), tw, width_at(tw), np.arange(0.011, duration, 1 / 30)


def run(tf, force, tw, width, tc, *, n_frames=3, stopped_s=None):
    return segment_grasp(tf, force, tw, width, tc, contact_force_n=0.75, n_frames=n_frames, stopped_s=stopped_s)


def with_frame(tc, t):
    """The frame times ``tc`` with one more at ``t``, in capture order."""
    return np.sort(np.append(tc[tc != t], t))


# --------------------------------------------------------------------------- loading frames


def test_a_frame_captured_at_the_contact_instant_is_the_first_loading_frame():
    tf, force, tw, width, tc = grasp()
    t_contact = run(tf, force, tw, width, tc).t_contact_s
    seg = run(tf, force, tw, width, with_frame(tc, t_contact))
    assert seg and seg.t_contact_s == t_contact
    assert seg.frame_t_s[0] == t_contact


def test_a_frame_captured_at_the_peak_instant_is_the_last_loading_frame_and_counted_once():
    tf, force, tw, width, tc = grasp()
    t_peak = run(tf, force, tw, width, tc).t_peak_s
    seg = run(tf, force, tw, width, with_frame(tc, t_peak))
    assert seg and seg.t_peak_s == t_peak
    assert np.count_nonzero(seg.frame_t_s == t_peak) == 1
    assert np.unique(seg.frame_index).size == seg.frame_index.size
    assert seg.frame_t_s[-2] == t_peak  # then the peak frame, after it


def test_a_frame_while_the_force_falls_back_right_after_contact_is_off_the_envelope():
    # An operator's grasp: the force jumps to 3 N at contact, falls back to 1 N by the next sample (a
    # bounce), then rises to 10 N; a frame between the two samples sees 2 N, below the 3 N reached.
    tf = np.arange(0.0, 3.0, 1 / FORCE_HZ)
    k = int(np.searchsorted(tf, 1.0))
    force = np.interp(tf, [0, tf[k + 1], 2.5, 3.0], [0, 1.0, 10.0, 10.0])
    force[:k] = 0.0
    force[k] = 3.0
    tw = np.arange(0.0, 3.0, 0.1)
    bounce = tf[k] + 0.5 / FORCE_HZ
    tc = np.concatenate([[bounce], np.arange(1.1, 3.0, 1 / 30)])
    seg = run(tf, force, tw, 0.05 - 1e-4 * np.clip(tw - 1.0, 0, None), tc)
    assert seg and seg.sample_by == "approach"
    assert bounce not in seg.frame_t_s
    assert seg.frame_t_s.size > 10


def test_every_frame_of_a_steady_operator_grasp_read_noisily_is_on_its_envelope():
    # Rising 10 N/s to 15 N, read with 0.1 N of noise: dips within three noise deviations of the running
    # maximum, beyond 1 % of it, are noise, not a back-off.
    rng = np.random.default_rng(2)
    tf = np.arange(0.0, 3.5, 0.01)
    force = np.interp(tf, [0, 1, 2.5, 3.5], [0, 0, 15, 15]) + rng.normal(0, 0.1, tf.size)
    tw = np.arange(0.0, 3.5, 0.02)
    tc = np.arange(0.011, 3.5, 1 / 30)
    seg = run(tf, force, tw, 0.05 - np.interp(tw, [0, 1, 2.5, 3.5], [0, 0, 0.0025, 0.0025]), tc)
    assert seg and seg.sample_by == "approach"
    loading = tc[(tc >= seg.t_contact_s) & (tc <= seg.t_peak_s)]
    np.testing.assert_array_equal(seg.frame_t_s[: loading.size], loading)


# --------------------------------------------------------------------------- peak frame


@pytest.mark.parametrize(("last_n", "peak_frames"), [(PEAK_N, 1), (0.0, 0)])
def test_a_force_sample_at_the_peak_frames_own_instant_decides_it(last_n, peak_frames):
    # Loaded between the frames at 0.544 and 0.578 s; the force arrived up to the peak and one sample at
    # the frame's own capture time: still at the peak, the frame shows it; already released, it does not.
    tf = np.arange(0, 0.57, 1 / FORCE_HZ)
    force = force_at(0.5 + (tf - 0.55) * 30)
    tc = np.arange(0.011, 0.6, 1 / 30)
    t_frame = tc[17]
    tf, force = np.append(tf, t_frame), np.append(force, last_n)
    tw = np.arange(0.003, 0.7, 1 / 10)
    seg = run(tf, force, tw, width_at(tw), tc)
    assert seg, seg.reason
    assert seg.frame_index.size == peak_frames
    if peak_frames:
        assert seg.frame_t_s[0] == t_frame and seg.frame_force_n[0] == pytest.approx(PEAK_N)


# --------------------------------------------------------------------------- hold


def test_a_hold_gives_three_frames_from_0_15_s_after_the_peak_to_its_end():
    tf, force, tw, width, tc = grasp(duration=1.6)
    seg = run(tf, force, tw, width, tc)
    assert seg.hold_index.size == 3
    held = tc[(tc >= seg.t_peak_s + 0.15) & (tc <= tw[-1])]  # from 0.15 s after the peak while widths are read
    assert seg.hold_t_s[0] == held[0] and seg.hold_t_s[-1] == held[-1]


def test_a_partial_release_of_a_tenth_of_the_force_ends_the_hold():
    tf, force, tw, width, tc = grasp(duration=2.0)
    seg = run(tf, np.where(tf >= 1.3, 0.9 * force, force), tw, width, tc)
    assert seg.hold_index.size >= 1
    assert np.all(seg.hold_t_s < 1.3)


def test_a_force_exactly_at_the_hold_level_still_holds():
    # The hold ends where the force falls below the peak by 5 % (1 N of 20 N): at 19 N it still holds.
    tf, force, tw, width, tc = grasp(duration=2.0)
    seg = run(tf, np.where(tf >= 1.2, 19.0, force), tw, width, tc)
    assert seg.hold_t_s[-1] > 1.8


def test_a_hold_read_noisily_lasts_until_the_release():
    # A 5 N grasp read with 0.15 N of noise: dips of 5 % (0.25 N) are noise; the hold ends at the release.
    rng = np.random.default_rng(4)
    tf = np.arange(0.0, 3.0, 1 / FORCE_HZ)
    force = np.interp(tf, [0, 0.5, 0.8, 2.5, 2.6, 3.0], [0, 0, 5, 5, 0, 0]) + rng.normal(0, 0.15, tf.size)
    tw = np.arange(0.003, 3.0, 1 / 10)
    seg = run(tf, force, tw, width_at(tw), np.arange(0.011, 3.0, 1 / 30), stopped_s=0.8)
    assert seg and seg.hold_index.size == 3
    assert seg.hold_t_s[-1] > 2.3


# --------------------------------------------------------------------------- sample and what is said


def test_approach_is_the_closure_since_contact():
    tf, force, tw, width, tc = grasp()
    seg = run(tf, force, tw, width, tc)
    assert seg.sample_by == "approach"
    closure, start = sampling_axis(seg)
    assert start == 0.0
    np.testing.assert_allclose(closure, seg.contact_width_m - seg.frame_width_m)
    assert closure[-1] > 0.0


def test_an_operator_grasp_without_a_width_at_contact_is_sampled_in_time():
    tf, force, tw, width, tc = grasp()
    late = tw > 0.6  # contact at about 0.55 s
    seg = run(tf, force, tw[late], width[late], tc, n_frames=3)
    assert seg and np.isnan(seg.contact_width_m)
    assert seg.sample_by == "time" and seg.sample.size == 3


def test_loading_frames_beyond_the_widths_are_counted_in_the_notes():
    tf, force, tw, width, tc = grasp()
    keep = tw < 0.65
    seg = run(tf, force, tw[keep], width[keep], tc)
    assert "misaligned" in seg.flags
    assert any("loading frames lie outside the width samples' span" in note for note in seg.notes)


def test_loading_frames_none_of_which_has_a_width_leave_a_frame_reason():
    tf, force, tw, width, tc = grasp()
    keep = tw < 0.65
    seg = run(tf, force, tw[keep], width[keep], tc[tc > 0.7])  # the camera starts late, the widths end early
    assert seg and seg.frame_index.size == 0
    assert seg.frame_reason == "no loading frame has a width sample around it"


def test_a_refused_segment_keeps_the_baseline_it_found():
    tf, force, tw, _, tc = grasp()
    opening = 0.05 + 0.001 * np.clip(tw - 0.5, 0, 0.3)  # the widths open as the force rises: refused
    seg = run(tf, force + 0.3, tw, opening, tc)
    assert not seg and "widths open" in seg.reason
    assert seg.force_baseline_n == pytest.approx(0.3, abs=1e-9)


def test_a_sample_in_approach_ends_at_the_last_loading_frame_where_the_widths_read_open_a_little():
    # The last width read before the peak reads 50 um more open than the one before it (read jitter, or a
    # finger relaxing): the peak frame's approach is not the largest, but the sample still ends on it.
    tf, force, tw, width, tc = grasp()
    width = width.copy()
    last = int(np.searchsorted(tw, 0.8)) - 1  # the read at 0.703 s; the next one at 0.803 s
    width[last + 1:] = width[last] + 5e-5
    seg = run(tf, force, tw, width, tc, n_frames=5)
    assert seg and seg.sample_by == "approach"
    closure, _ = sampling_axis(seg)
    assert closure.max() > closure[-1]
    assert seg.sample[-1] == seg.frame_index.size - 1
