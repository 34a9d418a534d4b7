"""Audit of estimator.fit_inputs: the bounds of the scalar checks and the float64 view."""

from __future__ import annotations

import math

import numpy as np
import pytest

from estimator.errors import FitError
from estimator.fit_inputs import poisson_ratio, positive, real_array


@pytest.mark.parametrize("bad", [math.inf, -math.inf, math.nan, 0.0, -1.0, True])
def test_positive_refuses_what_is_not_a_finite_number_above_zero(bad):
    with pytest.raises(FitError, match="series: h must be a finite real number > 0"):
        positive("series", h=bad)


def test_positive_returns_python_floats_in_order():
    values = positive("series", a=np.float32(0.5), b=3)
    assert values == (0.5, 3.0) and all(type(v) is float for v in values)


@pytest.mark.parametrize("nu", [0.0, 0.25, 0.5, np.float32(0.5)])
def test_poisson_ratio_admits_both_ends_of_0_to_half(nu):
    poisson_ratio("series", "object_poisson", nu)


@pytest.mark.parametrize("bad", [-1e-12, 0.5 + 1e-12, math.nan, math.inf, False, "0.4"])
def test_poisson_ratio_refuses_anything_outside_0_to_half(bad):
    with pytest.raises(FitError, match=r"series: object_poisson must be a real number in \[0, 0.5\]"):
        poisson_ratio("series", "object_poisson", bad)


def test_real_array_hands_back_a_float64_series_without_copying_it():
    values = np.linspace(0.0, 1.0, 5)
    assert np.shares_memory(real_array("fit_line", "x", values), values)
    as_float = real_array("fit_line", "x", np.array([1, 2], dtype=np.uint8))
    assert as_float.dtype == np.float64 and as_float.tolist() == [1.0, 2.0]
