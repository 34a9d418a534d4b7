"""Width-lag edge cases: traces that never close, and bad stop times and options."""

from __future__ import annotations

import numpy as np
import pytest

from estimator.errors import FitError
from estimator.lag import estimate_width_lag

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
