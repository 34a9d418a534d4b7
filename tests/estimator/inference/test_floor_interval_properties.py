"""A hybrid estimate's reason and interval agree on the analytical floor: where the reason says the
distribution was floored at a lower bound, the interval's lower end is not below it (property tests of
:meth:`~estimator.inference.hybrid.HybridEstimator.estimate_sampled` over the real
:func:`~estimator.inference.distribution.describe_on_gel`, on a stand-in model; fast).

The floor is soft (it weights the mass below it by a leak) and the interval is calibrated about the
median, so the interval may reach below the floor; the reason must then not claim the floor."""

from __future__ import annotations

import math
import re

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from support.hybrid_stand_in import SETTINGS, gaussian, stand_in_answer

from estimator.estimate import Estimate

# What a reason says of a floor, and of a ceiling should one ever name one.
FLOORED = re.compile(r"floored at the (\w+) lower bound ([0-9.e+-]+) Pa")
CEILED = re.compile(r"(?:capped|ceiled|ceiling) at (?:the (\w+) upper bound )?([0-9.e+-]+) Pa")


def answer(probs, floor_log10: float, method: str, *, scale: float = 1.6, p_rigid: float = 0.5,
           gel_modulus_pa: float | None = None) -> Estimate:
    return stand_in_answer(probs, (floor_log10, method), scale=scale, p_rigid=p_rigid, gel_modulus_pa=gel_modulus_pa)


def assert_interval_respects_what_the_reason_names(est: Estimate) -> None:
    low, high = est.interval_pa
    for match in FLOORED.finditer(est.reason):
        floor_pa = float(match.group(2))
        assert low is not None and low >= floor_pa, (
            f"interval {est.interval_pa} reaches below the floor the reason names ({floor_pa:g} Pa): {est.reason}")
    for match in CEILED.finditer(est.reason):
        ceiling_pa = float(match.group(2))
        assert high is not None and high <= ceiling_pa, (
            f"interval {est.interval_pa} reaches above the ceiling the reason names ({ceiling_pa:g} Pa): {est.reason}")


def test_the_observed_grasp_does_not_claim_a_floor_its_interval_ignores():
    # As the live rubber_duck grasp at 20 N: answer above the no_tactile bound 7.11e5 Pa, its calibrated
    # interval (about the median) reaching below it (here to ~4.2e5 Pa).
    est = answer(gaussian(6.1, 0.3), math.log10(7.11e5), "no_tactile")
    assert est.state == "ok" and est.e_pa > 7.11e5 and est.interval_pa[0] < 7.11e5
    assert_interval_respects_what_the_reason_names(est)
    assert "floored at" not in est.reason
    assert ("the no_tactile lower bound 7.11e+05 Pa weighted the distribution's mass below it by the floor's leak "
            "0.01; the interval, calibrated about the median, still reaches below that bound") in est.reason


def test_a_floor_above_the_resolution_limit_is_not_said_to_floor_a_bound_stated_below_it():
    limit = SETTINGS.resolution_limit_pa
    est = answer(gaussian(7.5, 0.2), math.log10(limit * 1.3), "series")
    assert est.state == "lower_bound" and est.interval_pa == (limit, None)
    assert_interval_respects_what_the_reason_names(est)
    assert "it lies above the sensor's resolution limit, where the bound is stated" in est.reason


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(mean_a=st.floats(3.0, 9.5), sd_a=st.floats(0.03, 1.2), mean_b=st.floats(3.0, 9.5), sd_b=st.floats(0.03, 1.2),
       share_b=st.floats(0.0, 0.5), floor_log10=st.floats(3.0, 8.5), method=st.sampled_from(("series", "no_tactile")),
       scale=st.floats(0.5, 4.0), p_rigid=st.floats(0.3, 0.95),
       gel_modulus_pa=st.one_of(st.none(), st.floats(2.0e5, 3.5e5)))
def test_a_floor_the_reason_names_is_respected_by_the_interval(mean_a, sd_a, mean_b, sd_b, share_b, floor_log10,
                                                               method, scale, p_rigid, gel_modulus_pa):
    probs = (1.0 - share_b) * gaussian(mean_a, sd_a) + share_b * gaussian(mean_b, sd_b)
    est = answer(probs, floor_log10, method, scale=scale, p_rigid=p_rigid, gel_modulus_pa=gel_modulus_pa)
    assert est.state != "insufficient_data" and f"the {method} lower bound" in est.reason
    assert_interval_respects_what_the_reason_names(est)
