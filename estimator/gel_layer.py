"""The gel's thin-layer correction: how much stiffer a bonded gel layer is than a half-space.

The gel is a layer bonded to a rigid backing, so a contact wider than the layer is thick
indents it less than it would a half-space under the same pressure. :func:`gel_layer_factor`
is that ratio of centre compliances under a Hertz pressure; the series method
(:func:`estimator.analytical.series`) scales the gel's compliance by it.
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np
from scipy import special

from estimator.fit_inputs import poisson_ratio, positive

__all__ = ["gel_layer_factor"]


def gel_layer_factor(
    contact_radius_m: np.ndarray | float, *, gel_thickness_m: float, gel_poisson: float
) -> np.ndarray:
    """The gel's centre compliance under a contact of radius ``a``, relative to a half-space's.

    The gel is a layer of thickness ``h`` bonded to a rigid backing. For a
    pressure wave of wavenumber ``q`` its surface compliance is the half-space's
    times (Chen & Engel, Int. J. Solids Struct. 8 (1972) 1257)::

        S(x) = (kappa sinh 2x - 2x) / (kappa cosh 2x + 2x^2 + (1 + kappa^2) / 2),
        x = q h, kappa = 3 - 4 nu.

    Under the Hertz pressure ``p0 sqrt(1 - r^2/a^2)`` (Hankel transform
    ``2 pi p0 a^2 j1(qa) / (qa)``) the centre displacement is
    ``u(0) = (k / pi) int S(qh) p~(q) dq``, so the factor is

        eta(a / h) = (4 / pi) int_0^inf S(x h / a) j1(x) / x dx,

    1 for ``a << h`` (a half-space), falling steeply once the contact is wider
    than the layer is thick (a 3 mm gel with nu = 0.48 under a contact of 6 mm
    radius is about 6.5 times stiffer than a half-space) and like ``h / a`` (confined
    compression) far beyond for a compressible gel. Tabulated once per Poisson's ratio for
    ``a / h <= 20``, interpolated, and extended as ``h / a`` beyond: an incompressible
    layer falls faster there, so at ``nu = 0.5`` and ``a / h = 40`` the factor is about
    4 times too high (at 0.48, 2.6 %); ``a / h > 20`` is a contact wider than a real pad.

    Parameters
    ----------
    contact_radius_m : array_like
        Contact radius ``a`` (m, >= 0; NaN gives NaN).
    gel_thickness_m : float
        ``h`` (m, > 0).
    gel_poisson : float
        The gel's Poisson's ratio in [0, 0.5].

    Returns
    -------
    ndarray
        ``eta`` in (0, 1], the shape of ``contact_radius_m``.
    """
    (gel_thickness_m,) = positive("gel_layer_factor", gel_thickness_m=gel_thickness_m)
    poisson_ratio("gel_layer_factor", "gel_poisson", gel_poisson)
    ratio, table = _layer_table(round(float(gel_poisson), 6))
    a = np.asarray(contact_radius_m, dtype=np.float64) / gel_thickness_m
    # Beyond the table the factor falls as h / a (confined compression of the layer).
    tail = table[-1] * ratio[-1] / np.maximum(a, ratio[-1])
    return np.where(a > ratio[-1], tail, np.interp(a, ratio, table))


@lru_cache(maxsize=4)
def _layer_table(poisson: float) -> tuple[np.ndarray, np.ndarray]:
    """eta on a grid of a / h from 0 to 20 (see :func:`gel_layer_factor`)."""
    kappa = 3.0 - 4.0 * poisson
    x = np.linspace(1e-6, 80.0, 40001)
    j1_over_x = special.spherical_jn(1, x) / x
    ratio = np.concatenate([[0.0], np.geomspace(1e-3, 20.0, 200)])
    qh = x[None, :] / np.maximum(ratio[1:, None], 1e-12)
    e2 = np.exp(-2.0 * qh)
    e4 = e2 * e2
    s = (kappa * (1.0 - e4) - 4.0 * qh * e2) / (kappa * (1.0 + e4) + (4.0 * qh * qh + 1.0 + kappa**2) * e2)
    # 1 - (4/pi) int (1 - S) j1(x)/x dx: the integrand vanishes where S -> 1, so the grid can end.
    eta = 1.0 - 4.0 / math.pi * np.trapezoid((1.0 - s) * j1_over_x, x, axis=1)
    table = np.concatenate([[1.0], np.clip(eta, 1e-12, 1.0)])
    table.flags.writeable = False
    return ratio, table
