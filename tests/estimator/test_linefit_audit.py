"""Audit of estimator.linefit: the interval half-width against its closed form, computed here."""

from __future__ import annotations

import math
from statistics import NormalDist

import numpy as np
import pytest
from scipy import stats

from estimator.errors import FitError
from estimator.linefit import LineFit, MeasurementNoise, fit_line, no_line_reason

Z95 = NormalDist().inv_cdf(0.975)  # 1.95996...


@pytest.mark.parametrize("bad", [math.inf, -math.inf, math.nan])
def test_measurement_noise_refuses_a_non_finite_deviation(bad):
    with pytest.raises(FitError, match="MeasurementNoise.force_n"):
        MeasurementNoise(force_n=bad)


def test_an_intercept_line_combines_scatter_resolution_and_shared_error_in_quadrature():
    x = np.array([0.0, 1.0, 2.0, 3.0, 5.0])
    y = np.array([1.1, 2.9, 5.2, 6.8, 11.3])
    sigma = np.array([0.1, 0.2, 0.1, 0.3, 0.2])
    shared = 0.02 * y  # a scale error all points share
    line = fit_line(x, y, sigma, through_origin=False, systematic_y=[shared])

    xc = x - x.mean()
    sxx = float(xc @ xc)
    slope = float(xc @ (y - y.mean())) / sxx
    intercept = y.mean() - slope * x.mean()
    rss = float(((y - slope * x - intercept) ** 2).sum())
    n = x.size
    scatter = stats.t.ppf(0.975, n - 2) * math.sqrt(rss / (n - 2) / sxx)
    resolution = Z95 * math.sqrt(float((xc**2) @ (sigma**2))) / sxx
    systematic = Z95 * float(xc @ shared) / sxx
    assert line.slope == pytest.approx(slope, rel=1e-12)
    assert line.intercept == pytest.approx(intercept, rel=1e-12)
    assert line.half_width == pytest.approx(math.hypot(scatter, resolution, systematic), rel=1e-9)
    assert (line.n, line.dof) == (5, 3)
    assert (line.low, line.high) == pytest.approx((slope - line.half_width, slope + line.half_width))


def test_a_line_through_the_origin_has_no_intercept_and_n_minus_1_degrees_of_freedom():
    x = np.array([1.0, 2.0, 3.0, 4.0])
    y = np.array([3.1, 4.9, 7.2, 8.8])  # an intercept-like offset the origin fit must not absorb
    line = fit_line(x, y, np.zeros(4), through_origin=True)

    sxx = float(x @ x)
    slope = float(x @ y) / sxx
    rss = float(((y - slope * x) ** 2).sum())
    assert line.slope == pytest.approx(slope, rel=1e-12)
    assert line.intercept == 0.0 and line.dof == 3
    assert line.half_width == pytest.approx(stats.t.ppf(0.975, 3) * math.sqrt(rss / 3 / sxx), rel=1e-9)


def test_one_point_through_the_origin_rests_on_its_resolution_alone():
    line = fit_line(np.array([2.0]), np.array([5.0]), np.array([0.4]), through_origin=True)
    assert line == LineFit(slope=2.5, intercept=0.0, half_width=pytest.approx(Z95 * 0.4 / 2.0), n=1, dof=0)
    assert "resolution only" in line.describe("E")


def test_a_constant_nonzero_x_through_the_origin_is_no_still_quantity():
    # Through the origin, x = (1, 1, 1) varies enough for a slope: a missing line then lies with y.
    reason = no_line_reason(np.ones(3), through_origin=True, x_name="stress", y_name="strain")
    assert reason == "the strain or its uncertainty is too large for a line fit (its sums overflow)"
    still = no_line_reason(np.ones(3), through_origin=False, x_name="stress", y_name="strain")
    assert still == "the stress does not vary over the loading frames"
