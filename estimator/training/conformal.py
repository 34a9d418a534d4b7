"""The conformal step: fit a trained model's answers to its validation grasps (torch-free).

:func:`fit_conformal` turns a model's logits on the validation objects into the run-time calibration
that ``metadata.json`` ``calibration`` holds (:mod:`estimator.inference.infer`), and scores it there:

* for a model that reads the analytical estimates, their reliable lower bounds
  (:data:`~estimator.inference.inputs.FLOOR_METHODS`) floor its distribution, leaving
  :data:`FLOOR_LEAK` of the mass below (:func:`~estimator.inference.distribution.floor_log_weights`);
* a temperature on the logits, minimising the log score under that floor;
* per band of the grasp's peak force (:data:`FORCE_BAND_EDGES_N`): the probability of E at or
  above the resolution limit from which the answer is a lower bound (the smallest of
  :data:`P_RIGID_CHOICES` at which the band's lower bounds hold at :data:`INTERVAL_LEVEL`), and the
  interval's half-width in spreads of the distribution: the smallest at which the band's answers,
  described with it, hold the truth on :data:`INTERVAL_LEVEL` of its grasps (split conformal),
  bounds included: the level is a promise about every answer the operator gets, light grasp or
  firm. The width also decides states (an interval wholly above the limit is a lower bound), so
  the answers are described anew at each width tried. The ``ok`` intervals alone hold the truth at
  ``ok_levels`` (the bounds' surplus lets them be narrower), never below :data:`OK_LEVEL_FLOOR`. A band with fewer than
  :data:`MIN_BAND_GRASPS` grasps takes what is fitted on all of them.

:func:`described` answers each grasp exactly as the estimator does
(:meth:`~estimator.inference.infer.CompliancePredictor.describe`), so what calibration scores is
what the operator is shown.
"""

from __future__ import annotations

import logging
import math
from typing import Any

import numpy as np

from estimator.errors import EstimatorError
from estimator.inference.distribution import (
    Described,
    censor,
    describe_on_gel,
    fit_temperature,
    floor_log_weights,
    force_band,
    interval_score,
    probabilities,
)
from estimator.inference.infer import force_bands
from estimator.inference.inputs import FLOOR_METHODS

__all__ = ["FLOOR_LEAK", "FORCE_BAND_EDGES_N", "INTERVAL_LEVEL", "MIN_BAND_GRASPS", "OK_LEVEL_FLOOR",
           "P_RIGID_CHOICES", "described", "fit_conformal", "holds"]

log = logging.getLogger(__name__)

INTERVAL_LEVEL = 0.9
P_RIGID_CHOICES = (0.5, 0.6, 0.7, 0.8, 0.9, 0.95, 0.98)
#: The least an ``ok`` interval alone promises, whatever the bounds' surplus coverage.
OK_LEVEL_FLOOR = 0.8
#: Edges (N) of the peak grasp force bands that each get their own interval scale. On the shipped
#: models' validation grasps one scale covered 82 % below 10 N and 92 % from 20 N (cross-validated
#: by object); the target forces of the randomized rigs span 5-30 N.
FORCE_BAND_EDGES_N = (10.0, 20.0)
#: The share of a hybrid's distribution left below the analytical floor: about the share of the
#: :data:`~estimator.inference.inputs.FLOOR_METHODS`' lower bounds that fail (module notes).
FLOOR_LEAK = 0.01
#: The fewest validation grasps a force band's own ``p_rigid`` and interval scale are fitted on.
MIN_BAND_GRASPS = 100
#: The narrowest interval scale (spreads) fitted: an answer's interval has a positive width.
MIN_SCALE = 1e-3
#: A scale (spreads) at which every interval reaches below the resolution limit.
WIDEST_SCALE = 1e6


def _log_weights(calibration: dict[str, Any], floors_log10: np.ndarray | None) -> np.ndarray | None:
    """The analytical floor's log weights under ``calibration`` (None for a calibration without one)."""
    floor = calibration.get("floor")
    if not floor:
        return None
    if floors_log10 is None:
        raise EstimatorError("a calibration with an analytical floor needs each grasp's floor")
    return floor_log_weights(floors_log10, leak=floor["leak"])


