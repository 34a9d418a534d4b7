"""What the hybrid's reason says of its answer, on a stand-in model (fast: no trained model): the
floor of the analytical lower bounds, and an interval wholly above the resolution limit."""

from __future__ import annotations

import math

import numpy as np
from support.hybrid_stand_in import SETTINGS, SOFT_PA, gaussian, stand_in_answer

from estimator.estimate import Estimate
from estimator.inference.distribution import describe

LIMIT_PA = SETTINGS.resolution_limit_pa
P_RIGID = 0.9  # the stand-in's


def rigid_looking() -> np.ndarray:
    """Most mass near 1e8 Pa, a sliver far below: P(E >= limit) under P_RIGID, its interval above the limit."""
    return 0.88 * gaussian(8.0, 0.1) + 0.12 * gaussian(4.0, 0.1)


def answer(probs: np.ndarray, floor: tuple[float, str | None]) -> Estimate:
    return stand_in_answer(probs, floor, p_rigid=P_RIGID)


def test_an_interval_wholly_above_the_limit_is_a_lower_bound_at_it_not_a_number_above_it():
    said = describe(rigid_looking(), scale=1.0, limit_pa=LIMIT_PA, soft_pa=SOFT_PA, p_rigid=P_RIGID)
    assert said.p_above_limit < P_RIGID
    assert (said.state, said.e_pa, said.low_pa, said.high_pa) == ("lower_bound", LIMIT_PA, LIMIT_PA, None)
    est = answer(rigid_looking(), (-math.inf, None))
    assert (est.state, est.e_pa) == ("lower_bound", LIMIT_PA)
    assert "lies wholly above the sensor's resolution limit" in est.reason and f"< {P_RIGID:g}" in est.reason


def test_an_answer_below_the_floor_is_not_said_to_be_floored_there():
    floor_pa = 6.66e4
    est = answer(gaussian(4.0, 0.15), (math.log10(floor_pa), "series"))
    assert est.state == "ok" and est.interval_pa[1] < floor_pa
    assert "floored at" not in est.reason
    assert "the series lower bound 6.66e+04 Pa weighted the distribution's mass below it by the floor's leak 0.01, " \
           "yet the answer lies below that bound" in est.reason
    above = answer(gaussian(5.5, 0.15), (math.log10(floor_pa), "series"))
    assert above.e_pa > floor_pa and "its distribution floored at the series lower bound 6.66e+04 Pa" in above.reason
