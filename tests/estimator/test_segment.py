"""Grasp segmentation on synthetic streams: contact, loading phase, flags, alignment."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from estimator.errors import FitError
from estimator.lag import estimate_camera_lag, estimate_width_lag
from estimator.plausible import MIN_FORCE_NOISE_N, MIN_WIDTH_NOISE_M
from estimator.segment import (
    HOLD_FRAMES,
    HOLD_SETTLE_S,
    HOLD_TOLERANCE,
    segment_grasp,
    unplaced_frames,
)
from estimator.signals import clean_samples, interpolate, noise_std

T_TOUCH = 0.5  # true first touch (s)
T_LOAD = 0.3  # touch to peak (s)
PEAK_N = 20.0
SPEED = 0.0375


def force_at(t):
    return PEAK_N * np.clip((t - T_TOUCH) / T_LOAD, 0, 1) ** 1.5


def width_at(t):
    return 0.06 - SPEED * np.minimum(t, T_TOUCH + T_LOAD)


def streams(*, force_noise=0.0, seed=0, duration=1.2):
    rng = np.random.default_rng(seed)
    tf = np.arange(0, duration, 1 / 80)
    tw = np.arange(0.003, duration, 1 / 10)
    tc = np.arange(0.011, duration, 1 / 30)
    force = force_at(tf) + rng.normal(0, force_noise, tf.size) if force_noise else force_at(tf)
    return tf, force, tw, width_at(tw), tc


def run(tf, force, tw, width, tc, n_frames=3):
    return segment_grasp(tf, force, tw, width, tc, contact_force_n=0.75, n_frames=n_frames)


def test_clean_grasp_is_segmented():
    seg = run(*streams())
    assert seg and seg.flags == ()
    t_contact = T_TOUCH + T_LOAD * (0.75 / PEAK_N) ** (2 / 3)
    assert seg.t_contact_s == pytest.approx(t_contact, abs=2e-3)
    assert T_TOUCH - 1e-9 <= seg.t_onset_s < T_TOUCH + 0.02
    assert seg.t_peak_s == pytest.approx(T_TOUCH + T_LOAD, abs=1 / 80)
    loading, peak_frame = seg.frame_t_s[:-1], seg.frame_t_s[-1]
    assert np.all((loading >= seg.t_contact_s) & (loading <= seg.t_peak_s))
    assert loading.size == 8
    # The peak frame: the next frame after the peak, showing the peak state.
    assert seg.t_peak_s < peak_frame <= seg.t_peak_s + 1 / 30
    assert seg.frame_force_n[-1] == pytest.approx(PEAK_N)
    assert seg.frame_width_m[-1] == pytest.approx(width_at(seg.t_peak_s), abs=2e-4)  # 10 Hz across the stop
    # Interpolated at the frames' own times, not matched by index.
    assert seg.frame_force_n[:-1] == pytest.approx(force_at(loading), abs=0.2)
    linear = loading < 0.7  # widths are exact away from the stop at 0.8 s
    assert seg.frame_width_m[:-1][linear] == pytest.approx(width_at(loading[linear]), abs=1e-9)
    assert seg.frame_width_m[:-1] == pytest.approx(width_at(loading), abs=1e-4)
    assert seg.onset_width_m == pytest.approx(width_at(seg.t_onset_s), abs=1e-9)
    # Three frames spread from contact to the peak frame: first, middle, last.
    assert seg.sample.tolist() in ([0, 4, 8], [0, 5, 8])
    assert seg.load_force_n.size == seg.load_t_s.size == seg.load_width_m.size > 20


def test_the_onset_is_known_to_one_force_period_of_closing():
    seg = run(*streams())
    assert seg.onset_width_sigma_m == pytest.approx(SPEED / 80 / np.sqrt(12), rel=1e-6)
    # A stiff object's force jumps within a sample: the same uncertainty, where interpolating the
    # crossing would put the onset just before the contact sample.
    tf, force, tw, width, tc = streams()
    force = np.where(tf >= T_TOUCH, PEAK_N, 0.0)
    seg = run(tf, force, tw, width, tc)
    assert seg.onset_width_sigma_m == pytest.approx(SPEED / 80 / np.sqrt(12), rel=1e-6)


def test_a_loading_between_two_width_reads_is_flagged():
    assert "width_unread" not in run(*streams()).flags  # 0.3 s of loading: three 10 Hz reads
    tf, force, tw, width, tc = streams()
    force = np.where(tf >= T_TOUCH, PEAK_N, 0.0)  # loaded within one force sample
    assert "width_unread" in run(tf, force, tw, width, tc).flags


def test_widths_beyond_the_grippers_opening_are_dropped_and_named():
    tf, force, tw, width, tc = streams()
    clean = run(tf, force, tw, width, tc)
    glitch = width.copy()
    glitch[4] = 5.0  # one bad read: dropped, nothing else changes
    seg = segment_grasp(tf, force, tw, glitch, tc, contact_force_n=0.75, n_frames=3, max_width_m=0.08)
    assert "implausible_width" in seg.flags and "dropped 1 width samples outside the gripper's 0-0.08 m" in seg.describe()
    assert seg.frame_width_m == pytest.approx(clean.frame_width_m, abs=2e-4)
    # Every width in millimetres: no width left, and the refusal's notes say why.
    in_mm = segment_grasp(tf, force, tw, width * 1e3, tc, contact_force_n=0.75, n_frames=3, max_width_m=0.08)
    assert not in_mm and "too few width samples (0 usable" in in_mm.reason
    assert "not in metres?" in in_mm.describe()


def test_forces_beyond_what_the_gripper_applies_are_dropped_or_refused():
    tf, force, tw, width, tc = streams()
    clean = run(tf, force, tw, width, tc)
    spiked = force.copy()
    spiked[len(spiked) // 2] = -1e4  # one bad read (either sign): dropped, nothing else changes
    seg = segment_grasp(tf, spiked, tw, width, tc, contact_force_n=0.75, n_frames=3, max_force_n=30.0)
    assert "implausible_force" in seg.flags and "dropped 1 force samples beyond 60 N" in seg.describe()
    assert seg.frame_force_n == pytest.approx(clean.frame_force_n, abs=0.05)
    # Forces in grams (a load-cell scale per gram): refused with the reason, not estimated stiffer.
    grams = segment_grasp(tf, force * 1e3 / 9.81, tw, width, tc, contact_force_n=0.75, n_frames=3, max_force_n=30.0)
    assert not grams and "implausible_force" in grams.flags and "in newtons?" in grams.reason
    within = segment_grasp(tf, force, tw, width, tc, contact_force_n=0.75, n_frames=3, max_force_n=PEAK_N / 1.5)
    assert within and "implausible_force" not in within.flags  # an overshoot past the maximum is a force


def test_exact_readings_carry_the_least_noise_a_reading_has():
    seg = run(*streams())  # noise-free force and width
    assert seg.force_noise_n == MIN_FORCE_NOISE_N and seg.width_noise_m == MIN_WIDTH_NOISE_M
    noisy = run(*streams(force_noise=0.05))
    assert noisy.force_noise_n > 10 * MIN_FORCE_NOISE_N  # measured, the floor far below it


def test_nan_duplicate_and_unsorted_timestamps_change_nothing():
    tf, force, tw, width, tc = streams()
    clean = run(tf, force, tw, width, tc)
    rng = np.random.default_rng(3)
    order = rng.permutation(tf.size)
    tf2 = np.concatenate([tf[order], [np.nan, tf[10], 0.7]])
    f2 = np.concatenate([force[order], [5.0, force[10], np.nan]])
    tw2 = np.concatenate([tw, tw[:3], [np.nan]])
    w2 = np.concatenate([width, width[:3], [0.01]])
    tc2 = np.concatenate([tc[:30], [np.nan], tc[30:], tc[20:22]])
    seg = run(tf2, f2, tw2, w2, tc2)
    assert "cleaned_timestamps" in seg.flags
    assert "dropped or merged 3 force and 4 width samples: non-finite values or timestamps" in seg.describe()
    assert seg.t_contact_s == pytest.approx(clean.t_contact_s)
    assert seg.frame_force_n == pytest.approx(clean.frame_force_n)
    assert seg.frame_t_s == pytest.approx(clean.frame_t_s)
    # Frame indices point into the stream as recorded (shifted by the inserted NaN frame).
    assert np.all(tc2[seg.frame_index] == seg.frame_t_s)


def test_frames_not_after_an_earlier_frame_are_dropped_and_counted():
    t = np.array([0.0, 1.0, 3.0, 2.0, 3.0, np.nan, 4.0, 0.5, 5.0])
    assert unplaced_frames(t).tolist() == [False, False, False, True, True, False, False, True, False]
    assert not unplaced_frames(t[:1]).any() and not unplaced_frames([np.nan, 1.0, 2.0]).any()
    tf, force, tw, width, tc = streams()
    clean = run(tf, force, tw, width, tc)
    i = int(clean.frame_index[len(clean.frame_index) // 2])
    late = np.concatenate([np.delete(tc, i), tc[i : i + 1], tc[i + 1 : i + 2]])  # frame i last, then a repeat
    seg = segment_grasp(tf, force, tw, width, late, contact_force_n=0.75, n_frames=3, finger="left")
    removed = run(tf, force, tw, width, np.delete(tc, i))
    assert "cleaned_timestamps" in seg.flags and "cleaned_timestamps" not in removed.flags
    assert seg.notes == (*removed.notes, "dropped 2 tactile frames of finger 'left' whose capture time is not "
                         "after the previous frame's (out of order or duplicated)")
    assert seg.frame_t_s.tolist() == removed.frame_t_s.tolist() and seg.sample.tolist() == removed.sample.tolist()
    assert seg.frame_index.tolist() == removed.frame_index.tolist()


def test_duplicate_timestamps_are_merged_into_their_mean():
    t, v = clean_samples([0.0, 1.0, 1.0, 2.0, np.nan], [0.0, 1.0, 3.0, 4.0, 9.0])
    assert t.tolist() == [0.0, 1.0, 2.0] and v.tolist() == [0.0, 2.0, 4.0]


def test_interpolation_never_extrapolates():
    out = interpolate(np.array([-1.0, 0.5, 3.0]), np.array([0.0, 1.0]), np.array([0.0, 2.0]))
    assert np.isnan(out[0]) and out[1] == 1.0 and np.isnan(out[2])


def test_air_grasp_has_no_contact():
    tf, force, tw, width, tc = streams()
    seg = run(tf, force * 0.02, tw, width, tc)
    assert not seg and "no contact" in seg.reason


def test_tare_offset_is_removed():
    tf, force, tw, width, tc = streams(force_noise=0.02)
    seg = run(tf, force + 0.4, tw, width, tc)
    assert seg.force_baseline_n == pytest.approx(0.4, abs=0.02)
    clean = run(tf, force, tw, width, tc)
    assert seg.t_contact_s == pytest.approx(clean.t_contact_s, abs=0.01)


def test_non_monotonic_loading_is_flagged():
    tf, force, tw, width, tc = streams()
    slip = (tf > 0.65) & (tf < 0.7)
    seg = run(tf, np.where(slip, force - 3.0, force), tw, width, tc)
    assert seg and "non_monotonic" in seg.flags
    assert "force drops by 2." in seg.describe()  # 3 N below a still rising force


def test_clipped_force_ends_loading_at_the_plateau():
    tf, force, tw, width, tc = streams(force_noise=0.01)
    clipped = np.minimum(force, 12.0)
    seg = run(tf, clipped, tw, width, tc)
    assert "clipped" in seg.flags
    first_clip = tf[np.argmax(clipped >= 12.0)]
    assert seg.t_peak_s == pytest.approx(first_clip)
    assert seg.frame_force_n.max() <= 12.0 - seg.force_baseline_n + 1e-12  # none beyond the plateau start


def test_frames_on_another_clock_are_misaligned():
    tf, force, tw, width, tc = streams()
    seg = run(tf, force, tw, width, tc + 100.0)
    assert seg and seg.frame_index.size == 0
    assert "misaligned" in seg.flags and "no tactile frame" in seg.frame_reason
    assert seg.load_force_n.size > 0  # force and width alone remain usable


def test_width_stream_ending_early_is_misaligned():
    tf, force, tw, width, tc = streams()
    keep = tw < 0.65
    seg = run(tf, force, tw[keep], width[keep], tc)
    assert "misaligned" in seg.flags
    assert np.all(seg.frame_t_s <= tw[keep][-1])


def test_single_loading_frame_is_flagged_and_the_peak_frame_shows_the_peak():
    tf, force, tw, width, tc = streams()
    fast = force_at(T_TOUCH + (tf - T_TOUCH) * 10)  # loading in 30 ms
    seg = run(tf, fast, tw, width, tc)
    assert seg.frame_index.size == 2 and seg.sample.tolist() == [0, 1]
    assert seg.frame_t_s[0] <= seg.t_peak_s < seg.frame_t_s[1]
    assert seg.frame_force_n[1] == pytest.approx(PEAK_N)
    assert "too_few_samples" in seg.flags


def loading_between_frames(tf):
    """Touch at 0.55 s, peak force 12.5 ms later: between the frames at 0.544 and 0.578 s."""
    return force_at(T_TOUCH + (tf - 0.55) * 30)


def test_loading_between_two_frames_leaves_the_peak_frame():
    tf, force, tw, width, tc = streams()
    seg = run(tf, loading_between_frames(tf), tw, width, tc)
    assert seg and seg.frame_index.size == 1 and not seg.frame_reason
    assert seg.frame_t_s[0] == pytest.approx(0.011 + 17 / 30) and seg.frame_force_n[0] == pytest.approx(PEAK_N)


def test_no_peak_frame_once_the_force_falls_or_too_long_after_the_peak():
    tf, force, tw, width, tc = streams()
    fast = loading_between_frames(tf)
    released = np.where(tf > 0.57, 0.0, fast)  # let go before the next frame
    seg = run(tf, released, tw, width, tc)
    assert seg and seg.frame_index.size == 0 and "no tactile frame" in seg.frame_reason
    late = tc[(tc < 0.55) | (tc > 0.7)]  # frames dropped for 0.15 s after the peak
    seg = run(tf, fast, tw, width, late)
    assert seg and seg.frame_index.size == 0


def test_too_few_force_samples_is_a_refusal():
    seg = run(np.array([0.0, 1.0]), np.array([0.0, 5.0]), np.array([0.0, 1.0]), np.array([0.05, 0.04]), np.array([0.5]))
    assert not seg and "too few force samples" in seg.reason


def test_noise_std_recovers_white_noise_on_a_trend():
    rng = np.random.default_rng(0)
    t = np.linspace(0, 1, 2000)
    assert noise_std(5 * t**2 + rng.normal(0, 0.02, t.size)) == pytest.approx(0.02, rel=0.1)
    assert noise_std(np.array([1.0, 2.0])) == 0.0


def test_camera_lag_is_recovered_from_the_tactile_onset():
    rng = np.random.default_rng(2)
    lag = 0.015
    tc = np.arange(0.0, 1.0, 1 / 30) + 0.004
    change = np.clip(tc - lag - T_TOUCH, 0, None) * 40 + rng.normal(0, 0.05, tc.size)
    seg = run(*streams(force_noise=0.02)[:4], tc)
    estimated = estimate_camera_lag(tc, change, t_onset_s=seg.t_onset_s)
    assert estimated == pytest.approx(lag, abs=0.012)


def test_width_stamp_delay_is_recovered_from_the_stop():
    rng = np.random.default_rng(4)
    delay = 0.09
    tw = np.arange(0.0, 1.5, 0.1) + rng.uniform(-0.01, 0.01, 15)
    width = width_at(tw) + rng.normal(0, 2e-5, tw.size)
    seg = run(*streams(force_noise=0.02)[:2], tw + delay, width, np.arange(0.011, 1.5, 1 / 30))
    lag = estimate_width_lag(tw + delay, width, t_stop_s=seg.t_peak_s)
    assert estimate_width_lag(tw + delay, width, t_stop_s=seg.t_peak_s, speed_m_s=SPEED) == pytest.approx(
        delay, abs=0.01)  # the commanded speed kept
    assert lag == pytest.approx(delay, abs=0.02)
    assert estimate_width_lag(tw, width, t_stop_s=seg.t_peak_s) == pytest.approx(0.0, abs=0.02)


def test_width_lag_needs_a_stop():
    tw = np.arange(0.0, 1.5, 0.1)
    assert estimate_width_lag(tw, 0.06 - 0.01 * tw, t_stop_s=0.8) is None  # never stops closing
    assert estimate_width_lag(tw[:3], 0.06 - 0.01 * tw[:3], t_stop_s=0.8) is None


def test_camera_lag_needs_no_contact_frames():
    tc = np.arange(0.45, 1.0, 1 / 30)
    assert estimate_camera_lag(tc, np.ones_like(tc), t_onset_s=0.5) is None


def test_bad_arguments_are_refused():
    with pytest.raises(FitError, match="contact_force_n"):
        segment_grasp(*streams(), contact_force_n=0.0, n_frames=3)
    with pytest.raises(FitError, match="1-D"):
        clean_samples(np.zeros(3), np.zeros(4))


finite_or_not = st.floats(allow_nan=True, allow_infinity=True, min_value=None, max_value=None)


@settings(max_examples=60, deadline=None)
@given(
    st.lists(st.tuples(finite_or_not, finite_or_not), min_size=0, max_size=40),
    st.lists(st.tuples(finite_or_not, finite_or_not), min_size=0, max_size=15),
    st.lists(finite_or_not, min_size=0, max_size=20),
)
# Loading forces far below their first sample's rise: pause bands once came out negative or countless.
@example([(0.0, 8.0), (-5.0, -1.0), (-4.0, 0.0), (-3.0, -1.0), (-2.0, 0.0), (-1.0, -1.0),
          (-4.703454885022833e16, -3.897394040810574e21), (-4.703454885022834e16, 0.0)], [(0.0, 0.0), (1.0, 0.0)], [])
@example([(0.0, 8.0), (-5.0, -1.0), (-4.0, 0.0), (-3.0, -1.0), (-2.0, 0.0), (-1.0, -1.0),
          (-4.703454885022833e16, -2930089567901777.0), (-4.703454885022834e16, 0.0)], [(0.0, 0.0), (1.0, 0.0)], [])
def test_any_streams_segment_without_crashing(force, width, frames):
    tf, f = (np.array(c, dtype=float) for c in zip(*force, strict=True)) if force else (np.zeros(0), np.zeros(0))
    tw, w = (np.array(c, dtype=float) for c in zip(*width, strict=True)) if width else (np.zeros(0), np.zeros(0))
    seg = segment_grasp(tf, f, tw, w, np.array(frames, dtype=float), contact_force_n=0.75, n_frames=3)
    if not seg:
        assert seg.reason
        return
    assert np.all(np.isfinite(seg.frame_force_n)) and np.all(np.isfinite(seg.frame_width_m))
    assert np.all(np.isfinite(seg.load_force_n)) and np.all(np.isfinite(seg.load_width_m))
    assert seg.t_onset_s <= seg.t_contact_s <= seg.t_peak_s


def test_a_peak_at_the_last_representable_time_segments_without_overflow_warnings():
    big = np.finfo(float).max
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the peak frame is searched after the peak's time
        seg = segment_grasp(np.array([0.0, 0.1, 0.2, big]), np.array([0.0, 2.0, 4.0, 10.0]), np.array([0.0, big]),
                            np.array([0.05, 0.04]), np.array([0.05, 0.15, 0.25]), contact_force_n=0.75, n_frames=3)
    assert seg.t_peak_s == big


def test_width_reads_a_float_range_apart_segment_without_overflow_warnings():
    big = np.finfo(float).max
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the closing speed at the onset divides by their gap
        seg = segment_grasp(np.array([0.0, 0.1, 0.2, 0.3]), np.array([0.0, 2.0, 4.0, 10.0]), np.array([-big, big]),
                            np.array([0.05, 0.04]), np.array([0.05, 0.15, 0.25]), contact_force_n=0.75, n_frames=3)
    assert seg.onset_width_sigma_m == 0.0  # no closing speed over an unbounded gap


def test_hold_frames_follow_the_peak_after_the_width_reads_settle():
    tf, force, tw, width, tc = streams(duration=1.6)
    seg = run(tf, force, tw, width, tc)
    assert 1 <= seg.hold_index.size <= HOLD_FRAMES
    assert np.all(seg.hold_t_s >= seg.t_peak_s + HOLD_SETTLE_S)
    assert seg.hold_force_n == pytest.approx(np.full(seg.hold_index.size, seg.peak_force_n), rel=0.05)
    assert np.all(np.isfinite(seg.hold_width_m))
    assert not np.isin(seg.hold_index, seg.frame_index).any()


def test_hold_frames_end_where_the_release_begins():
    tf, force, tw, width, tc = streams(duration=2.0)
    letting_go = np.clip((tf - 1.3) / 0.2, 0.0, 1.0)  # the release: from 1.3 s, free by 1.5 s
    seg = run(tf, force * (1.0 - letting_go), tw, width, tc)
    assert 1 <= seg.hold_index.size <= HOLD_FRAMES
    assert np.all(seg.hold_t_s <= 1.3 + 1 / 80)
    assert np.all(seg.hold_force_n >= seg.peak_force_n * (1.0 - HOLD_TOLERANCE))


def test_reported_stop_admits_the_peak_frame_before_any_force_after_it_and_fixes_its_width():
    tf, force, tw, width, tc = streams()
    fast = loading_between_frames(tf)
    # What has arrived when the peak frame (0.578 s) comes: force up to 0.57 s, widths up to the stop.
    stop_s = 0.5625
    arrived_f, arrived_w = tf <= 0.57, tw <= stop_s
    tw_live = np.append(tw[arrived_w], stop_s + 1e-4)
    w_live = np.append(width[arrived_w], 0.0335)  # the width read at the stop
    args = (tf[arrived_f], fast[arrived_f], tw_live, w_live, tc[tc <= 0.58])
    assert run(*args).frame_index.size == 0  # the force at 0.578 s is not known yet
    seg = segment_grasp(*args, contact_force_n=0.75, n_frames=3, stopped_s=stop_s)
    assert seg.frame_t_s.tolist() == pytest.approx([0.011 + 17 / 30])
    assert seg.frame_force_n[0] == pytest.approx(PEAK_N)
    assert seg.frame_width_m[0] == pytest.approx(np.interp(stop_s, tw_live, w_live))
    assert "misaligned" not in seg.flags  # no width is wanted after the stop


def test_widths_stamped_after_the_reported_stop_are_the_width_at_the_stop():
    # The fingers stand still from the reported stop on: width reads stamped later (a delayed stamp, here
    # still closing) are not a further closing, in the loading phase or at the frames.
    tf, force, tw, width, tc = streams()
    stop_s = 0.7  # before the force peaks at 0.8 s
    seg = segment_grasp(tf, force, tw, width, tc, contact_force_n=0.75, n_frames=3, stopped_s=stop_s)
    at_stop = np.interp(stop_s, tw, width)
    loading_after = seg.load_t_s > stop_s
    assert loading_after.any() and seg.load_width_m[loading_after] == pytest.approx(at_stop, abs=1e-9)
    frames_after = np.minimum(seg.frame_t_s, seg.t_peak_s) > stop_s  # the peak frame shows the peak's state
    assert frames_after.any() and seg.frame_width_m[frames_after] == pytest.approx(at_stop, abs=1e-9)


# --------------------------------------------------------------------------- an operator's grasp


def operator_streams(*, pause=None, backoff=None, speed_m_s=0.01, noise=0.0, seed=0):
    """An operator's grasp of a linear spring (2000 N/m): it closes at ``speed_m_s`` from 0.5 s,
    holds still over ``pause`` (start, end), and over ``backoff`` (start, turn, end) opens at the
    same speed until ``turn`` and closes again; it stops at 0.9 of the way and never reports a stop."""
    dt = 1e-3
    t = np.arange(0.0, 4.0, dt)
    velocity = np.where(t >= 0.5, -speed_m_s, 0.0)
    if pause:
        velocity[(t >= pause[0]) & (t < pause[1])] = 0.0
    if backoff:
        velocity[(t >= backoff[0]) & (t < backoff[1])] = speed_m_s
    closure = np.cumsum(-velocity) * dt
    closure = np.minimum(closure, 0.9 * closure.max() if closure.max() > 0 else 0.0)
    closure = np.maximum.accumulate(closure) if not backoff else closure
    width = 0.06 - closure
    force = 2000.0 * np.clip(closure - 0.004, 0.0, None)  # touch after 4 mm
    rng = np.random.default_rng(seed)
    tf = np.arange(0.0, 4.0, 1 / 80)
    tw = np.arange(0.003, 4.0, 1 / 10)
    tc = np.arange(0.011, 4.0, 1 / 30)
    f = np.interp(tf, t, force) + (rng.normal(0, noise, tf.size) if noise else 0.0)
    return tf, f, tw, np.interp(tw, t, width), tc


def test_an_operator_grasp_is_segmented_on_its_loading_envelope_and_sampled_by_approach():
    tf, force, tw, width, tc = operator_streams(backoff=(1.6, 1.9, 2.5), noise=0.01)
    seg = run(tf, force, tw, width, tc, n_frames=5)
    assert seg and seg.sample_by == "approach"
    # Backing off and squeezing back up to the first peak's force is skipped: no loading frame
    # there lies below the force reached before it.
    backing = (seg.frame_t_s > 1.62) & (seg.frame_t_s < 2.18)  # back at the first peak's force at 2.2 s
    assert not backing.any()
    assert np.all(np.diff(seg.frame_force_n) > -0.1)
    assert "1 back-off and re-squeeze skipped" in seg.loading and seg.loading in seg.describe()
    # Said of any grasp without a reported stop, a scripted one still loading live included.
    assert "no gripper stop reported, as when an operator drives" in seg.loading
    assert (seg.load_force_n >= np.maximum.accumulate(seg.load_force_n) - 0.1).all()
    # The sample is spread evenly in approach along the envelope.
    approach = seg.contact_width_m - seg.frame_width_m[seg.sample]
    steps = np.diff(approach)
    assert steps.max() < 1.6 * steps.mean()


def test_a_pause_is_named_and_sampling_by_approach_skips_its_repeated_frames():
    tf, force, tw, width, tc = operator_streams(pause=(1.2, 2.4))
    seg = run(tf, force, tw, width, tc, n_frames=5)
    assert seg and "paused 1.2" in seg.loading
    by_time = np.abs(seg.frame_t_s[None, :] - np.linspace(seg.t_contact_s, seg.frame_t_s[-1], 5)[:, None]).argmin(1)
    in_pause = (seg.frame_t_s > 1.25) & (seg.frame_t_s < 2.35)
    assert in_pause[seg.sample].sum() <= 1 < in_pause[by_time].sum()


def test_a_reported_stop_keeps_the_papers_segmentation():
    tf, force, tw, width, tc = streams()
    seg = segment_grasp(tf, force, tw, width, tc, contact_force_n=0.75, n_frames=3, stopped_s=T_TOUCH + T_LOAD)
    assert seg.sample_by == "time" and seg.loading == ""
    targets = np.linspace(seg.t_contact_s, seg.frame_t_s[-1], 3)
    assert seg.sample.tolist() == np.unique(np.abs(seg.frame_t_s[None, :] - targets[:, None]).argmin(1)).tolist()
