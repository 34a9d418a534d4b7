"""Checks of the inputs of the contact fits (:mod:`estimator.analytical`, :mod:`estimator.gel_layer`)
and of the series they rest on (:mod:`estimator.signals`, :mod:`estimator.segment`, :mod:`estimator.lag`,
:mod:`estimator.linefit`).

Each raises :class:`~estimator.errors.FitError` naming the fit, the input and what was expected.
"""

from __future__ import annotations

import math
from numbers import Real

import numpy as np

from estimator.errors import FitError

__all__ = ["is_real", "poisson_ratio", "positive", "real_array"]


def is_real(value: object) -> bool:
    """Whether ``value`` is one real number (a numpy scalar too; a bool is no measurement)."""
    return isinstance(value, Real) and not isinstance(value, bool)


def positive(method: str, **scalars: float) -> tuple[float, ...]:
    """The scalars as Python floats (a float32 would otherwise carry its precision into the fit)."""
    for name, value in scalars.items():
        if not (is_real(value) and math.isfinite(value) and value > 0):
            raise FitError(f"{method}: {name} must be a finite real number > 0, got {value!r}")
    return tuple(float(value) for value in scalars.values())


def poisson_ratio(method: str, name: str, poisson: float) -> None:
    """Refuse a Poisson's ratio that is not a real number in [0, 0.5]."""
    if not (is_real(poisson) and math.isfinite(poisson) and 0.0 <= poisson <= 0.5):
        raise FitError(f"{method}: {name} must be a real number in [0, 0.5], got {poisson!r}")


def real_array(method: str, name: str, values: object) -> np.ndarray:
    """``values`` as a float64 array when they are real numbers (integers or floats), else a FitError
    naming them: a complex value would lose its imaginary part, and a bool, a string or an object is
    no measurement. The shape is the caller's to check; one dtype check, no pass over the values."""
    array = np.asarray(values)
    if array.dtype.kind not in "iuf":
        raise FitError(f"{method}: {name} must be real numbers (integers or floats), got dtype {array.dtype}")
    return array.astype(np.float64, copy=False)
