"""Where the clock-lag estimates draw their lines (estimator.lag): the camera lag's baseline (frames strictly
before the window), the level a change must exceed (not touch, and a floor above a perfectly still baseline),
a lag of exactly max_lag_s, a change already clear at the window's first frame; the width lag's second of reads
either side of the stop, its two reads after the hinge, and its limit of MAX_HINGES hinge times."""

from __future__ import annotations

import numpy as np
import pytest

from estimator.lag import MAX_HINGES, WIDTH_LAG_SLACK_S, estimate_camera_lag, estimate_width_lag

DT = 1 / 64  # frame times on a binary grid: the window's edges fall exactly on frames


def noisy_baseline(n: int) -> np.ndarray:
    return 1.0 + 0.01 * (np.arange(n) % 3 - 1.0)  # -0.01, 0, +0.01 in turn


def closing_until(t, stop_s, *, speed_m_s=0.02, stopped_width_m=0.04):
    return stopped_width_m + speed_m_s * np.maximum(stop_s - t, 0.0)


# --------------------------------------------------------------------------- camera lag


def test_a_frame_at_the_window_start_is_not_in_the_baseline():
    # Onset 0.5 s, max_lag 0.25 s: the baseline is the frames before 0.25 s, here 0, 1/8 and 1/4 s: two of them.
    t = np.r_[0.0, 0.125, 0.25, np.arange(0.3, 1.0, 0.01)]
    change = np.where(t >= 0.6, 1.0 + 5.0 * (t - 0.6), 1.0 + 0.01 * (np.arange(t.size) % 2))
    assert estimate_camera_lag(t, change, t_onset_s=0.5) is None
    assert estimate_camera_lag(np.r_[-0.125, t], np.r_[1.0, change], t_onset_s=0.5) is not None  # three


def test_a_change_already_clear_at_the_windows_first_frame_has_no_lag():
    # The change clears its noise between the last baseline frame and the window's first (0.25 s): it left its
    # noise more than max_lag_s before the onset, no lag, not -max_lag_s.
    t = np.arange(0.0, 1.0, DT)
    change = np.where(t >= 0.25, 100.0, noisy_baseline(t.size))
    assert estimate_camera_lag(t, change, t_onset_s=0.5) is None


def test_a_still_baseline_still_needs_more_than_rounding_to_be_left():
    # A baseline of exactly 1 has no spread; a change of 1e-7 is rounding, not contact: the lag is the ramp's.
    t = np.arange(0.0, 1.0, DT)
    change = np.where(t >= 0.625, 1.0 + 10.0 * (t - 0.625), 1.0)
    change[t == 0.5] = 1.0 + 1e-7
    lag = estimate_camera_lag(t, change, t_onset_s=0.5)
    assert lag == pytest.approx(0.125, abs=2 * DT)


def test_a_change_that_only_touches_its_level_does_not_leave_its_noise():
    # A baseline of exactly 0: the level is 1e-9; a frame at exactly that level, then back, is no departure.
    t = np.arange(0.0, 1.0, DT)
    change = np.where(t >= 0.625, 1.0, 0.0)
    change[t == 0.5] = 1e-9
    assert estimate_camera_lag(t, change, t_onset_s=0.5) == pytest.approx(0.125 - DT, abs=DT)


def test_a_lag_of_exactly_max_lag_is_a_lag():
    # Zero baseline (level 1e-9), a change of 2e-9 at 0.75 + 1/128 s after 0 at 0.75 - 1/128 s: it crosses at
    # 0.75 s exactly, max_lag_s after the onset: "within" max_lag_s.
    t = np.r_[np.arange(0.0, 0.75, DT), 0.75 - DT / 2, 0.75 + DT / 2]
    t = np.unique(t)
    change = np.where(t > 0.75, 2e-9, 0.0)
    assert estimate_camera_lag(t, change, t_onset_s=0.5, max_lag_s=0.25) == 0.25


# --------------------------------------------------------------------------- width lag


def test_width_reads_up_to_a_second_from_the_stop_count():
    # A read every 0.3 s: within half a second of the stop only two come before it; within a second, four.
    t = np.round(np.arange(-0.9, 0.91, 0.3), 10)
    assert estimate_width_lag(t, closing_until(t, 0.05), t_stop_s=0.0) == pytest.approx(0.05, abs=0.003)


def test_width_reads_more_than_a_second_from_the_stop_do_not():
    # The gripper sat open until 1.2 s before the stop, then closed: the reads before that are no part of the fit.
    t = np.round(np.arange(-3.0, 1.0, 0.01), 10) + 0.005
    w = np.where(t < -1.2, 0.08, closing_until(t, 0.05))
    assert estimate_width_lag(t, w, t_stop_s=0.0) == pytest.approx(0.05, abs=0.003)


def test_one_read_after_the_stop_is_too_few():
    t = np.r_[np.round(np.arange(-1.0, -0.1, 0.01), 10), 0.4]  # one read past the stop, none near it
    assert estimate_width_lag(t, closing_until(t, 0.05), t_stop_s=0.0) is None
    t2 = np.r_[t, 0.5]  # a second read past it: the hinge is placed
    assert estimate_width_lag(t2, closing_until(t2, 0.05), t_stop_s=0.0) == pytest.approx(0.05, abs=0.003)


def test_exactly_max_hinges_hinge_times_are_allowed():
    step_s = 2e-6
    assert (0.18 + WIDTH_LAG_SLACK_S) / step_s == MAX_HINGES  # "more than MAX_HINGES" is refused, this is not
    t = np.round(np.arange(-0.3, 0.5, 0.05), 10)
    lag = estimate_width_lag(t, closing_until(t, 0.1), t_stop_s=0.0, max_lag_s=0.18, step_s=step_s)
    assert lag == pytest.approx(0.1, abs=0.01)
