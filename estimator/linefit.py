"""Least-squares lines with honest intervals, and the measurement resolution they rest on.

The analytical estimators (:mod:`estimator.analytical`) fit every grasp as a line through its
loading frames; the slope's interval (about 95 %) combines the fit's scatter with each measured
quantity's resolution (:class:`MeasurementNoise`), so that even exact points report what they
rest on.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from numbers import Real

import numpy as np
from scipy import special

from estimator.errors import FitError
from estimator.fit_inputs import real_array

__all__ = ["CONFIDENCE", "LineFit", "MeasurementNoise", "fit_line", "no_line_reason"]

CONFIDENCE = 0.95


@dataclass(frozen=True)
class MeasurementNoise:
    """Standard deviation of one reading of each measured quantity (SI units).

    Attributes
    ----------
    force_n : float
        One force reading (N).
    width_m : float
        One fingertip-separation reading (m).
    depth_m : float
        Depth resolution of the tactile sensor (m).
    length_m : float
        Resolution of a length on the tactile image: the pixel pitch (m).
    depth_scale : float
        Relative scale uncertainty of reconstructed depth (a calibration
        error shared by every frame, so it does not average out).
    onset_width_m : float
        Uncertainty of the fingertip separation at the contact onset (m), from
        which every approach is measured: an error all frames share.
    """

    force_n: float = 0.0
    width_m: float = 0.0
    depth_m: float = 0.0
    length_m: float = 0.0
    depth_scale: float = 0.0
    onset_width_m: float = 0.0

    def __post_init__(self) -> None:
        for name in ("force_n", "width_m", "depth_m", "length_m", "depth_scale", "onset_width_m"):
            value = getattr(self, name)
            # A numpy scalar is a number too (kept as a float: a float32 would carry its precision into
            # the fits); a bool is no standard deviation.
            if not (isinstance(value, Real) and not isinstance(value, bool) and math.isfinite(value) and value >= 0):
                raise FitError(f"MeasurementNoise.{name}: expected a finite real number >= 0, got {value!r}")
            object.__setattr__(self, name, float(value))

    @property
    def approach_m(self) -> float:
        """One per-finger approach reading (m): half a width reading."""
        return self.width_m / 2.0

    @property
    def onset_approach_m(self) -> float:
        """The per-finger approach's share of the onset uncertainty (m): half of ``onset_width_m``."""
        return self.onset_width_m / 2.0


@dataclass(frozen=True)
class LineFit:
    """Least-squares line ``y = slope * x + intercept`` with the slope's interval half-width."""

    slope: float
    intercept: float
    half_width: float
    n: int
    dof: int

    @property
    def low(self) -> float:
        return self.slope - self.half_width

    @property
    def high(self) -> float:
        return self.slope + self.half_width

    def describe(self, symbol: str) -> str:
        basis = "fit scatter and resolution" if self.dof > 0 else "resolution only"
        return f"{symbol} = {self.slope:.4g} ± {self.half_width:.2g} over {self.n} frames ({basis})"


def fit_line(
    x: np.ndarray,
    y: np.ndarray,
    sigma_y: np.ndarray,
    *,
    through_origin: bool,
    systematic_y: Sequence[np.ndarray] = (),
) -> LineFit | None:
    """Least-squares slope of ``y`` on ``x`` with a ~95 % interval.

    The half-width combines in quadrature the residual standard error (times
    Student's t on the degrees of freedom, when there are any), the
    propagated independent measurement error ``sigma_y`` and the slope shift
    caused by each error in ``systematic_y``, an error shared by all points
    (e.g. a depth scale error: one standard deviation per point, fully
    correlated; independent of the others), all in units of ``y``. Returns
    None when the slope is undetermined (no spread in ``x``) or not
    representable (values so large that the sums overflow);
    :func:`no_line_reason` says which.

    Raises
    ------
    FitError
        ``x``, ``y``, ``sigma_y`` or an error in ``systematic_y`` is not a 1-D
        real series of the length of ``x``.
    """
    x = real_array("fit_line", "x", x)
    if x.ndim != 1:
        raise FitError(f"fit_line: x must be a 1-D series, got shape {x.shape}")
    y = _like_x(x, "y", y)
    sigma_y = _like_x(x, "sigma_y", sigma_y)
    systematic_y = [_like_x(x, f"systematic_y[{i}]", shared) for i, shared in enumerate(systematic_y)]
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        return _fit_line(x, y, sigma_y, through_origin=through_origin, systematic_y=systematic_y)


def no_line_reason(x: np.ndarray, *, through_origin: bool, x_name: str, y_name: str) -> str:
    """Why :func:`fit_line` gave no line for ``x`` (called ``x_name``) and its ``y`` (``y_name``).

    ``x`` lacks the spread a slope needs (no nonzero value through the origin, fewer than two
    distinct values with an intercept), or its spread is beyond float range (below or above), or
    else the ``y`` side (the values or their uncertainties) is too large for the sums to stay finite.
    """
    x = np.asarray(x, dtype=np.float64)
    varies = bool(np.any(x != 0)) if through_origin else x.size >= 2 and bool(x.max() > x.min())
    if not varies:
        return f"the {x_name} does not vary over the loading frames"
    with np.errstate(over="ignore", under="ignore", invalid="ignore"):
        x_c = x if through_origin else x - x.mean()
        sxx = float(x_c @ x_c)  # as fit_line computes it
    if sxx == 0:
        return f"the {x_name} varies too little for a line fit (its spread underflows)"
    if not math.isfinite(sxx):
        return f"the {x_name} is too large for a line fit (its sums overflow)"
    return f"the {y_name} or its uncertainty is too large for a line fit (its sums overflow)"


def _like_x(x: np.ndarray, name: str, values: object) -> np.ndarray:
    """``values`` as a float64 series of the shape of ``x``, else a FitError naming them."""
    array = real_array("fit_line", name, values)
    if array.shape != x.shape:
        raise FitError(f"fit_line: {name} must have the shape of x {x.shape}, got {array.shape}")
    return array


def _fit_line(x: np.ndarray, y: np.ndarray, sigma_y: np.ndarray, *, through_origin: bool,
              systematic_y: Sequence[np.ndarray]) -> LineFit | None:
    """:func:`fit_line` on checked series."""
    n = x.size
    if n == 0 or (not through_origin and n < 2):
        return None
    x_c = x if through_origin else x - x.mean()
    sxx = float(x_c @ x_c)
    if not (sxx > 0 and math.isfinite(sxx)):
        return None
    y_c = y if through_origin else y - y.mean()
    slope = float(x_c @ y_c) / sxx
    intercept = 0.0 if through_origin else float(y.mean() - slope * x.mean())
    dof = n - (1 if through_origin else 2)
    z = float(special.ndtri(0.5 + CONFIDENCE / 2))
    se_floor = math.sqrt(float((x_c * x_c) @ (sigma_y * sigma_y))) / sxx
    half_sq = (z * se_floor) ** 2
    for shared in systematic_y:
        half_sq += (z * float(x_c @ shared) / sxx) ** 2
    if dof > 0:
        residual = y - (slope * x + intercept)
        se_fit = math.sqrt(float(residual @ residual) / dof / sxx)
        half_sq += (float(special.stdtrit(dof, 0.5 + CONFIDENCE / 2)) * se_fit) ** 2
    half = math.sqrt(half_sq)
    if not (math.isfinite(slope) and math.isfinite(half)):
        return None
    return LineFit(slope=slope, intercept=intercept, half_width=half, n=n, dof=dof)