def described(logits: np.ndarray, calibration: dict[str, Any], gel_scales: np.ndarray, peak_forces_n: np.ndarray,
               floors_log10: np.ndarray | None = None) -> list[Described]:
    """What each distribution says under ``calibration`` (temperature, analytical floor, ``p_rigid`` and
    interval scale per force band, soft_pa, limit_pa) for grasps on gels of ``gel_scales`` with peak
    forces ``peak_forces_n`` (N) and analytical floors ``floors_log10`` (:attr:`~estimator.training.splits.SplitData.floors_log10`),
    in their gels' moduli: exactly what the estimator answers
    (:meth:`~estimator.inference.infer.CompliancePredictor.describe`)."""
    probs = probabilities(logits, temperature=calibration["temperature"],
                          log_weights=_log_weights(calibration, floors_log10))
    edges, p_rigids, scales = force_bands(calibration)
    bands = force_band(peak_forces_n, edges)
    return [describe_on_gel(p, scale=scales[b], limit_pa=calibration["limit_pa"], soft_pa=calibration["soft_pa"],
                            p_rigid=p_rigids[b], gel_scale=float(g))
            for p, g, b in zip(probs, gel_scales, bands, strict=True)]


def fit_conformal(logits: np.ndarray, log10_truth: np.ndarray, *, gel_scales: np.ndarray, peak_forces_n: np.ndarray,
                  soft_pa: float, limit_pa: float, floors_log10: np.ndarray | None = None, level: float = INTERVAL_LEVEL,
                  force_band_edges_n: tuple[float, ...] = FORCE_BAND_EDGES_N) -> dict[str, Any]:
    """The run-time calibration fitted on validation grasps (module notes), with what it scores there.

    ``log10_truth`` are the labels on the reference gel, ``gel_scales`` each grasp's
    :func:`~estimator.inference.inputs.gel_scale`, ``peak_forces_n`` its peak grasp force (N),
    ``soft_pa`` the softest training label on the reference gel and ``limit_pa`` the resolution limit
    of the settings the estimator runs with (Pa): each grasp is answered as the estimator would answer
    it (:func:`described`). ``floors_log10`` (a hybrid model's: :attr:`~estimator.training.splits.SplitData.floors_log10`) makes
    the analytical lower bounds a floor on the distribution, leaking :data:`FLOOR_LEAK` below it.

    The temperature minimises the log score of the censored truths (under the floor, if any). Then,
    in each band of ``force_band_edges_n``: ``p_rigid`` is the smallest of :data:`P_RIGID_CHOICES` at
    which the band's lower bounds hold on at least ``level`` of the grasps they answer, and the
    interval scale the smallest of the band's interval scores at which its answers hold on
    ``level`` of its grasps (split conformal: ``ceil((n + 1) level)`` of them) and its ``ok``
    intervals on at least :data:`OK_LEVEL_FLOOR` of theirs; ``ok_level`` is the split-conformal
    level those ``ok`` intervals meet. Where no scale does, the widest score is taken (at least
    one spread), ``ok_level`` 1, and a warning says so. A band with fewer than
    :data:`MIN_BAND_GRASPS` grasps takes what is fitted on all of them.

    Returns ``temperature``, ``floor`` (``{"methods", "leak"}``, or None), ``level``,
    ``force_band_edges_n``, ``p_rigids``, ``interval_scales`` and ``ok_levels`` (per band),
    ``soft_pa``, ``limit_pa`` (the resolution limit it was fitted at), ``chosen_on`` and the
    validation figures: ``n``, ``n_ok``, ``ok_coverage`` (share of ``ok`` intervals holding the
    truth), ``bound_coverage`` (share of bounds the truth satisfies), ``coverage`` (all of them) and
    ``band_n``, ``band_coverage`` (per band)."""
    gel_scales = np.asarray(gel_scales, dtype=np.float64)
    truth_pa = 10.0 ** np.asarray(log10_truth, dtype=np.float64) / gel_scales
    edges = tuple(float(v) for v in force_band_edges_n)
    bands = force_band(peak_forces_n, edges)
    floor = None if floors_log10 is None else {"methods": list(FLOOR_METHODS), "leak": FLOOR_LEAK}
    log_weights = _log_weights({"floor": floor}, floors_log10)
    temperature = fit_temperature(logits, censor(log10_truth), log_weights=log_weights)
    probs = probabilities(logits, temperature=temperature, log_weights=log_weights)
    scores = interval_score(probs, log10_truth)
    common = {"temperature": temperature, "floor": floor, "level": level, "soft_pa": soft_pa, "limit_pa": limit_pa}

    limits = {"limit_pa": limit_pa, "soft_pa": soft_pa}
    fitted: dict[bytes, tuple[float, float, float]] = {}

    def fit(grasps: np.ndarray) -> tuple[float, float, float]:
        key = np.packbits(grasps).tobytes()  # a band of every grasp is the fit on all of them
        if key not in fitted:
            which = np.flatnonzero(grasps)
            fitted[key] = _fit_band(probs[which], truth_pa[which], scores[which], gel_scales[which], level=level,
                                    **limits)
        return fitted[key]

    per_band = [fit(bands == b) if (bands == b).sum() >= MIN_BAND_GRASPS else fit(np.ones(bands.size, dtype=bool))
                for b in range(len(edges) + 1)]
    calibration = {**common, "force_band_edges_n": list(edges), "p_rigids": [p for p, _, _ in per_band],
                   "interval_scales": [s for _, s, _ in per_band], "ok_levels": [q for _, _, q in per_band],
                   "chosen_on": "val"}
    said = described(logits, calibration, gel_scales, peak_forces_n, floors_log10)
    held = np.array([holds(d, t) for d, t in zip(said, truth_pa, strict=True)], dtype=bool)
    ok = np.array([d.state == "ok" for d in said], dtype=bool)
    calibration.update(n=int(held.size), n_ok=int(ok.sum()),
                       ok_coverage=float(held[ok].mean()) if ok.any() else None,
                       bound_coverage=float(held[~ok].mean()) if (~ok).any() else None,
                       coverage=float(held.mean()) if held.size else None,
                       band_n=[int((bands == b).sum()) for b in range(len(edges) + 1)],
                       band_coverage=[float(held[bands == b].mean()) if (bands == b).any() else None
                                      for b in range(len(edges) + 1)])
    return calibration


