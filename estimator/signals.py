"""Sample streams as the segmentation reads them: cleaned, interpolated, their noise and crossings.

Each stream of a grasp keeps its own timestamps on one clock; nothing is matched by index. These
pure functions work on one stream at a time (:mod:`estimator.segment` aligns them).
"""

from __future__ import annotations

import numpy as np

from estimator.errors import FitError
from estimator.fit_inputs import real_array

__all__ = ["clean_samples", "crossing_time", "interpolate", "noise_std", "reading_noise"]


def clean_samples(t_s: np.ndarray, value: np.ndarray, *,
                  names: tuple[str, str] = ("t_s", "value")) -> tuple[np.ndarray, np.ndarray]:
    """Finite samples sorted by time, duplicate timestamps merged into their mean value.

    Parameters
    ----------
    t_s, value : array_like, shape (n,)
        Sample times (s) and values (any unit).
    names : (str, str)
        What the caller calls them, for the error.

    Returns
    -------
    t_s, value : ndarray, float64
        Strictly increasing times and their values.

    Raises
    ------
    FitError
        The arrays are not 1-D of one length, or not of real numbers (integers or floats).
    """
    t = real_array("samples", names[0], t_s)
    v = real_array("samples", names[1], value)
    if t.ndim != 1 or t.shape != v.shape:
        raise FitError(f"samples: {names[0]} and {names[1]} must be 1-D of one length, got {t.shape} and {v.shape}")
    keep = np.isfinite(t) & np.isfinite(v)
    t, v = t[keep], v[keep]
    unique_t, inverse, counts = np.unique(t, return_inverse=True, return_counts=True)
    return unique_t, np.bincount(inverse, weights=v, minlength=unique_t.size) / counts


def interpolate(t_query: np.ndarray, t_s: np.ndarray, value: np.ndarray) -> np.ndarray:
    """Linear interpolation of cleaned samples at ``t_query``; NaN outside their time span.

    ``t_s`` must be strictly increasing (see :func:`clean_samples`).
    """
    tq = np.asarray(t_query, dtype=np.float64)
    if t_s.size == 0:
        return np.full(tq.shape, np.nan)
    out = np.interp(tq, t_s, value)
    return np.where((tq >= t_s[0]) & (tq <= t_s[-1]), out, np.nan)


def noise_std(value: np.ndarray) -> float:
    """Robust standard deviation of white noise on a smooth signal (same unit as ``value``).

    From the median absolute second difference, which removes trends and
    ignores the few kinks (contact, stop) of a grasp: for white noise of
    standard deviation s the second difference has standard deviation
    ``sqrt(6) * s``. Returns 0 for fewer than 3 samples, or when the values
    are too large for their differences to be represented.
    """
    v = np.asarray(value, dtype=np.float64)
    if v.size < 3:
        return 0.0
    with np.errstate(over="ignore", invalid="ignore"):
        second = np.diff(v, n=2)
        sigma = float(1.4826 * np.median(np.abs(second - np.median(second))) / np.sqrt(6.0))
    return sigma if np.isfinite(sigma) else 0.0


def reading_noise(value: np.ndarray, *, floor: float) -> float:
    """Standard deviation of one reading (same unit as ``value``): :func:`noise_std`, but at least
    ``floor``, since no reading is exact: identical or noise-free readings would otherwise claim a
    resolution no sensor has."""
    return max(noise_std(value), floor)


def crossing_time(t: np.ndarray, v: np.ndarray, i: int, level: float) -> float:
    """Time where ``v`` crosses ``level`` between samples ``i`` and ``i + 1``."""
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        frac = (level - v[i]) / (v[i + 1] - v[i])
    frac = float(np.clip(frac, 0.0, 1.0)) if np.isfinite(frac) else 0.0
    return float(np.clip(t[i] + frac * (t[i + 1] - t[i]), t[i], t[i + 1]))  # rounding stays inside
