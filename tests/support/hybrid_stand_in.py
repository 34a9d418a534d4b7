"""A stand-in for the learned model behind the hybrid's answer (fast: no trained model): a fixed
distribution of log10 E and a fixed analytical floor, described by the real
:func:`~estimator.inference.distribution.describe_on_gel`."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
from scipy.stats import norm

from estimator.estimate import Estimate
from estimator.inference.distribution import EDGES_LOG10, describe_on_gel
from estimator.inference.hybrid import HybridEstimator
from estimator.inference.sampling import SampledGrasp
from estimator.settings import estimator_settings
from teleop.settings import Settings

SETTINGS = Settings()
SOFT_PA = 3.5e3


def gaussian(mean: float, sd: float) -> np.ndarray:
    """Bin probabilities of a normal distribution of log10 E."""
    return np.diff(norm.cdf(EDGES_LOG10, mean, sd))


class StandInPredictor:
    """The parts of a CompliancePredictor the hybrid's answer reads: a fixed distribution and floor
    (``floor``: log10 Pa and the method, or a method of None for none)."""

    def __init__(self, probs: np.ndarray, floor: tuple[float, str | None], *, scale: float = 1.0,
                 p_rigid: float = 0.9):
        self.probs, self._floor, self.scale, self.p_rigid = probs, floor, scale, p_rigid
        self.variant = SimpleNamespace(method="hybrid", name="stand-in", n_frames=3, window_m=None)
        self.depth_binning = estimator_settings(SETTINGS).depth_binning
        self.metadata = SimpleNamespace(raw={}, floor_leak=0.01, p_rigid_at=lambda _f: p_rigid,
                                        force_band_at=lambda _f: "at any force")
        self.interval_level, self.rig_range, self.calibration_smoothing_px = 0.9, {}, (0.0,)

    def predict_distribution(self, _items):
        return [self.probs]

    def floor(self, _item):
        return self._floor

    def describe(self, probs, *, limit_pa, peak_force_n, widen=1.0, gel_scale=1.0):
        return describe_on_gel(probs, scale=self.scale, limit_pa=limit_pa, soft_pa=SOFT_PA, p_rigid=self.p_rigid,
                               gel_scale=gel_scale, widen=widen)


def stand_in_answer(probs: np.ndarray, floor: tuple[float, str | None], *, scale: float = 1.0, p_rigid: float = 0.9,
                    gel_modulus_pa: float | None = None) -> Estimate:
    """The hybrid's answer on the stand-in, with the floor's method's bound among the analytical estimates."""
    floor_log10, method = floor
    bound = (Estimate.at_least(method, 10.0 ** floor_log10, "stand-in") if method
             else Estimate.refuse("series", "-"))
    sampled = SampledGrasp(estimates=(bound,), force_n=np.array([1.0, 5.0, 10.0]), gel_modulus_pa=gel_modulus_pa)
    predictor = StandInPredictor(probs, floor, scale=scale, p_rigid=p_rigid)
    return HybridEstimator(predictor, settings=SETTINGS).estimate_sampled(sampled)
