"""The Estimate value: its invariants and its JSON form."""

from __future__ import annotations

import json
import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from estimator.errors import FitError
from estimator.estimate import Estimate


def test_ok_estimate_round_trips_to_json():
    est = Estimate.ok("series", 2.0e6, 1.5e6, 3.0e6, "fit").with_latency(0.012)
    assert est
    data = json.loads(json.dumps(est.to_json()))
    assert data == {
        "method": "series", "E_pa": 2.0e6, "interval_pa": [1.5e6, 3.0e6], "state": "ok",
        "reason": "fit", "latency_ms": pytest.approx(12.0),
    }


def test_bounds_have_one_open_side_and_carry_the_bound():
    low = Estimate.at_least("hertz", 5e7, "rigid")
    high = Estimate.at_most("series", 1e3, "soft")
    assert low.to_json()["interval_pa"] == [5e7, None] and low.e_pa == 5e7
    assert high.to_json()["interval_pa"] == [None, 1e3] and high.e_pa == 1e3
    assert low and high


def test_refusal_is_falsy_and_needs_a_reason():
    refusal = Estimate.refuse("elastic", "no contact")
    assert not refusal
    assert refusal.to_json()["E_pa"] is None and refusal.to_json()["interval_pa"] == [None, None]
    with pytest.raises(FitError, match="must say why"):
        Estimate.refuse("elastic", "")


@pytest.mark.parametrize(
    "kwargs",
    [
        {"e_pa": math.nan, "interval_pa": (1.0, 2.0), "state": "ok"},
        {"e_pa": -1.0, "interval_pa": (1.0, 2.0), "state": "ok"},
        {"e_pa": math.inf, "interval_pa": (1.0, None), "state": "lower_bound"},
        {"e_pa": 1.5, "interval_pa": (1.0, math.inf), "state": "ok"},
        {"e_pa": 3.0, "interval_pa": (1.0, 2.0), "state": "ok"},
        {"e_pa": 1.5, "interval_pa": (1.0, None), "state": "ok"},
        {"e_pa": 2.0, "interval_pa": (1.0, None), "state": "lower_bound"},
        {"e_pa": 0.0, "interval_pa": (None, 0.0), "state": "upper_bound"},
        {"e_pa": 1.0, "interval_pa": (None, None), "state": "insufficient_data"},
        {"e_pa": 1.0, "interval_pa": (1.0, 1.0), "state": "maybe"},
        {"e_pa": None, "interval_pa": (1.0, 2.0), "state": "ok"},
    ],
)
def test_invalid_estimates_cannot_be_built(kwargs):
    with pytest.raises(FitError):
        Estimate(method="x", reason="r", **kwargs)


@pytest.mark.parametrize("latency_s", [-0.1, math.inf, math.nan])
def test_a_negative_or_unbounded_latency_is_refused(latency_s):
    with pytest.raises(FitError, match="latency"):
        Estimate.ok("x", 1.0, 1.0, 1.0).with_latency(latency_s)


@given(st.floats(allow_nan=True, allow_infinity=True), st.floats(allow_nan=True, allow_infinity=True))
def test_any_built_estimate_is_finite_and_positive(e_pa, low):
    try:
        est = Estimate.at_least("x", low, "r") if e_pa != e_pa else Estimate.ok("x", e_pa, low, max(e_pa, low))
    except FitError:
        return
    values = [v for v in (est.e_pa, *est.interval_pa) if v is not None]
    assert all(math.isfinite(v) and v > 0 for v in values)
