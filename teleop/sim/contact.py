"""Frictionless normal contact between the tactile gel and an object.

Two models, each used only where a scene needs it:

``bem-layer``
    A boundary-element solution on a regular grid of rectangular cells: the
    pressure is uniform on each cell, the gap closes where the pressure is
    positive, and the pressure is zero where the gap stays open. Surface
    displacements are the convolution of the pressure with influence
    coefficients, evaluated with zero-padded FFTs (scipy.fft; linear, not
    periodic, convolution: the DC-FFT of Liu, Wang & Liu, Wear 243 (2000) 101).
    The pressure solves the linear complementarity problem with the
    conjugate-gradient scheme of Polonsky & Keer, Wear 231 (1999) 206, either
    for a given total force or for a given approach, warm-started from a
    previous solution.

    The gel is an elastic layer of thickness h bonded to a rigid backing with a
    frictionless top surface. Its surface compliance for a pressure wave of
    wavenumber q is (Chen & Engel, Int. J. Solids Struct. 8 (1972) 1257; in
    this form e.g. Persson, J. Phys.: Condens. Matter 24 (2012) 095008)::

        u(q) / p(q) = 2 (1 - nu^2) / (E q) * S(q h)
        S(x) = (kappa sinh 2x - 2x) / (kappa cosh 2x + 2x^2 + (1 + kappa^2) / 2),  kappa = 3 - 4 nu

    S -> 1 as qh -> inf (the half-space, 2 (1 - nu^2) / (E q)) and
    u/p -> h (1 + nu)(1 - 2 nu) / (E (1 - nu)) as qh -> 0 (the confined
    compression of a thin bonded layer). Its real-space influence is the
    half-space's (Love's rectangle formula, Johnson, Contact Mechanics, eq. 3.25)
    plus a smooth correction, the Hankel transform of (S - 1), tabulated once
    per Poisson's ratio.

    A layer may instead lie on a lubricated backing (``Body.base_slip`` = 1: no
    shear at the interface, the companion case of Chen & Engel). Mirrored about
    its base it is a free plate of thickness 2h pressed alike on both faces, a
    pure traction problem, so its stresses do not depend on nu and::

        S_slip(x) = (cosh 2x - 1) / (sinh 2x + 2x)

    S_slip -> 1 as qh -> inf and u/p -> h (1 - nu^2) / E as qh -> 0 (the layer
    spreads sideways over its base: far softer than the bonded layer, stiffer
    than the half-space). Between the two (0 < ``base_slip`` < 1) the compliance
    is the blend (1 - s) S + s S_slip, an interpolation for a partly bonded
    backing (no solved partial-slip problem); its correction is the same blend of
    the two tables, the slip one tabulated once.

    The object is a half-space of its own compliance. Both bodies carry the
    same pressure, so the total displacement is the gel's layer response plus
    the object's half-space response to that pressure; the composite modulus
    1/E* = k_gel + k_obj is never used for the layer.

``hertz``
    The closed form for a sphere on a flat, both half-spaces (Johnson, ch. 4).

Frames and units: grids are (rows, cols) arrays of cells ``cell_m`` = (row
pitch, column pitch) metres; gaps, displacements and approaches are metres,
positive into the bodies; pressure in Pa; forces in N.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np
import scipy.fft
from scipy.special import j0

__all__ = [
    "NO_CONTACT_GAP_M",
    "Body",
    "ContactSolution",
    "Influence",
    "hertz_contact",
    "hertz_sphere",
    "hertz_surface_displacement",
    "gel_shear",
    "layer_factor",
    "layer_stiffening",
    "solve_contact",
]

# Gap given to cells the object does not cover: far beyond any approach.
NO_CONTACT_GAP_M = 1.0
# The layer correction's Hankel integral: quadrature grid over x = q h and the table over rho = r / h.
_LAYER_X_MAX = 16.0  # |S(x) - 1| ~ x^2 exp(-2x) / kappa: below 1e-10 beyond
_LAYER_X_STEP = 0.01
_LAYER_RHO_MAX = 24.0  # beyond, the correction is the half-space's far field, -1/rho, to 1e-9
_LAYER_RHO_STEP = 0.02
# Sub-points per cell side averaging the layer correction over a source cell.
_LAYER_SUBCELLS = 4


@dataclass(frozen=True)
class Body:
    """An elastic body in contact.

    Parameters
    ----------
    modulus_pa : float
        Young's modulus E, Pa (> 0).
    poisson : float
        Poisson's ratio in [0, 0.5].
    thickness_m : float or None
        None: a half-space. Otherwise a layer of this thickness (m) on a rigid
        backing, loaded on its frictionless free surface.
    base_slip : float
        A layer only: how freely it slides on its backing, in [0, 1]; 0 bonded
        (the sensor as built), 1 on a frictionless (lubricated) backing, between
        a blend of the two compliances (module notes).
    """

    modulus_pa: float
    poisson: float
    thickness_m: float | None = None
    base_slip: float = 0.0

    def __post_init__(self) -> None:
        if not (math.isfinite(self.modulus_pa) and self.modulus_pa > 0):
            raise ValueError(f"Body.modulus_pa must be finite and > 0, got {self.modulus_pa}")
        if not 0.0 <= self.poisson <= 0.5:
            raise ValueError(f"Body.poisson must be in [0, 0.5], got {self.poisson}")
        if self.thickness_m is not None and not (math.isfinite(self.thickness_m) and self.thickness_m > 0):
            raise ValueError(f"Body.thickness_m must be None or finite and > 0, got {self.thickness_m}")
        if not 0.0 <= self.base_slip <= 1.0:
            raise ValueError(f"Body.base_slip must be in [0, 1], got {self.base_slip}")
        if self.thickness_m is None and self.base_slip != 0.0:
            raise ValueError(f"Body.base_slip {self.base_slip} is for a layer: a half-space has no backing")

    @property
    def compliance_per_pa(self) -> float:
        """k = (1 - nu^2) / E, 1/Pa."""
        return (1.0 - self.poisson**2) / self.modulus_pa


def layer_factor(qh: np.ndarray | float, *, poisson: float, base_slip: float = 0.0) -> np.ndarray:
    """S(qh): the layer's surface compliance relative to a half-space's.

    Parameters
    ----------
    qh : array_like
        Wavenumber (rad/m) times layer thickness (m), >= 0.
    poisson : float
        The layer's Poisson's ratio in [0, 0.5].
    base_slip : float
        0: bonded to its backing; 1: on a frictionless backing; between: the blend (module notes).

    Returns
    -------
    ndarray
        S in [0, 1]; written with exp(-2 qh) so that it never overflows.
    """
    x = np.asarray(qh, dtype=np.float64)
    kappa = 3.0 - 4.0 * poisson
    e2 = np.exp(-2.0 * x)
    e4 = e2 * e2
    bonded = (kappa * (1.0 - e4) - 4.0 * x * e2) / (kappa * (1.0 + e4) + (4.0 * x * x + 1.0 + kappa**2) * e2)
    if base_slip == 0.0:
        return bonded
    return (1.0 - base_slip) * bonded + base_slip * _slip_factor(x)


def _slip_factor(x: np.ndarray) -> np.ndarray:
    """S_slip(x) = (cosh 2x - 1) / (sinh 2x + 2x), written with exp(-2x); x/2 to first order, 0 at 0."""
    e2 = np.exp(-2.0 * x)
    denominator = -np.expm1(-4.0 * x) + 4.0 * x * e2
    return np.expm1(-2.0 * x) ** 2 / np.where(x > 0, denominator, 1.0)


@functools.lru_cache(maxsize=8)
def _layer_correction_table(poisson: float | None) -> tuple[np.ndarray, np.ndarray]:
    """f(rho) = integral_0^inf (S(x) - 1) J0(x rho) dx on a table of rho = r / h.

    For the bonded layer of this Poisson's ratio; None: the layer on a
    frictionless backing (S_slip does not depend on nu: one table). The layer's
    point-load displacement is the half-space's plus k / (pi h) * f(r / h)
    (k = (1 - nu^2)/E).
    """
    x = np.arange(0.0, _LAYER_X_MAX + _LAYER_X_STEP / 2, _LAYER_X_STEP)
    s_minus_1 = (_slip_factor(x) if poisson is None else layer_factor(x, poisson=poisson)) - 1.0
    weights = np.full(x.shape, _LAYER_X_STEP)
    weights[[0, -1]] *= 0.5  # trapezoid rule
    rho = np.arange(0.0, _LAYER_RHO_MAX + _LAYER_RHO_STEP / 2, _LAYER_RHO_STEP)
    table = np.empty_like(rho)
    for start in range(0, rho.size, 256):  # chunks keep the (rho, x) block small
        block = rho[start:start + 256, None] * x[None, :]
        table[start:start + 256] = j0(block) @ (weights * s_minus_1)
    return rho, table


def _layer_correction(r_m: np.ndarray, thickness_m: float, poisson: float, base_slip: float) -> np.ndarray:
    """The layer's point-load displacement minus the half-space's, per unit force and compliance (1/m^2)."""
    rho_table, f_table = _layer_correction_table(poisson)
    if base_slip > 0.0:  # the correction is linear in S: blend the tables
        f_table = (1.0 - base_slip) * f_table + base_slip * _layer_correction_table(None)[1]
    rho = r_m / thickness_m
    far = rho > rho_table[-1]  # both corrections' far field: S(0) = 0 for both backings
    f = np.interp(rho, rho_table, f_table)
    f[far] = -1.0 / rho[far]
    return f / (math.pi * thickness_m)


def _love_rectangle(x: np.ndarray, y: np.ndarray, half_x: float, half_y: float) -> np.ndarray:
    """Integral of 1/r over a rectangle of half-sides (half_x, half_y) centred at (x, y) from the origin.

    Johnson eq. 3.25 written with asinh (the log terms cancel between corners);
    with cell offsets the corners are never on an axis.
    """

    def corner(cx: np.ndarray, cy: np.ndarray) -> np.ndarray:
        return cx * np.arcsinh(cy / np.abs(cx)) + cy * np.arcsinh(cx / np.abs(cy))

    return (corner(x + half_x, y + half_y) - corner(x + half_x, y - half_y)
            - corner(x - half_x, y + half_y) + corner(x - half_x, y - half_y))


def _fft_size(n: int) -> int:
    """Smallest 2^a 3^b >= n: the sizes pocketfft transforms fastest."""
    return min(2**a * 3**b for a in range(int(math.log2(n)) + 2) for b in range(int(math.log(n, 3)) + 2)
               if 2**a * 3**b >= n)


@functools.lru_cache(maxsize=16)
def _unit_kernels(shape: tuple[int, int], cell_m: tuple[float, float], thickness_m: float | None,
                  poisson: float, base_slip: float) -> tuple[tuple[int, int], np.ndarray, np.ndarray | None]:
    """FFTs of the influence coefficients for unit compliance k = 1 on the zero-padded grid.

    Returns the padded shape, the half-space kernel's rFFT and the layer
    correction's rFFT (None for a half-space).
    """
    rows, cols = shape
    dy, dx = cell_m
    padded = (_fft_size(2 * rows - 1), _fft_size(2 * cols - 1))
    i = np.arange(-(rows - 1), rows)[:, None]
    j = np.arange(-(cols - 1), cols)[None, :]
    y, x = i * dy, j * dx
    half_space = _love_rectangle(x, y, dx / 2, dy / 2) / math.pi

    def spectrum(kernel: np.ndarray) -> np.ndarray:
        full = np.zeros(padded)
        full[np.ix_(np.arange(-(rows - 1), rows) % padded[0], np.arange(-(cols - 1), cols) % padded[1])] = kernel
        return scipy.fft.rfft2(full).astype(np.complex64)  # single precision halves the solver's time

    correction = None
    if thickness_m is not None:
        offsets = (np.arange(_LAYER_SUBCELLS) + 0.5) / _LAYER_SUBCELLS - 0.5
        total = np.zeros(half_space.shape)
        for oy in offsets:  # average over sub-points of the source cell: 16 vectorised passes
            for ox in offsets:
                total += _layer_correction(np.hypot(x + ox * dx, y + oy * dy), thickness_m, poisson, base_slip)
        correction = spectrum(total * (dx * dy / _LAYER_SUBCELLS**2))
    return padded, spectrum(half_space), correction


class Influence:
    """Surface displacements of the gel and the object under a pressure field on a grid.

    Parameters
    ----------
    shape : (int, int)
        Grid (rows, cols).
    cell_m : (float, float)
        Cell size (row pitch, column pitch), m.
    gel : Body
        The gel; a layer when ``gel.thickness_m`` is set (bonded, sliding on its
        backing or between: ``gel.base_slip``). Its thickness must be at
        least the larger cell side (the layer correction is averaged over
        ``_LAYER_SUBCELLS``^2 points of a cell).
    obj : Body
        The object: a half-space (its ``thickness_m`` must be None).
    """

    def __init__(self, shape: tuple[int, int], cell_m: tuple[float, float], *, gel: Body, obj: Body) -> None:
        if len(shape) != 2 or min(shape) < 1:
            raise ValueError(f"Influence: shape must be (rows, cols) >= 1, got {shape}")
        if not all(math.isfinite(c) and c > 0 for c in cell_m):
            raise ValueError(f"Influence: cell_m must be two positive sizes in metres, got {cell_m}")
        if obj.thickness_m is not None:
            raise ValueError("Influence: the object is a half-space; obj.thickness_m must be None")
        if gel.thickness_m is not None and gel.thickness_m < max(cell_m):
            raise ValueError(
                f"Influence: gel thickness {gel.thickness_m} m is below the cell size {max(cell_m)} m; "
                "refine the grid"
            )
        self.shape = (int(shape[0]), int(shape[1]))
        self.cell_m = (float(cell_m[0]), float(cell_m[1]))
        self.cell_area_m2 = self.cell_m[0] * self.cell_m[1]
        self.gel_body, self.object_body = gel, obj
        self._padded, half_space, correction = _unit_kernels(
            self.shape, self.cell_m, gel.thickness_m, float(gel.poisson), float(gel.base_slip)
        )
        self._buffer = np.zeros(self._padded, dtype=np.float32)  # scratch input: not for sharing across threads
        k_gel, k_obj = gel.compliance_per_pa, obj.compliance_per_pa
        self._gel = k_gel * half_space if correction is None else k_gel * (half_space + correction)
        self._object = k_obj * half_space
        self._total = self._gel + self._object
        # Displacement of a cell under its own unit pressure: scales the first guess of a solve.
        self.self_compliance_m_per_pa = float(self.total(_unit_impulse(self.shape))[0, 0])

    def _apply(self, spectrum: np.ndarray, pressure_pa: np.ndarray) -> np.ndarray:
        rows, cols = self.shape
        # The zero padding stays in place between calls: only the grid's corner is rewritten.
        self._buffer[:rows, :cols] = pressure_pa
        product = scipy.fft.rfft2(self._buffer)
        product *= spectrum
        return scipy.fft.irfft2(product, s=self._padded, overwrite_x=True)[:rows, :cols].astype(np.float64)

    def total(self, pressure_pa: np.ndarray) -> np.ndarray:
        """Gel plus object surface displacement (m) under ``pressure_pa``."""
        return self._apply(self._total, pressure_pa)

    def gel(self, pressure_pa: np.ndarray) -> np.ndarray:
        """The gel's surface displacement (m, into the gel): what the tactile sensor images."""
        return self._apply(self._gel, pressure_pa)

    def object(self, pressure_pa: np.ndarray) -> np.ndarray:
        """The object's surface displacement (m, into the object)."""
        return self._apply(self._object, pressure_pa)


