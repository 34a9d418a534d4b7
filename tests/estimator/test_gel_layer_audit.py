"""Audit of estimator.gel_layer: the tabulated factor against an independent quadrature of the
bonded-layer compliance and against confined compression, its closed form for wide contacts."""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest
from scipy import integrate, special

from estimator.gel_layer import gel_layer_factor


def layer_over_half_space(u: float, nu: float) -> float:
    """Surface compliance of a layer bonded to a rigid base over a half-space's, at q h = u (Chen &
    Engel 1972), in its hyperbolic form (the module tabulates an exponential rewriting)."""
    kappa = 3.0 - 4.0 * nu
    if u > 350.0:
        return 1.0
    c = math.cosh(2 * u)
    return (kappa * math.tanh(2 * u) - 2 * u / c) / (kappa + (2 * u * u + (1 + kappa**2) / 2) / c)


def eta_by_quadrature(a_over_h: float, nu: float) -> float:
    """1 - (4/pi) int_0^inf (1 - S(u)) j1(u a/h) / u du: the Hertz-pressure factor in q h, by quad."""
    def integrand(u: float) -> float:
        return (1.0 - layer_over_half_space(u, nu)) * special.spherical_jn(1, u * a_over_h) / u

    value, _ = integrate.quad(integrand, 0.0, 40.0, limit=2000)
    return 1.0 - 4.0 / math.pi * value


@pytest.mark.parametrize(("nu", "a_over_h"), [
    (0.0, 2.0), (0.3, 0.3), (0.3, 12.3), (0.48, 1.0), (0.48, 5.0), (0.48, 20.0), (0.5, 2.0),
])
def test_the_factor_matches_an_independent_quadrature_for_any_poisson_ratio(nu, a_over_h):
    h = 3e-3
    eta = float(gel_layer_factor(a_over_h * h, gel_thickness_m=h, gel_poisson=nu))
    assert eta == pytest.approx(eta_by_quadrature(a_over_h, nu), rel=3e-3)


@pytest.mark.parametrize("nu", [0.0, 0.3])
@pytest.mark.parametrize("a_over_h", [20.0, 50.0])
def test_a_compressible_layer_far_wider_than_thick_is_in_confined_compression(nu, a_over_h):
    # Centre displacement h p0 / M (M the constrained modulus) over the half-space's k pi p0 a / 2.
    expected = 2 * (1 - 2 * nu) / (math.pi * (1 - nu) ** 2) / a_over_h
    eta = float(gel_layer_factor(a_over_h, gel_thickness_m=1.0, gel_poisson=nu))
    assert eta == pytest.approx(expected, rel=1e-3)


def test_a_softer_poisson_ratio_gives_a_more_compliant_layer():
    etas = [float(gel_layer_factor(2e-3, gel_thickness_m=1e-3, gel_poisson=nu)) for nu in (0.0, 0.3, 0.48, 0.5)]
    assert etas == sorted(etas, reverse=True) and len(set(etas)) == 4


def test_a_zero_radius_among_others_is_a_half_space_without_a_warning():
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        eta = gel_layer_factor(np.array([0.0, 1e-3, 90e-3]), gel_thickness_m=3e-3, gel_poisson=0.48)
    assert eta[0] == 1.0 and 0 < eta[2] < eta[1] < 1
