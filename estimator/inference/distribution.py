"""The learned estimate as a predictive distribution over log10 E, and what it says (torch-free).

The network ends in logits over :data:`N_BINS` bins of log10 E, each
:data:`BIN_DECADES` wide, spanning :data:`~estimator.inference.inputs.LOG10_E_RANGE`
(1 kPa to 1 TPa); the probability is uniform within a bin, so the cumulative
distribution is piecewise linear in log10 E and every quantile is finite.
The distribution is of E censored at :data:`CENSOR_PA` (100 MPa, some 15 times
the shipped gel's resolution limit): a plastic, a wood and a metal deform the
gel alike, so the model is not asked to tell them apart, and training and
calibration see every label above it as that value (:func:`censor`).
Training minimises the continuous ranked probability score of the
distribution (a proper scoring rule that reduces to the absolute error for a
point mass) plus a small log score; a temperature fitted on the validation
objects then calibrates it (:func:`fit_temperature`). A hybrid model also
takes the analytical fits' most reliable lower bounds as evidence: below the
highest of them (:func:`~estimator.inference.inputs.analytical_floor`) its
mass is multiplied by a small leak, the share of such bounds that fail
(:func:`floor_log_weights`), before the temperature is fitted. The network
reads those bounds as inputs too, but does not always heed them
(``docs/decisions/0004-analytical-floor.md``).

From a distribution, :func:`describe` gives the estimate the operator is
shown:

* ``lower_bound`` at the sensor's resolution limit (``limit_pa``,
  :attr:`~teleop.settings.Settings.resolution_limit_pa`) when the probability
  that E is at least that limit reaches ``p_rigid``: the gel cannot tell
  stiffer objects apart, so no number above it is offered; ``p_rigid`` is
  chosen on the validation objects so that these bounds hold at the stated
  level. So is an answer whose calibrated interval (below) lies wholly above
  the limit while that probability stays under ``p_rigid``;
* ``upper_bound`` at ``soft_pa`` (the softest label the model was trained on)
  when the median is at or below it;
* otherwise ``ok``: the interval is ``m -/+ scale * s`` about the median ``m``
  of log10 E, where ``s`` is the distribution's spread
  (half its 16-84 % range, at least :data:`SPREAD_FLOOR_DECADES`;
  :func:`spread`) and ``scale`` is chosen on the validation objects so that
  the interval holds the truth at the stated level (split conformal on the
  normalised error :func:`interval_score`: :func:`conformal_scale`), one
  scale per band of the grasp's peak force (:func:`force_band`): a light
  grasp presses the gel less and its distribution is overconfident, so a
  single scale gave intervals too narrow there and too wide on firm grasps
  (Mondrian conformal: the level then holds within each band). The
  distribution's own quantiles are no interval to state: it puts its mass on
  the few moduli the training labels take, so its tails are lumpy, while its
  spread still says how sure the grasp is. An interval that reaches the
  censored value is open up to 1 TPa. The value is the point the display
  should render (:func:`hedged_point`, below).

The value of an ``ok`` answer
-----------------------------
The operator feels the value on a display that renders nothing stiffer than
the resolution limit, so what matters is the error in decades between the
rendered value and the truth, both clipped to ``[soft_pa, limit_pa]``. The
median of the clipped distribution minimises its expected size, but when the
distribution has mass both far below and far above it (a grasp that reads
like a stiff rubber or like a metal) the median sits in one mode and the
other mode's objects are felt badly wrong. The value minimises instead the
expected ``|d| + HEDGE_WEIGHT * max(0, |d| - HEDGE_FROM_DECADES)``: an error
beyond a factor of about 3 (0.5 decade, some 8 just-noticeable differences
at the 15 % Weber fraction of :mod:`haptics.mapping`) costs twice as much.
A unimodal distribution keeps about its median; a bimodal one is rendered
between its modes, no more wrong than a factor of about 3 either way, and its
wide interval says how unsure it is. The value stays within the answer's
calibrated interval; a grasp outside what the model was trained on has that
interval widened afterwards, which moves its ends and not the value.

The loss names no threshold of the evaluation's; the hedge's weight was
chosen on the validation objects by a rule fixed before the run, and a loss
that charged the dangerous misses themselves was tried and dropped
(``docs/decisions/0003-hedged-value.md``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.optimize import minimize_scalar
from scipy.special import log_softmax, softmax

from estimator.errors import ModelError
from estimator.inference.inputs import LOG10_E_RANGE

__all__ = [
    "BIN_DECADES",
    "CENSOR_PA",
    "EDGES_LOG10",
    "HEDGE_FROM_DECADES",
    "HEDGE_WEIGHT",
    "N_BINS",
    "SPREAD_FLOOR_DECADES",
    "Described",
    "bin_index",
    "censor",
    "conformal_scale",
    "describe",
    "describe_on_gel",
    "fit_temperature",
    "floor_log_weights",
    "force_band",
    "hedged_point",
    "interval_score",
    "probabilities",
    "quantile",
    "spread",
]

BIN_DECADES = 0.1
N_BINS = round((LOG10_E_RANGE[1] - LOG10_E_RANGE[0]) / BIN_DECADES)
EDGES_LOG10 = np.linspace(LOG10_E_RANGE[0], LOG10_E_RANGE[1], N_BINS + 1)
CENSOR_PA = 1e8
SPREAD_FLOOR_DECADES = BIN_DECADES / 2
#: An ``ok`` answer's value: errors beyond this many decades weigh ``1 + HEDGE_WEIGHT`` times (module notes).
HEDGE_FROM_DECADES = 0.5
HEDGE_WEIGHT = 1.0
#: Points at which :func:`hedged_point` evaluates the loss's slope across the interval.
_HEDGE_GRID = 1025


def censor(log10_e: np.ndarray) -> np.ndarray:
    """log10 E as the model learns it: values above log10 :data:`CENSOR_PA` become that value."""
    return np.minimum(np.asarray(log10_e, dtype=np.float64), math.log10(CENSOR_PA))


def probabilities(logits: np.ndarray, *, temperature: float = 1.0, log_weights: np.ndarray | None = None
                  ) -> np.ndarray:
    """Bin probabilities (B, N_BINS) of logits (B, N_BINS) divided by ``temperature``, times
    ``exp(log_weights)`` (B, N_BINS; :func:`floor_log_weights`) and normalised again, float64."""
    if not (math.isfinite(temperature) and temperature > 0):
        raise ModelError(f"temperature {temperature!r}: expected a finite value > 0")
    scaled = np.asarray(logits, dtype=np.float64) / temperature
    return softmax(scaled if log_weights is None else scaled + log_weights, axis=-1)


def floor_log_weights(floor_log10: np.ndarray, *, leak: float) -> np.ndarray:
    """Log weights (B, N_BINS) that keep a distribution's mass at or above each floor (log10 E, B) and
    leave ``leak`` (0 < leak <= 1) of it below: the share of analytical lower bounds that fail.
    A bin cut by the floor keeps the part above it; a floor of -inf keeps everything."""
    if not 0.0 < leak <= 1.0:
        raise ModelError(f"leak {leak!r}: expected 0 < leak <= 1")
    floor = np.asarray(floor_log10, dtype=np.float64)[:, None]
    above = np.clip((EDGES_LOG10[1:] - floor) / BIN_DECADES, 0.0, 1.0)
    return np.log(leak + (1.0 - leak) * above)


def _cdf_at_edges(probs: np.ndarray) -> np.ndarray:
    """(B, N_BINS + 1) cumulative probability at every bin edge (0 first, 1 last)."""
    cdf = np.cumsum(probs, axis=-1)
    cdf /= cdf[..., -1:]
    return np.concatenate([np.zeros((*cdf.shape[:-1], 1)), cdf], axis=-1)


def quantile(probs: np.ndarray, q: float | np.ndarray) -> np.ndarray:
    """log10 E at probability ``q`` of each distribution (B,) (or (B, len(q)) for an array ``q``)."""
    cdf = _cdf_at_edges(np.atleast_2d(probs))
    qs = np.atleast_1d(np.asarray(q, dtype=np.float64))
    out = np.stack([np.interp(qs, c, EDGES_LOG10) for c in _strictly_rising(cdf)])
    return out[:, 0] if np.ndim(q) == 0 else out


def _strictly_rising(cdf: np.ndarray) -> np.ndarray:
    """The CDF nudged to rise strictly, so that interpolating its inverse is defined at empty bins."""
    return cdf + np.linspace(0.0, 1e-12, cdf.shape[-1])


def cdf_at(probs: np.ndarray, log10_e: np.ndarray) -> np.ndarray:
    """P(log10 E <= log10_e) under each distribution (B,), for one value per distribution."""
    cdf = _cdf_at_edges(np.atleast_2d(probs))
    values = np.broadcast_to(np.asarray(log10_e, dtype=np.float64), (cdf.shape[0],))
    return np.array([np.interp(v, EDGES_LOG10, c) for v, c in zip(values, cdf, strict=True)])


def hedged_point(probs: np.ndarray, *, low: float, high: float, soft: float, limit: float) -> float | None:
    """The log10 E in ``[low, high]`` (an ``ok`` answer's interval) that minimises the expected
    ``|d| + HEDGE_WEIGHT * max(0, |d| - HEDGE_FROM_DECADES)`` under one distribution (N_BINS,), ``d``
    the difference of log10 values with E and the point both clipped to ``[soft, limit]`` (module
    notes). None when the interval does not meet ``[soft, limit]``.

    The expected loss is convex; its slope at ``v`` is ``2 F(v) - 1 + HEDGE_WEIGHT * (F(v - c) +
    F(v + c) - 1)`` with ``F`` the clipped distribution's CDF and ``c`` = HEDGE_FROM_DECADES, so the
    minimum is where that slope turns non-negative, found on a grid of :data:`_HEDGE_GRID` points
    across the interval and interpolated between them.
    """
    lo, hi = max(low, soft), min(high, limit)
    if lo > hi:
        return None
    cdf = _cdf_at_edges(np.atleast_2d(probs))[0]
    grid = np.linspace(lo, hi, _HEDGE_GRID)

    def clipped_cdf(x: np.ndarray) -> np.ndarray:
        return np.where(x >= limit, 1.0, np.where(x < soft, 0.0, np.interp(x, EDGES_LOG10, cdf)))

    slope = (2.0 * clipped_cdf(grid) - 1.0
             + HEDGE_WEIGHT * (clipped_cdf(grid - HEDGE_FROM_DECADES) + clipped_cdf(grid + HEDGE_FROM_DECADES) - 1.0))
    rising = np.flatnonzero(slope >= 0.0)
    if rising.size == 0:
        return float(hi)
    i = int(rising[0])
    # The slope jumps where F does: at the limit it often turns there, so the minimum lies exactly on
    # it (rendered rigid). Elsewhere interpolate its zero within the grid step, so that the value
    # moves continuously with the distribution.
    if i == 0 or (i == grid.size - 1 and hi == limit):
        return float(grid[i])
    before, after = slope[i - 1], slope[i]
    return float(grid[i - 1] + (grid[i] - grid[i - 1]) * -before / (after - before))


def bin_index(log10_e: np.ndarray) -> np.ndarray:
    """The bin of each log10 E, clipped to the first and last bin."""
    index = np.floor((np.asarray(log10_e, dtype=np.float64) - LOG10_E_RANGE[0]) / BIN_DECADES)
    return np.clip(index, 0, N_BINS - 1).astype(np.int64)


def spread(probs: np.ndarray) -> np.ndarray:
    """Half the 16-84 % range of log10 E of each distribution (B,), at least
    :data:`SPREAD_FLOOR_DECADES` (a normal distribution's standard deviation)."""
    q16, q84 = quantile(np.atleast_2d(probs), np.array([0.16, 0.84])).T
    return np.maximum((q84 - q16) / 2.0, SPREAD_FLOOR_DECADES)


def interval_score(probs: np.ndarray, log10_truth: np.ndarray) -> np.ndarray:
    """How many spreads the (censored) truth lies from each distribution's median (B,): the
    conformity score of :func:`conformal_scale`."""
    probs = np.atleast_2d(probs)
    return np.abs(censor(log10_truth) - quantile(probs, 0.5)) / spread(probs)


def conformal_scale(scores: np.ndarray, level: float) -> float:
    """Split-conformal scale: the ``ceil((n + 1) level) / n`` empirical quantile of the validation
    scores (:func:`interval_score`), so that a new grasp's interval of that many spreads about its
    median holds its truth with probability at least ``level`` (0 < level <= 1); infinite when there
    are too few (always at level 1, which calibration asks for when the bounds leave the ``ok``
    intervals everything to hold). A ModelError for any other level."""
    if not 0.0 < level <= 1.0:  # also NaN; a level of 0 would pick the largest score, not none
        raise ModelError(f"conformal_scale: level must be in (0, 1], got {level!r}")
    scores = np.sort(np.asarray(scores, dtype=np.float64))
    n = scores.size
    rank = math.ceil((n + 1) * level)
    return math.inf if n == 0 or rank > n else float(scores[rank - 1])


def force_band(peak_force_n: float | np.ndarray, edges_n: tuple[float, ...]) -> np.ndarray:
    """The force band of each grasp's peak force (N): 0 below ``edges_n[0]``, ``i`` from
    ``edges_n[i - 1]`` up to ``edges_n[i]``, ``len(edges_n)`` from the last edge on."""
    return np.searchsorted(np.asarray(edges_n, dtype=np.float64), np.asarray(peak_force_n, dtype=np.float64),
                           side="right")


def fit_temperature(logits: np.ndarray, log10_truth: np.ndarray, *, log_weights: np.ndarray | None = None
                    ) -> float:
    """The temperature minimising the log score (bin negative log likelihood) of the truths under
    :func:`probabilities`, in [0.25, 8]; fitted on validation objects. A ModelError when a truth is
    not finite (it has no bin)."""
    logits = np.asarray(logits, dtype=np.float64)
    weights = 0.0 if log_weights is None else log_weights
    truth = np.asarray(log10_truth, dtype=np.float64)
    if not np.isfinite(truth).all():
        bad = np.flatnonzero(~np.isfinite(truth.ravel()))
        raise ModelError(f"fit_temperature: log10_truth must be finite, got {truth.ravel()[bad[:5]].tolist()} "
                         f"at {bad[:5].tolist()} ({bad.size} in all)")
    index = bin_index(truth)

    def nll(log_t: float) -> float:
        scaled = log_softmax(logits / math.exp(log_t) + weights, axis=-1)
        return float(-scaled[np.arange(index.size), index].mean())

    best = minimize_scalar(nll, bounds=(math.log(0.25), math.log(8.0)), method="bounded")
    return float(math.exp(best.x))


@dataclass(frozen=True)
class Described:
    """What one predictive distribution says (see the module notes).

    Attributes
    ----------
    state : {"ok", "lower_bound", "upper_bound"}
    e_pa : float
        The value to render (:func:`hedged_point`), or the bound.
    low_pa, high_pa : float or None
        The interval; None for an open side.
    p_above_limit : float
        Probability that E is at or above the resolution limit.
    """

    state: str
    e_pa: float
    low_pa: float | None
    high_pa: float | None
    p_above_limit: float

    def divided(self, factor: float) -> Described:
        """The same answer with every modulus divided by ``factor`` (> 0): from the reference gel's
        moduli to the measuring gel's (:func:`~estimator.inference.inputs.gel_scale`)."""
        def div(value: float | None) -> float | None:
            return None if value is None else value / factor

        return Described(self.state, self.e_pa / factor, div(self.low_pa), div(self.high_pa), self.p_above_limit)


def describe(probs: np.ndarray, *, scale: float, limit_pa: float, soft_pa: float,
             p_rigid: float = 0.5, widen: float = 1.0) -> Described:
    """The estimate of one distribution (N_BINS,): state, value and interval (module notes).

    Parameters
    ----------
    probs : ndarray
        Bin probabilities (calibrated).
    scale : float
        Half-width of the ``ok`` interval in spreads (:func:`spread`), > 0.
    limit_pa : float
        The sensor's resolution limit (Pa), at most :data:`CENSOR_PA`.
    soft_pa : float
        The softest modulus the model resolves (Pa): a median at or below it is an
        ``upper_bound`` there.
    p_rigid : float
        The probability of E >= ``limit_pa`` from which the answer is a ``lower_bound`` there.
    widen : float
        Factor (>= 1) on the interval for a grasp outside what the model was trained on. The value
        is sought within the interval before widening, so widening moves only the interval's ends.

    Raises
    ------
    ModelError
        An option is out of its range, or ``probs`` is not N_BINS finite probabilities >= 0
        with a positive sum.
    """
    if not (0.0 < scale < math.inf and 0.0 < p_rigid < 1.0 and 1.0 <= widen < math.inf) or not (
            0.0 < soft_pa < limit_pa <= CENSOR_PA):
        raise ModelError(f"describe: expected 0 < scale < inf, 0 < p_rigid < 1, 1 <= widen < inf and 0 < soft_pa < "
                         f"limit_pa <= {CENSOR_PA:g}, got scale {scale}, p_rigid {p_rigid}, widen {widen}, soft_pa "
                         f"{soft_pa}, limit_pa {limit_pa}")
    probs = np.asarray(probs, dtype=np.float64)[None]
    # Not a distribution (NaN logits, every bin zero): its quantiles would be NaN.
    if probs.shape != (1, N_BINS) or not (np.isfinite(probs).all() and probs.min() >= 0.0 and probs.sum() > 0.0):
        raise ModelError(f"describe: probs must be {N_BINS} finite probabilities >= 0 with a positive sum, got "
                         f"shape {probs.shape[1:]}, sum {float(np.sum(probs))!r}")
    median = float(quantile(probs, 0.5)[0])
    p_above = float(1.0 - cdf_at(probs, math.log10(limit_pa))[0])
    if p_above >= p_rigid:
        return Described("lower_bound", limit_pa, limit_pa, None, p_above)
    if median <= math.log10(soft_pa):
        return Described("upper_bound", soft_pa, None, soft_pa, p_above)

    def interval(half: float) -> tuple[float, float]:
        high = median + half
        if high > math.log10(CENSOR_PA):  # the censored value stands for anything stiffer
            high = LOG10_E_RANGE[1]
        return max(median - half, LOG10_E_RANGE[0] - 1.0), high

    half = scale * float(spread(probs)[0])
    low_calibrated, high_calibrated = interval(half)
    if low_calibrated > math.log10(limit_pa):  # no number above the limit is offered, not even its low end
        return Described("lower_bound", limit_pa, limit_pa, None, p_above)
    # The interval meets [soft, limit]: it holds the median, above soft_pa, and starts at or below the limit.
    point = hedged_point(probs[0], low=low_calibrated, high=high_calibrated, soft=math.log10(soft_pa),
                         limit=math.log10(limit_pa))
    low, high = interval(half * widen)
    return Described("ok", 10.0 ** point, 10.0 ** low, 10.0 ** high, p_above)


def describe_on_gel(probs: np.ndarray, *, scale: float, limit_pa: float, soft_pa: float, p_rigid: float,
                    gel_scale: float, widen: float = 1.0) -> Described:
    """The estimate of one distribution (N_BINS,) over the reference gel's moduli for a grasp on a gel
    of :func:`~estimator.inference.inputs.gel_scale` ``gel_scale``, in that gel's moduli: what the
    estimator answers, and what calibration scores.

    ``limit_pa`` is the settings' resolution limit (Pa, the measuring gel's moduli), taken onto the
    reference gel and at most :data:`CENSOR_PA` there; ``soft_pa`` the softest modulus the model
    resolves on the reference gel, at most a tenth of that limit. ``scale``, ``p_rigid`` and ``widen``
    as :func:`describe`.
    """
    limit_ref_pa = min(limit_pa * gel_scale, CENSOR_PA)
    said = describe(probs, scale=scale, limit_pa=limit_ref_pa, soft_pa=min(soft_pa, limit_ref_pa / 10.0),
                    p_rigid=p_rigid, widen=widen)
    return said.divided(gel_scale)
