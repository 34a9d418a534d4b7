"""Width-lag edge cases: traces that never close, fingers that stop before the force peaks or after the
search window, sparse reads, and bad stop times and options; where the camera lag's change clears its
noise, and how much no-contact baseline it needs."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from estimator.errors import FitError
from estimator.lag import WIDTH_LAG_SLACK_S, estimate_camera_lag, estimate_width_lag
from estimator.load_phase import ONSET_SIGMAS
from estimator.measure import measure_grasp
from teleop.record import GRASP_DONE_EVENT, Samples

T = np.linspace(0.0, 1.0, 50)
CLOSING = np.where(T < 0.5, 0.05 - 0.02 * T, 0.04)  # closes at 20 mm/s, stops at 0.5 s


def closing_until(t, stop_s, *, speed_m_s=0.02, stopped_width_m=0.04):
    """Widths closing at ``speed_m_s`` until ``stop_s``, then still at ``stopped_width_m``."""
    return stopped_width_m + speed_m_s * np.maximum(stop_s - t, 0.0)


def test_a_width_trace_that_never_closes_has_no_lag():
    rng = np.random.default_rng(5)
    assert estimate_width_lag(T, np.full(50, 0.04), t_stop_s=0.5) is None
    assert estimate_width_lag(T, 0.04 + rng.normal(0, 1e-6, 50), t_stop_s=0.5) is None
    # The commanded speed assumes a closing; the reads must still show one.
    late = np.linspace(0.35, 1.0, 30)
    assert estimate_width_lag(late, 0.04 + rng.normal(0, 1e-5, 30), t_stop_s=0.5, speed_m_s=0.0375) is None
    assert estimate_width_lag(T, CLOSING, t_stop_s=0.5) == pytest.approx(0.0, abs=0.01)


@pytest.mark.parametrize("t_stop_s", [float("nan"), float("inf"), -float("inf")])
def test_a_stop_time_that_is_not_finite_has_no_lag(t_stop_s):
    assert estimate_width_lag(T, CLOSING, t_stop_s=t_stop_s) is None


@pytest.mark.parametrize(("options", "named"), [
    ({"max_lag_s": float("nan")}, "max_lag_s"),
    ({"max_lag_s": 0.0}, "max_lag_s"),
    ({"step_s": float("nan")}, "step_s"),
    ({"step_s": 0}, "step_s"),
    ({"step_s": -0.002}, "step_s"),
    ({"step_s": 1e-12}, "step_s"),
    ({"step_s": None}, "step_s"),
    ({"speed_m_s": float("inf")}, "speed_m_s"),
    ({"t_stop_s": None}, "t_stop_s"),
    ({"t_stop_s": "0.5"}, "t_stop_s"),
])
def test_bad_width_lag_options_are_refused_by_name(options, named):
    with pytest.raises(FitError, match=named):
        estimate_width_lag(T, CLOSING, **{"t_stop_s": 0.5, **options})


@pytest.mark.parametrize("speed_m_s", [None, 0.02])
def test_fingers_that_stop_before_the_force_peaks_have_no_lag(speed_m_s):
    # The fingers stop 0.2 s before the peak: a stamp taken late cannot make a width early.
    assert estimate_width_lag(T, CLOSING, t_stop_s=0.7, speed_m_s=speed_m_s) is None
    assert estimate_width_lag(T, CLOSING, t_stop_s=0.5 - 0.15, speed_m_s=speed_m_s) == pytest.approx(0.15, abs=0.01)


def test_a_zero_lag_fitted_a_little_early_is_zero():
    assert estimate_width_lag(T, CLOSING, t_stop_s=0.5 + WIDTH_LAG_SLACK_S / 2) == 0.0


def test_an_operator_grasp_whose_fingers_stop_early_keeps_its_width_times(records, settings):
    # No gripper stop reported (as an operator drives the fingers), widths read 0.3 s early: the
    # fingers stop about 0.2 s before the force peaks, which no stamping lag explains.
    record = records["steel_ball_bearing"]
    events = {name: t for name, t in record.events.items() if name != GRASP_DONE_EVENT}
    operated = dataclasses.replace(record, events=events)
    assert measure_grasp(operated, settings=settings, tactile=False, correct_width_lag=True).width_lag_s > 0.05
    early = dataclasses.replace(operated, width_m=Samples(record.width_m.t_s - 0.3, record.width_m.value))
    assert measure_grasp(early, settings=settings, tactile=False, correct_width_lag=True).width_lag_s is None


def test_a_lag_just_inside_max_lag_is_found():
    t = np.arange(0.0, 1.5, 0.01)
    lag = estimate_width_lag(t, closing_until(t, 0.5 + 0.298), t_stop_s=0.5, max_lag_s=0.3)
    assert lag == pytest.approx(0.298, abs=0.0015)  # one step inside the search


def test_fingers_that_stop_after_max_lag_have_no_lag():
    t = np.arange(0.0, 1.5, 0.01)
    assert estimate_width_lag(t, closing_until(t, 0.5 + 0.5), t_stop_s=0.5, max_lag_s=0.3) is None


def test_sparse_width_reads_over_the_last_second_give_the_lag():
    t = np.round(np.arange(-1.0, 0.61, 0.2), 10)  # a read every 0.2 s around a stop at 0
    assert estimate_width_lag(t, closing_until(t, 0.05), t_stop_s=0.0) == pytest.approx(0.05, abs=0.003)


def test_two_reads_before_the_stop_are_too_few():
    t = np.r_[-0.2, -0.1, np.arange(0.4, 1.0, 0.01)]  # no read between -0.1 s and the search's end
    assert estimate_width_lag(t, closing_until(t, 0.1), t_stop_s=0.0) is None


def test_the_hinge_count_limit_counts_the_slack():
    # 0.3 / 3e-6 = 100000 hinges on [0, max_lag_s], more with the slack below 0: too fine.
    t = np.arange(0.0, 1.0, 0.01)
    with pytest.raises(FitError, match="step_s"):
        estimate_width_lag(t, closing_until(t, 0.5), t_stop_s=0.5, max_lag_s=0.3, step_s=3e-6)


# --------------------------------------------------------------------------- camera lag


def test_camera_lag_is_where_the_change_clears_onset_sigmas():
    t = np.arange(0.0, 1.0, 0.01)
    d = 0.01
    change = 1.0 + d * (np.arange(t.size) % 3 - 1.0)  # baseline 1: -d, 0, +d in turn, so a MAD of d
    change = np.where(t >= 0.6, 1.0 + 0.5 * (t - 0.6), change)  # tactile change ramps from 0.6 s at 0.5 /s
    lag = estimate_camera_lag(t, change, t_onset_s=0.555)
    assert lag == pytest.approx(0.6 + ONSET_SIGMAS * 1.4826 * d / 0.5 - 0.555, abs=1e-9)


def test_camera_lag_needs_three_no_contact_frames():
    t = np.r_[0.0, 0.1, np.arange(0.4, 1.0, 0.01)]  # two frames before onset - max_lag (0.55 - 0.25)
    change = np.where(t >= 0.6, 1.0 + 5.0 * (t - 0.6), 1.0)
    assert estimate_camera_lag(t, change, t_onset_s=0.55) is None


def test_camera_change_before_the_window_gives_no_lag():
    # The change leaves its noise 0.26 s before the force onset: beyond max_lag_s (0.25) early, no lag.
    t = np.round(np.arange(0.0, 1.0, 0.02), 10)
    change = np.where(t >= 0.36, 100.0, 1.0 + np.where(np.arange(t.size) % 2 == 0, 0.01, -0.01))
    assert estimate_camera_lag(t, change, t_onset_s=0.6) is None
