"""The Estimate value, audited: both sides of its interval, its notes, its JSON form for numpy numbers,
and the choice among methods."""

from __future__ import annotations

import json

import numpy as np
import pytest

from estimator.errors import FitError
from estimator.estimate import Estimate, choose_estimate


@pytest.mark.parametrize("interval_pa", [(1.0,), (1.0, 2.0, 3.0)])
def test_an_interval_that_is_not_a_pair_is_refused_as_a_fit_error(interval_pa):
    with pytest.raises(FitError, match="must be \\(low, high\\)"):
        Estimate("x", 1.5, interval_pa, "ok", "r")


def test_a_modulus_below_its_interval_is_refused():
    with pytest.raises(FitError, match="outside interval_pa"):
        Estimate.ok("x", 0.5, 1.0, 2.0)


def test_an_upper_bound_must_carry_its_bound_as_the_modulus():
    with pytest.raises(FitError, match="must equal the bound"):
        Estimate("x", 1.0, (None, 2.0), "upper_bound", "soft")


def test_an_empty_note_leaves_the_estimate_as_it_is():
    est = Estimate.ok("x", 2.0, 1.0, 3.0, "fit")
    assert est.with_note("") is est


def test_a_note_follows_the_reason_after_a_semicolon_or_stands_alone():
    assert Estimate.ok("x", 2.0, 1.0, 3.0, "fit").with_note("widened").reason == "fit; widened"
    assert Estimate.ok("x", 2.0, 1.0, 3.0).with_note("widened").reason == "widened"


def test_numpy_numbers_become_plain_floats_and_serialise_to_json():
    est = Estimate.ok("x", np.float32(2e6), np.float32(1e6), np.int64(3_000_000)).with_latency(np.float32(0.5))
    assert all(type(v) is float for v in (est.e_pa, *est.interval_pa, est.latency_s))
    data = json.loads(json.dumps(est.to_json()))
    assert data["interval_pa"] == [1e6, 3e6] and data["E_pa"] == pytest.approx(2e6)
    assert data["latency_ms"] == pytest.approx(500.0)


def test_an_upper_bound_serialises_with_an_open_low_side():
    assert Estimate.at_most("x", 1e3, "soft").to_json()["interval_pa"] == [None, 1e3]


def test_choosing_among_no_estimates_is_refused():
    with pytest.raises(FitError, match="at least one"):
        choose_estimate([])


def test_the_first_answer_is_chosen_even_a_bound_after_a_refusal():
    bound = Estimate.at_least("hertz", 1e9, "rigid")
    chosen = choose_estimate([Estimate.refuse("series", "no contact"), bound, Estimate.ok("elastic", 2.0, 1.0, 3.0)])
    assert chosen is bound


def test_when_every_method_refuses_the_refusal_names_the_first_method_and_every_reason():
    chosen = choose_estimate([Estimate.refuse("series", "no contact"), Estimate.refuse("hertz", "no depth")])
    assert not chosen and chosen.method == "series"
    assert chosen.reason == "every method refuses (series: no contact; hertz: no depth)"
