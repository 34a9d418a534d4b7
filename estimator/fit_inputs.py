"""Checks of the scalar inputs of the contact fits (:mod:`estimator.analytical`, :mod:`estimator.gel_layer`).

Each raises :class:`~estimator.errors.FitError` naming the fit, the input and what was expected.
"""

from __future__ import annotations

import math
from numbers import Real

from estimator.errors import FitError

__all__ = ["poisson_ratio", "positive"]


def _real(value: object) -> bool:
    """Whether ``value`` is one real number (a numpy scalar too; a bool is no measurement)."""
    return isinstance(value, Real) and not isinstance(value, bool)


def positive(method: str, **scalars: float) -> tuple[float, ...]:
    """The scalars as Python floats (a float32 would otherwise carry its precision into the fit)."""
    for name, value in scalars.items():
        if not (_real(value) and math.isfinite(value) and value > 0):
            raise FitError(f"{method}: {name} must be a finite real number > 0, got {value!r}")
    return tuple(float(value) for value in scalars.values())


def poisson_ratio(method: str, name: str, poisson: float) -> None:
    """Refuse a Poisson's ratio that is not a real number in [0, 0.5]."""
    if not (_real(poisson) and math.isfinite(poisson) and 0.0 <= poisson <= 0.5):
        raise FitError(f"{method}: {name} must be a real number in [0, 0.5], got {poisson!r}")
