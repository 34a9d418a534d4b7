"""What the hybrid's reason says of its answer, on a stand-in model (fast: no trained model): the
floor of the analytical lower bounds, and an interval wholly above the resolution limit."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
from scipy.stats import norm

from estimator.estimate import Estimate
from estimator.inference.distribution import EDGES_LOG10, describe, describe_on_gel
from estimator.inference.hybrid import HybridEstimator
from estimator.inference.sampling import SampledGrasp
from estimator.settings import estimator_settings
from teleop.settings import Settings

SETTINGS = Settings()
LIMIT_PA = SETTINGS.resolution_limit_pa
P_RIGID = 0.9


def gaussian(mean: float, sd: float) -> np.ndarray:
    """Bin probabilities of a normal distribution of log10 E."""
    return np.diff(norm.cdf(EDGES_LOG10, mean, sd))


def rigid_looking() -> np.ndarray:
    """Most mass near 1e8 Pa, a sliver far below: P(E >= limit) under P_RIGID, its interval above the limit."""
    return 0.88 * gaussian(8.0, 0.1) + 0.12 * gaussian(4.0, 0.1)


class StandInPredictor:
    """The parts of a CompliancePredictor the hybrid's answer reads, with a fixed distribution."""

    def __init__(self, probs: np.ndarray, floor: tuple[float, str | None]):
        self.probs, self._floor = probs, floor
        self.variant = SimpleNamespace(method="hybrid", name="stand-in", n_frames=3, window_m=None)
        self.depth_binning = estimator_settings(SETTINGS).depth_binning
        self.metadata = SimpleNamespace(raw={}, floor_leak=0.01, p_rigid_at=lambda _f: P_RIGID,
                                        force_band_at=lambda _f: "at any force")
        self.interval_level, self.rig_range, self.calibration_smoothing_px = 0.9, {}, (0.0,)

    def predict_distribution(self, _items):
        return [self.probs]

    def floor(self, _item):
        return self._floor

    def describe(self, probs, *, limit_pa, peak_force_n, widen=1.0, gel_scale=1.0):
        return describe_on_gel(probs, scale=1.0, limit_pa=limit_pa, soft_pa=3.5e3, p_rigid=P_RIGID,
                               gel_scale=gel_scale, widen=widen)


def answer(probs: np.ndarray, floor: tuple[float, str | None]) -> Estimate:
    series = Estimate.at_least("series", 10.0 ** floor[0], "stand-in") if floor[1] else Estimate.refuse("series", "-")
    sampled = SampledGrasp(estimates=(series,), force_n=np.array([1.0, 5.0, 10.0]))
    return HybridEstimator(StandInPredictor(probs, floor), settings=SETTINGS).estimate_sampled(sampled)


def test_an_interval_wholly_above_the_limit_is_a_lower_bound_at_it_not_a_number_above_it():
    said = describe(rigid_looking(), scale=1.0, limit_pa=LIMIT_PA, soft_pa=3.5e3, p_rigid=P_RIGID)
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