def _unit_impulse(shape: tuple[int, int]) -> np.ndarray:
    impulse = np.zeros(shape)
    impulse[0, 0] = 1.0
    return impulse


@dataclass(frozen=True)
class ContactSolution:
    """A solved contact; falsy when the solver did not converge (``reason`` says why).

    Attributes
    ----------
    pressure_pa : ndarray (rows, cols)
        Contact pressure, >= 0.
    contact : ndarray of bool (rows, cols)
        Cells carrying pressure.
    force_n, approach_m : float
        Total force and rigid-body approach of the two surfaces (m).
    gel_displacement_m : ndarray (rows, cols)
        The gel's normal surface displacement (m, into the gel; negative where a
        nearly incompressible layer bulges).
    object_displacement_m : ndarray (rows, cols)
        The object's normal surface displacement (m).
    model : str
        "bem-layer", "bem-half-space" or "hertz".
    """

    pressure_pa: np.ndarray
    contact: np.ndarray
    force_n: float
    approach_m: float
    gel_displacement_m: np.ndarray
    object_displacement_m: np.ndarray
    model: str
    iterations: int = 0
    converged: bool = True
    reason: str = ""

    def __bool__(self) -> bool:
        return self.converged


def solve_contact(
    gap_m: np.ndarray,
    influence: Influence,
    *,
    force_n: float | None = None,
    approach_m: float | None = None,
    initial_pressure_pa: np.ndarray | None = None,
    tolerance: float = 1e-6,
    max_iterations: int = 500,
) -> ContactSolution:
    """Solve the frictionless normal contact on a grid (Polonsky-Keer conjugate gradient).

    Parameters
    ----------
    gap_m : ndarray (rows, cols)
        Initial separation of the two surfaces before loading (m, >= 0 where the
        object faces the cell; :data:`NO_CONTACT_GAP_M` where it does not).
    influence : Influence
        Bodies and grid.
    force_n, approach_m : float
        Exactly one: the total normal force (N, > 0) or the approach of the two
        bodies (m, > 0).
    initial_pressure_pa : ndarray, optional
        A previous solution to start from (warm start); rescaled to ``force_n``.
    tolerance : float
        Stop when the L1 change of the pressure relative to its total is below it.
    max_iterations : int

    Returns
    -------
    ContactSolution
        Falsy with a reason when the iteration did not converge or no cell can
        touch (e.g. an approach smaller than every gap).
    """
    gap = np.asarray(gap_m, dtype=np.float64)
    if gap.shape != influence.shape:
        raise ValueError(f"solve_contact: gap_m has shape {gap.shape}, the influence grid is {influence.shape}")
    if not np.isfinite(gap).all() or (gap < 0).any():
        raise ValueError("solve_contact: gap_m must be finite and >= 0 (m)")
    if (force_n is None) == (approach_m is None):
        raise ValueError("solve_contact: give exactly one of force_n and approach_m")
    by_force = force_n is not None
    target = float(force_n if by_force else approach_m)
    if not (math.isfinite(target) and target > 0):
        name = "force_n" if by_force else "approach_m"
        raise ValueError(f"solve_contact: {name} must be finite and > 0, got {target}")
    area = influence.cell_area_m2
    model = "bem-layer" if influence.gel_body.thickness_m is not None else "bem-half-space"

    if initial_pressure_pa is not None and np.asarray(initial_pressure_pa).sum() > 0:
        p = np.array(initial_pressure_pa, dtype=np.float64)
        if p.shape != gap.shape:
            raise ValueError(f"solve_contact: initial_pressure_pa has shape {p.shape}, expected {gap.shape}")
        p = np.maximum(p, 0.0)
    else:
        # First guess: each overlapping cell pressed alone to close its overlap.
        reach = (target * influence.self_compliance_m_per_pa / area) if by_force else target
        p = np.maximum(reach - gap, 0.0) / influence.self_compliance_m_per_pa
        if not p.any():
            p = (gap <= gap.min()).astype(np.float64)
    if by_force:
        p *= target / (p.sum() * area)
    elif not (gap < target).any():
        return _solution(p * 0.0, gap, influence, model, 0, False,
                         f"approach {target:.3g} m is smaller than every gap (min {gap.min():.3g} m)")

    search = np.zeros_like(p)
    norm_old, conjugate = 1.0, False
    approach = target
    displacement = influence.total(p)  # kept up to date below: one convolution per step, two when cells switch
    for iteration in range(1, max_iterations + 1):
        active = p > 0
        residual = displacement + gap
        if by_force:
            approach = residual[active].mean()
        residual -= approach
        norm = float(np.sum(residual[active] ** 2))
        search = np.where(active, residual + (norm / norm_old if conjugate else 0.0) * search, 0.0)
        norm_old = norm
        response = influence.total(search)
        centred = response - response[active].mean() if by_force else response
        curvature = float(np.sum(centred[active] * search[active]))
        if curvature <= 0:
            break  # the residual vanished on the contact cells: converged
        step = float(np.sum(residual[active] * search[active])) / curvature
        p_old = p
        trial = p - step * search
        p = np.maximum(trial, 0.0)
        overlap = (p == 0) & (residual < 0)
        conjugate = not overlap.any()
        p[overlap] -= step * residual[overlap]
        displacement -= step * response
        switched = p - trial
        if switched.any():
            displacement += influence.total(switched)
        total = p.sum()
        if total <= 0:
            return _solution(p, gap, influence, model, iteration, False, "the pressure vanished everywhere")
        if by_force:
            scale = target / (total * area)
            p *= scale
            displacement *= scale
        if np.abs(p - p_old).sum() < tolerance * p.sum():
            return _solution(p, gap, influence, model, iteration, True, "")
    else:
        return _solution(p, gap, influence, model, max_iterations, False,
                         f"no convergence to {tolerance:g} in {max_iterations} iterations")
    return _solution(p, gap, influence, model, iteration, True, "")


