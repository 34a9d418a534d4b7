"""Width-lag edge cases: traces that never close, fingers that stop before the force peaks, and bad stop
times and options."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from estimator.errors import FitError
from estimator.lag import WIDTH_LAG_SLACK_S, estimate_width_lag
from estimator.measure import measure_grasp
from teleop.record import GRASP_DONE_EVENT, Samples

T = np.linspace(0.0, 1.0, 50)
CLOSING = np.where(T < 0.5, 0.05 - 0.02 * T, 0.04)  # closes at 20 mm/s, stops at 0.5 s


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