def _fit_band(probs: np.ndarray, truth_pa: np.ndarray, scores: np.ndarray, gel_scales: np.ndarray, *, level: float,
              limit_pa: float, soft_pa: float) -> tuple[float, float, float]:
    """(p_rigid, interval scale, ok_level) fitted on one band's grasps (:func:`fit_conformal`)."""
    needed = math.ceil((truth_pa.size + 1) * level)  # held answers, split conformal, bounds included

    def answers(p_rigid: float, scale: float, which: np.ndarray) -> list[tuple[str, bool]]:
        """(state, whether it holds) of the grasps ``which``."""
        said = (describe_on_gel(probs[i], scale=scale, p_rigid=p_rigid, gel_scale=float(gel_scales[i]),
                                limit_pa=limit_pa, soft_pa=soft_pa) for i in which)
        return [(d.state, holds(d, float(truth_pa[i]))) for i, d in zip(which, said, strict=True)]

    def enough(said: list[tuple[str, bool]]) -> bool:
        ok_held = [h for state, h in said if state == "ok"]
        return (sum(h for _, h in said) >= needed
                and (not ok_held or sum(ok_held) >= math.ceil((len(ok_held) + 1) * OK_LEVEL_FLOOR)))

    for p_rigid in P_RIGID_CHOICES:
        # An answer that is no ok interval at the widest scale is the same bound at every scale; the
        # others are ok intervals, or lower bounds while narrow enough to lie wholly above the limit.
        widest = answers(p_rigid, WIDEST_SCALE, np.arange(truth_pa.size))
        varies = np.array([state == "ok" for state, _ in widest], dtype=bool)
        fixed = [a for a, v in zip(widest, varies, strict=True) if not v]
        which = np.flatnonzero(varies)
        # An ok interval holds from its own score on (a hair above it, for rounding): the smallest scale is one.
        candidates = np.unique(np.maximum(scores[which] * (1.0 + 1e-9), MIN_SCALE))
        lo, hi = 0, candidates.size - 1
        # First where the ok intervals alone would just make up the level, and just below: usually the answer.
        guess = needed - sum(h for _, h in fixed) - 1
        for mid in (guess, guess - 1):
            if lo <= mid < hi:
                lo, hi = (lo, mid) if enough(fixed + answers(p_rigid, float(candidates[mid]), which)) else (mid + 1, hi)
        while lo < hi:
            mid = (lo + hi) // 2
            lo, hi = (lo, mid) if enough(fixed + answers(p_rigid, float(candidates[mid]), which)) else (mid + 1, hi)
        scale = float(candidates[lo]) if candidates.size else 1.0
        said = fixed + answers(p_rigid, scale, which)
        bounds = [h for state, h in said if state == "lower_bound"]
        # p_rigid decides which answers are lower bounds: an upper bound that fails is no reason
        # for a stricter one, and none would make it hold.
        if not bounds or np.mean(bounds) >= level:
            break
    if not enough(said):
        scale = max(scale, 1.0)
        log.warning("%d validation grasps are too few, or their bounds fail too often, to promise a %.0f%% interval; "
                    "the interval takes the widest of them (%.2f spreads): add validation objects", truth_pa.size,
                    100 * level, scale)
        return p_rigid, scale, 1.0
    ok_held = [h for state, h in said if state == "ok"]
    # The split-conformal level the ok intervals alone meet at this scale (the floor, where there are none).
    return p_rigid, scale, max(min(sum(ok_held) / (len(ok_held) + 1), 1.0), OK_LEVEL_FLOOR)


def holds(said: Described, truth_pa: float) -> bool:
    """Whether the truth (Pa) satisfies an answer: inside its interval, an open side included."""
    return (said.low_pa is None or said.low_pa <= truth_pa) and (said.high_pa is None or truth_pa <= said.high_pa)