def _solution(p: np.ndarray, gap: np.ndarray, influence: Influence, model: str, iterations: int,
              converged: bool, reason: str) -> ContactSolution:
    gel = influence.gel(p)
    obj = influence.object(p)
    contact = p > 0
    approach = float(np.mean((gel + obj + gap)[contact])) if contact.any() else 0.0
    return ContactSolution(
        pressure_pa=p, contact=contact, force_n=float(p.sum() * influence.cell_area_m2), approach_m=approach,
        gel_displacement_m=gel, object_displacement_m=obj, model=model, iterations=iterations,
        converged=converged, reason=reason,
    )


# --------------------------------------------------------------------------- closed forms


def hertz_sphere(force_n: float | np.ndarray, *, radius_m: float, e_star_pa: float
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Hertz: a sphere of radius R on a flat, both elastic half-spaces.

    Returns
    -------
    contact_radius_m, approach_m, peak_pressure_pa : ndarray
        a = (3 F R / (4 E*))^(1/3), delta = a^2 / R, p0 = 3 F / (2 pi a^2).
    """
    force = np.asarray(force_n, dtype=np.float64)
    a = np.cbrt(3.0 * force * radius_m / (4.0 * e_star_pa))
    with np.errstate(divide="ignore", invalid="ignore"):
        p0 = np.where(a > 0, 3.0 * force / (2.0 * np.pi * a**2), 0.0)
    return a, a**2 / radius_m, p0


def hertz_surface_displacement(r_m: np.ndarray, *, contact_radius_m: float, radius_m: float) -> np.ndarray:
    """Sum of both bodies' normal surface displacements at distance r from the Hertz contact centre (m).

    Inside the contact it is delta - r^2 / (2R); outside (Johnson eq. 3.42b)
    (a^2 / (pi R)) [(2 - r^2/a^2) asin(a/r) + sqrt(r^2/a^2 - 1)]. Each body's
    share is its compliance over the sum.
    """
    r = np.abs(np.asarray(r_m, dtype=np.float64))
    a, big_r = contact_radius_m, radius_m
    if a <= 0:
        return np.zeros_like(r)
    inside = a * a / big_r - r * r / (2.0 * big_r)
    ratio = np.maximum(r / a, 1.0)
    outside = (a * a / (np.pi * big_r)) * ((2.0 - ratio**2) * np.arcsin(1.0 / ratio) + np.sqrt(ratio**2 - 1.0))
    return np.where(r <= a, inside, outside)


def hertz_contact(force_n: float, *, shape: tuple[int, int], cell_m: tuple[float, float],
                  centre_rc: tuple[float, float], radius_m: float, gel: Body, obj: Body) -> ContactSolution:
    """The Hertz solution sampled at the cell centres of a grid, as a :class:`ContactSolution`.

    ``centre_rc`` is the contact centre in (row, col) cell units. Valid where
    both bodies behave as half-spaces (the gel's thickness is ignored here).
    """
    k_gel, k_obj = gel.compliance_per_pa, obj.compliance_per_pa
    a, approach, p0 = (float(v) for v in hertz_sphere(force_n, radius_m=radius_m, e_star_pa=1.0 / (k_gel + k_obj)))
    rows, cols = np.indices(shape, dtype=np.float64)
    r = np.hypot((rows - centre_rc[0]) * cell_m[0], (cols - centre_rc[1]) * cell_m[1])
    pressure = p0 * np.sqrt(np.clip(1.0 - (r / a) ** 2, 0.0, None)) if a > 0 else np.zeros(shape)
    total = hertz_surface_displacement(r, contact_radius_m=a, radius_m=radius_m)
    return ContactSolution(
        pressure_pa=pressure, contact=pressure > 0, force_n=float(force_n), approach_m=approach,
        gel_displacement_m=total * (k_gel / (k_gel + k_obj)),
        object_displacement_m=total * (k_obj / (k_gel + k_obj)), model="hertz",
    )


def layer_stiffening(contact_radius_m: float, *, gel: Body, obj: Body) -> float:
    """First-order relative reduction of the Hertz approach by the gel layer's finite thickness.

    For a contact small against the layer (a << h) the layer removes a nearly
    uniform displacement F k_gel I / (pi h), I = integral_0^inf (1 - S(x)) dx, from
    the half-space solution; relative to the Hertz approach a^2 / R that is
    (4 / (3 pi)) (k_gel / (k_gel + k_obj)) I a / h. (At nu = 0.5 and a rigid object
    this is 0.751 a/h; as F ~ approach^1.5, the force at fixed approach rises by 1.5
    times that, 1.127 a/h: the 1.133 a/h term of Dimitriadis et al., Biophys. J. 82
    (2002) 2798.)
    S is the gel's own (its ``base_slip``). Zero for a half-space gel.
    """
    if gel.thickness_m is None:
        return 0.0
    x = np.arange(0.0, _LAYER_X_MAX, _LAYER_X_STEP)
    integral = float(np.trapezoid(1.0 - layer_factor(x, poisson=gel.poisson, base_slip=gel.base_slip), x))
    share = gel.compliance_per_pa / (gel.compliance_per_pa + obj.compliance_per_pa)
    return 4.0 / (3.0 * math.pi) * share * integral * contact_radius_m / gel.thickness_m


def gel_shear(gel_displacement_m: np.ndarray, *, cell_m: tuple[float, float], thickness_m: float) -> np.ndarray:
    """In-plane displacement of the gel surface (m), an approximation for the marker pattern.

    The gel is nearly incompressible and bonded to its backing, so the volume an
    indentation w displaces flows sideways through the layer: with a parabolic
    (Poiseuille-like) profile, no slip at the backing and a free surface, the
    depth-averaged displacement U satisfies h div U = w and the surface moves by
    1.5 U. U is taken as a gradient field, U = grad phi with
    (laplacian - 1/l^2) phi = w / h, screened over l = 2 h because the bonded
    base holds the layer beyond a few thicknesses; solved with zero-padded FFTs.
    Friction between the object and the gel is ignored.

    Parameters
    ----------
    gel_displacement_m : ndarray (..., rows, cols)
        The gel's normal surface displacement (m, into the gel); leading axes are
        independent fields (e.g. force levels), transformed together.
    cell_m : (float, float)
        Cell size (row pitch, column pitch), m.
    thickness_m : float
        Gel thickness h, m.

    Returns
    -------
    ndarray (..., rows, cols, 2)
        [d_col, d_row] surface displacement, m (columns to the right, rows down).
    """
    w = np.asarray(gel_displacement_m, dtype=np.float64)
    rows, cols = w.shape[-2:]
    padded = (scipy.fft.next_fast_len(2 * rows, real=True), scipy.fft.next_fast_len(2 * cols, real=True))
    k_row = 2.0 * np.pi * scipy.fft.fftfreq(padded[0], d=cell_m[0])[:, None]
    k_col = 2.0 * np.pi * scipy.fft.rfftfreq(padded[1], d=cell_m[1])[None, :]
    screening = 1.0 / (2.0 * thickness_m) ** 2
    phi = -scipy.fft.rfft2(w, s=padded) / (thickness_m * (k_row**2 + k_col**2 + screening))
    d_col = scipy.fft.irfft2(1j * k_col * phi, s=padded)[..., :rows, :cols]
    d_row = scipy.fft.irfft2(1j * k_row * phi, s=padded)[..., :rows, :cols]
    return 1.5 * np.stack([d_col, d_row], axis=-1)
