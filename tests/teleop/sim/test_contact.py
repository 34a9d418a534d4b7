"""The contact solver (teleop.sim.contact) against closed forms and published layer solutions."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.linalg import expm

from teleop.sim.contact import (
    NO_CONTACT_GAP_M,
    Body,
    Influence,
    gel_shear,
    hertz_contact,
    hertz_sphere,
    hertz_surface_displacement,
    layer_factor,
    layer_stiffening,
    solve_contact,
)

GEL = Body(1.0e6, 0.3)  # half-space unless a thickness is given
OBJECT = Body(3.0e6, 0.45)
RIGID = Body(1.0e15, 0.3)


def e_star(*bodies: Body) -> float:
    return 1.0 / sum(b.compliance_per_pa for b in bodies)


def centred_radius(n_rows: int, n_cols: int, cell_m: float) -> np.ndarray:
    rows, cols = np.indices((n_rows, n_cols))
    return np.hypot((rows - (n_rows - 1) / 2) * cell_m, (cols - (n_cols - 1) / 2) * cell_m)


def sphere_gap(radius_m: float, r: np.ndarray) -> np.ndarray:
    return np.where(r < radius_m, radius_m - np.sqrt(np.clip(radius_m**2 - r**2, 0.0, None)), NO_CONTACT_GAP_M)


# --------------------------------------------------------------------------- half-space closed forms


@pytest.mark.parametrize("obj", [RIGID, OBJECT], ids=["rigid sphere", "elastic sphere"])
def test_bem_sphere_follows_hertz_over_the_loading_range(obj):
    cell, radius = 1e-4, 0.01
    r = centred_radius(64, 64, cell)
    gap = sphere_gap(radius, r)
    influence = Influence((64, 64), (cell, cell), gel=GEL, obj=obj)
    previous = None
    for force in (0.05, 0.2, 0.5, 1.0, 2.0):
        solution = solve_contact(gap, influence, force_n=force, initial_pressure_pa=previous, tolerance=1e-7)
        assert solution, solution.reason
        previous = solution.pressure_pa
        a, approach, p0 = (float(v) for v in hertz_sphere(force, radius_m=radius, e_star_pa=e_star(GEL, obj)))
        assert solution.approach_m == pytest.approx(approach, rel=0.02)
        # F(delta) of the BEM against the closed form at the BEM's approach.
        hertz_force = 4.0 / 3.0 * e_star(GEL, obj) * math.sqrt(radius) * solution.approach_m**1.5
        assert solution.force_n == pytest.approx(hertz_force, rel=0.02)
        contact_radius = math.sqrt(solution.contact.sum() * cell**2 / math.pi)
        assert abs(contact_radius - a) < cell
        assert solution.pressure_pa.max() == pytest.approx(p0, rel=0.03)


def test_gel_share_of_the_approach_is_its_compliance_share():
    """Half-spaces under one pressure: d / delta = k_gel / (k_gel + k_obj) at the first-contact point."""
    cell = 1e-4
    r = centred_radius(64, 64, cell)
    influence = Influence((64, 64), (cell, cell), gel=GEL, obj=OBJECT)
    solution = solve_contact(sphere_gap(0.01, r), influence, force_n=1.0, tolerance=1e-7)
    centre = np.unravel_index(np.argmin(r), r.shape)
    share = GEL.compliance_per_pa / (GEL.compliance_per_pa + OBJECT.compliance_per_pa)
    assert solution.gel_displacement_m[centre] / solution.approach_m == pytest.approx(share, rel=0.01)


def test_flat_punch_stiffness_is_2_a_e_star():
    cell, a, approach = 1e-4, 2e-3, 1e-5
    n = int(2 * a / cell) + 8
    r = centred_radius(n, n, cell)
    gap = np.where(r <= a, 0.0, NO_CONTACT_GAP_M)
    influence = Influence((n, n), (cell, cell), gel=GEL, obj=OBJECT)
    solution = solve_contact(gap, influence, approach_m=approach, tolerance=1e-7, max_iterations=2000)
    assert solution, solution.reason
    assert solution.force_n == pytest.approx(2 * a * e_star(GEL, OBJECT) * approach, rel=0.02)
    # The rim carries the singular pressure of a flat punch.
    ring = (r > a - 1.5 * cell) & (r <= a)
    assert solution.pressure_pa[ring].mean() > 2 * solution.pressure_pa[r < a / 2].mean()


def test_cylinder_line_contact_half_width():
    """A long cylinder on its side: b = sqrt(4 F' R / (pi E*)) at its middle, F' the load per length there."""
    cell, radius = 5e-5, 5e-3
    rows, cols = 120, 400
    y = (np.indices((rows, cols))[0] - (rows - 1) / 2) * cell
    gap = radius - np.sqrt(radius**2 - y**2)
    influence = Influence((rows, cols), (cell, cell), gel=GEL, obj=OBJECT)
    solution = solve_contact(gap, influence, force_n=5.0, tolerance=1e-7, max_iterations=2000)
    assert solution, solution.reason
    middle = cols // 2
    load_per_length = solution.pressure_pa[:, middle].sum() * cell
    expected = math.sqrt(4 * load_per_length * radius / (math.pi * e_star(GEL, OBJECT)))
    assert solution.contact[:, middle].sum() * cell / 2 == pytest.approx(expected, rel=0.05)


def test_error_shrinks_as_the_grid_is_refined():
    """Paraboloid (exactly Hertz's profile): the pressure field's error against Hertz falls with the cell size."""
    radius, extent, approach = 0.01, 4e-3, 1e-4
    a = math.sqrt(radius * approach)
    p0 = 2 * e_star(GEL, RIGID) * a / (math.pi * radius)
    errors, force_errors = [], []
    for cell in (4e-4, 2e-4, 1e-4):
        n = int(round(extent / cell))
        r = centred_radius(n, n, cell)
        influence = Influence((n, n), (cell, cell), gel=GEL, obj=RIGID)
        solution = solve_contact(r**2 / (2 * radius), influence, approach_m=approach, tolerance=1e-8)
        hertz = p0 * np.sqrt(np.clip(1 - (r / a) ** 2, 0.0, None))
        errors.append(np.sqrt(np.mean((solution.pressure_pa - hertz)[r < 1.2 * a] ** 2)) / p0)
        force_errors.append(solution.force_n / (4 / 3 * e_star(GEL, RIGID) * math.sqrt(radius) * approach**1.5) - 1)
    assert errors[0] > errors[1] > errors[2]
    assert errors[2] < 0.015 and abs(force_errors[2]) < 0.005


# --------------------------------------------------------------------------- the bonded layer


def test_layer_factor_limits():
    for nu in (0.0, 0.3, 0.48, 0.5):
        assert layer_factor(40.0, poisson=nu) == pytest.approx(1.0, abs=1e-12)
        x = 1e-4  # thin layer: u/p -> h (1 + nu)(1 - 2 nu) / (E (1 - nu)), i.e. S -> x (1 - 2 nu) / (2 (1 - nu)^2)
        if nu < 0.5:
            assert layer_factor(x, poisson=nu) == pytest.approx(x * (1 - 2 * nu) / (2 * (1 - nu) ** 2), rel=1e-3)
    s = layer_factor(np.linspace(0.0, 10.0, 200), poisson=0.48)
    assert np.all(np.diff(s) >= 0) and s[0] == 0.0 and np.isfinite(layer_factor(1e4, poisson=0.48))


@pytest.mark.parametrize("nu", [0.3, 0.4, 0.48, 0.5])
def test_layer_first_order_term_matches_dimitriadis(nu):
    """The layer's first-order correction, integral of (1 - S), against Dimitriadis et al. (2002)'s alpha_0 fit."""
    alpha_0 = (1.2876 - 1.4678 * nu + 1.3442 * nu**2) / (1 - nu)
    gel = Body(1e6, nu, 1e-3)
    a = 1e-5  # stiffening = 4 / (3 pi) * integral * a / h for a rigid object
    integral = layer_stiffening(a, gel=gel, obj=RIGID) / (4 / (3 * math.pi) * a / 1e-3)
    assert integral == pytest.approx(alpha_0, rel=0.01)


@pytest.mark.parametrize("chi", [0.15, 0.3])
def test_rigid_sphere_on_bonded_layer_matches_published_correction(chi):
    """Rigid sphere on an incompressible layer bonded to a rigid base, frictionless contact.

    F = (16 E / 9) R^1/2 delta^3/2 * f(chi), chi = sqrt(R delta) / h, with f from
    Garcia & Garcia, Biophys. J. 114 (2018) 2923 and Dimitriadis et al., Biophys. J. 82 (2002) 2798.
    """
    cell, radius, approach = 5e-5, 0.01, 8e-5
    thickness = math.sqrt(radius * approach) / chi
    gel = Body(1e6, 0.5, thickness)
    n = 96
    influence = Influence((n, n), (cell, cell), gel=gel, obj=RIGID)
    solution = solve_contact(sphere_gap(radius, centred_radius(n, n, cell)), influence, approach_m=approach,
                             tolerance=1e-7)
    assert solution, solution.reason
    ratio = solution.force_n / (16 * 1e6 / 9 * math.sqrt(radius) * approach**1.5)
    garcia = 1 + 1.133 * chi + 1.497 * chi**2 + 1.469 * chi**3 + 0.755 * chi**4
    dimitriadis = 1 + 1.133 * chi + 1.283 * chi**2 + 0.769 * chi**3 + 0.0975 * chi**4
    assert ratio == pytest.approx(garcia, rel=0.015)
    assert ratio == pytest.approx(dimitriadis, rel=0.03)


def _plane_strain_factor(qh: float, nu: float, *, slip: bool) -> float:
    """S from Navier's equations for one pressure wave, solved directly (no Chen & Engel formula).

    u_x = U(z) sin qx, u_z = W(z) cos qx on a layer 0 <= z <= h (z into it, h = 1); the state
    (U, U', W, W') is propagated by expm; the loaded frictionless top and the backing give four
    conditions, W(h) = 0 and U(h) = 0 (bonded) or U'(h) = 0 (no shear: slip).
    """
    q, modulus = qh, 1.0
    mu, lam = modulus / (2 * (1 + nu)), modulus * nu / ((1 + nu) * (1 - 2 * nu))
    system = np.zeros((4, 4))
    system[0, 1] = system[2, 3] = 1.0
    system[1, 0], system[1, 3] = q * q * (lam + 2 * mu) / mu, q * (lam + mu) / mu
    system[3, 2], system[3, 1] = mu * q * q / (lam + 2 * mu), -q * (lam + mu) / (lam + 2 * mu)
    base = expm(system)
    conditions = np.array([[lam * q, 0, 0, lam + 2 * mu],  # sigma_zz(0) = -p
                           [0, 1, -q, 0],  # no shear at the top
                           base[2],  # W(h) = 0
                           base[1] if slip else base[0]])
    state = np.linalg.solve(conditions, [-1.0, 0.0, 0.0, 0.0])
    return state[2] / (2 * (1 - nu**2) / (modulus * q))


@pytest.mark.parametrize("nu", [0.0, 0.3, 0.45])
def test_both_backings_match_a_direct_plane_strain_solution(nu):
    for qh in (0.05, 0.5, 2.0):
        assert layer_factor(qh, poisson=nu) == pytest.approx(_plane_strain_factor(qh, nu, slip=False), rel=1e-8)
        assert layer_factor(qh, poisson=nu, base_slip=1.0) == pytest.approx(
            _plane_strain_factor(qh, nu, slip=True), rel=1e-8)


def test_sliding_layer_factor_limits():
    for nu in (0.0, 0.3, 0.48, 0.5):
        assert layer_factor(40.0, poisson=nu, base_slip=1.0) == pytest.approx(1.0, abs=1e-12)
        x = 1e-4  # thin layer free to slide: u/p -> h (1 - nu^2) / E, i.e. S -> x / 2 whatever nu
        assert layer_factor(x, poisson=nu, base_slip=1.0) == pytest.approx(x / 2, rel=1e-3)
    x = np.linspace(0.0, 10.0, 200)
    slip = layer_factor(x, poisson=0.48, base_slip=1.0)
    bonded = layer_factor(x, poisson=0.48)
    assert slip[0] == 0.0 and np.all(np.diff(slip) >= 0) and np.isfinite(layer_factor(1e4, poisson=0.48, base_slip=1))
    # Softer than the bonded layer, stiffer than the half-space; a partly bonded backing lies between.
    assert np.all(slip[1:] > bonded[1:]) and np.all(slip < 1.0)
    half = layer_factor(x, poisson=0.48, base_slip=0.5)
    np.testing.assert_allclose(half, 0.5 * (slip + bonded), rtol=1e-12)
    assert 0 < layer_stiffening(1e-4, gel=Body(1e6, 0.48, 1e-3, base_slip=1.0), obj=RIGID) < layer_stiffening(
        1e-4, gel=Body(1e6, 0.48, 1e-3), obj=RIGID)


@pytest.mark.parametrize("nu", [0.3, 0.48])
def test_wide_punch_on_a_sliding_layer_reaches_its_thin_layer_asymptote(nu):
    """a >> h on a lubricated backing: the layer spreads sideways, F -> A E delta / ((1 - nu^2) h),
    far below the bonded layer's confined compression when the gel is nearly incompressible."""
    cell, thickness, a, approach = 1e-4, 5e-4, 4.5e-3, 1e-5
    n = 100
    r = centred_radius(n, n, cell)
    gap = np.where(r <= a, 0.0, NO_CONTACT_GAP_M)
    forces = {slip: solve_contact(gap, Influence((n, n), (cell, cell), gel=Body(1e6, nu, thickness, base_slip=slip),
                                                 obj=RIGID), approach_m=approach, tolerance=1e-7,
                                  max_iterations=2000).force_n for slip in (0.0, 0.5, 1.0)}
    area = (r <= a).sum() * cell**2
    assert forces[1.0] == pytest.approx(area * 1e6 * approach / ((1 - nu**2) * thickness), rel=0.05)
    assert forces[1.0] < forces[0.5] < forces[0.0]
    if nu == 0.48:
        assert forces[0.0] > 4 * forces[1.0]


def test_wide_punch_on_a_thin_layer_reaches_the_confined_compression_asymptote():
    """a >> h: the layer acts as a bed of confined columns, F -> A M delta / h (M the P-wave modulus)."""
    cell, thickness, a, approach = 1e-4, 5e-4, 4.5e-3, 1e-5
    nu = 0.3
    gel = Body(1e6, nu, thickness)
    n = 100
    r = centred_radius(n, n, cell)
    gap = np.where(r <= a, 0.0, NO_CONTACT_GAP_M)
    layered = solve_contact(gap, Influence((n, n), (cell, cell), gel=gel, obj=RIGID), approach_m=approach,
                            tolerance=1e-7, max_iterations=2000)
    half_space = solve_contact(gap, Influence((n, n), (cell, cell), gel=Body(1e6, nu), obj=RIGID),
                               approach_m=approach, tolerance=1e-7, max_iterations=2000)
    p_wave_modulus = 1e6 * (1 - nu) / ((1 + nu) * (1 - 2 * nu))
    area = (r <= a).sum() * cell**2
    assert layered.force_n == pytest.approx(area * p_wave_modulus * approach / thickness, rel=0.05)
    assert layered.force_n > 5 * half_space.force_n


def test_sensor_gel_is_measurably_stiffer_than_a_half_space_for_wide_contacts():
    """The real gel (3 mm, nu 0.48) under a rigid sphere: stiffening grows with contact radius / thickness."""
    cell, radius = 2e-4, 0.01
    n = 100
    gap = sphere_gap(radius, centred_radius(n, n, cell))
    layer = Influence((n, n), (cell, cell), gel=Body(2.75e5, 0.48, 3e-3), obj=RIGID)
    half_space = Influence((n, n), (cell, cell), gel=Body(2.75e5, 0.48), obj=RIGID)
    ratios = []
    for approach in (2e-5, 2e-4, 1e-3):
        f_layer = solve_contact(gap, layer, approach_m=approach, tolerance=1e-6).force_n
        f_half = solve_contact(gap, half_space, approach_m=approach, tolerance=1e-6).force_n
        ratios.append(f_layer / f_half)
    assert 1.0 < ratios[0] < ratios[1] < ratios[2]
    assert ratios[2] > 1.5  # a = sqrt(R delta) ~ 3.2 mm > h


# --------------------------------------------------------------------------- solver behaviour


def test_warm_start_needs_fewer_iterations():
    cell = 2e-4
    gap = sphere_gap(0.01, centred_radius(60, 60, cell))
    influence = Influence((60, 60), (cell, cell), gel=Body(2.75e5, 0.48, 3e-3), obj=OBJECT)
    first = solve_contact(gap, influence, force_n=5.0, tolerance=1e-6)
    cold = solve_contact(gap, influence, force_n=5.5, tolerance=1e-6)
    warm = solve_contact(gap, influence, force_n=5.5, tolerance=1e-6, initial_pressure_pa=first.pressure_pa)
    assert warm.iterations < cold.iterations
    assert warm.approach_m == pytest.approx(cold.approach_m, rel=1e-4)


def test_force_and_approach_loading_agree():
    cell = 2e-4
    gap = sphere_gap(0.01, centred_radius(50, 50, cell))
    influence = Influence((50, 50), (cell, cell), gel=Body(2.75e5, 0.48, 3e-3), obj=OBJECT)
    by_force = solve_contact(gap, influence, force_n=3.0, tolerance=1e-7)
    by_approach = solve_contact(gap, influence, approach_m=by_force.approach_m, tolerance=1e-7)
    assert by_approach.force_n == pytest.approx(3.0, rel=1e-3)
    assert np.all(by_force.pressure_pa >= 0) and np.isfinite(by_force.gel_displacement_m).all()


def test_failures_are_falsy_with_a_reason():
    cell = 2e-4
    gap = sphere_gap(0.01, centred_radius(40, 40, cell)) + 1e-3
    influence = Influence((40, 40), (cell, cell), gel=GEL, obj=OBJECT)
    short = solve_contact(gap, influence, approach_m=1e-4)
    assert not short and "smaller than every gap" in short.reason
    stopped = solve_contact(gap - 1e-3, influence, force_n=1.0, max_iterations=1, tolerance=1e-12)
    assert not stopped and "no convergence" in stopped.reason


def test_bad_input_is_named():
    influence = Influence((8, 8), (1e-4, 1e-4), gel=GEL, obj=OBJECT)
    with pytest.raises(ValueError, match="exactly one"):
        solve_contact(np.zeros((8, 8)), influence, force_n=1.0, approach_m=1e-5)
    with pytest.raises(ValueError, match="gap_m"):
        solve_contact(np.full((8, 8), np.nan), influence, force_n=1.0)
    inside = np.zeros((8, 8))
    inside[3, 3] = -1e-6  # an object already inside the gel: the caller's error, whichever load is given
    for load in ({"force_n": 1.0}, {"approach_m": 1e-5}):
        with pytest.raises(ValueError, match="gap_m"):
            solve_contact(inside, influence, **load)
    with pytest.raises(ValueError, match="shape"):
        solve_contact(np.zeros((4, 8)), influence, force_n=1.0)
    with pytest.raises(ValueError, match="force_n"):
        solve_contact(np.zeros((8, 8)), influence, force_n=-1.0)
    with pytest.raises(ValueError, match="thickness"):
        Influence((8, 8), (1e-3, 1e-3), gel=Body(1e6, 0.4, 1e-4), obj=OBJECT)
    with pytest.raises(ValueError, match="modulus_pa"):
        Body(float("nan"), 0.3)
    with pytest.raises(ValueError, match="base_slip must be in"):
        Body(1e6, 0.4, 1e-3, base_slip=1.5)
    with pytest.raises(ValueError, match="half-space has no backing"):
        Body(1e6, 0.4, base_slip=0.5)


# --------------------------------------------------------------------------- closed forms and shear


def test_hertz_closed_forms_are_the_textbook_ones():
    force, radius, estar = 2.0, 0.005, 4e5
    a, approach, p0 = (float(v) for v in hertz_sphere(force, radius_m=radius, e_star_pa=estar))
    assert force == pytest.approx(4 / 3 * estar * math.sqrt(radius) * approach**1.5)
    assert p0 == pytest.approx(3 * force / (2 * math.pi * a**2))
    assert p0 == pytest.approx((6 * force * estar**2 / radius**2) ** (1 / 3) / math.pi)
    total = hertz_surface_displacement(np.array([0.0, a, a * (1 + 1e-9), 3 * a]), contact_radius_m=a,
                                       radius_m=radius)
    assert total[0] == pytest.approx(approach) and total[1] == pytest.approx(approach / 2)
    # Outside (Johnson eq. 3.42b) it continues the inside at r = a and falls off as
    # (a^2 / (pi R)) [(2 - r^2/a^2) asin(a/r) + sqrt(r^2/a^2 - 1)]: the dent around every Hertz contact.
    assert total[2] == pytest.approx(approach / 2, rel=1e-6)
    outside = a * a / (math.pi * radius) * ((2 - 9) * math.asin(1 / 3) + math.sqrt(8))
    assert total[3] == pytest.approx(outside, rel=1e-9)
    # The gel's centre displacement: k_gel pi p0 a / 2 (the brief's corrected formula).
    gel, obj = Body(2.75e5, 0.48), Body(1e6, 0.4)
    cell = 1e-4
    solution = hertz_contact(force, shape=(41, 41), cell_m=(cell, cell), centre_rc=(20, 20), radius_m=radius,
                             gel=gel, obj=obj)
    a, _, p0 = (float(v) for v in hertz_sphere(force, radius_m=radius, e_star_pa=e_star(gel, obj)))
    assert solution.gel_displacement_m[20, 20] == pytest.approx(gel.compliance_per_pa * math.pi * p0 * a / 2)
    assert solution.model == "hertz" and solution


def test_gel_shear_flows_outward_and_scales_with_depth():
    cell = 2e-4
    r = centred_radius(60, 60, cell)
    depth = 1e-3 * np.exp(-((r / 2e-3) ** 2))
    shear = gel_shear(depth, cell_m=(cell, cell), thickness_m=3e-3)
    assert shear.shape == (60, 60, 2)
    right_of_centre, below_centre = shear[30, 40], shear[40, 30]
    assert right_of_centre[0] > 0 and below_centre[1] > 0  # away from the dent
    assert np.abs(shear).max() < 1e-3
    np.testing.assert_allclose(gel_shear(2 * depth, cell_m=(cell, cell), thickness_m=3e-3), 2 * shear, atol=1e-12)
    assert not gel_shear(np.zeros((10, 10)), cell_m=(cell, cell), thickness_m=3e-3).any()


def test_gel_shear_of_a_stack_is_the_shear_of_each_field():
    cell = 2e-4
    r = centred_radius(40, 50, cell)
    stack = np.stack([d * np.exp(-((r / 2e-3) ** 2)) for d in (0.2e-3, 1e-3)] + [np.roll(r, 7, axis=1) * 1e-2])
    shears = gel_shear(stack, cell_m=(cell, cell), thickness_m=3e-3)
    assert shears.shape == (3, 40, 50, 2)
    for field, shear in zip(stack, shears, strict=True):
        np.testing.assert_allclose(shear, gel_shear(field, cell_m=(cell, cell), thickness_m=3e-3), atol=1e-15)


def test_influence_gives_the_same_field_whatever_it_computed_before():
    """Its zero-padded scratch input is reused: no residue of an earlier pressure may leak in."""
    influence = Influence((30, 40), (2e-4, 2e-4), gel=Body(2.75e5, 0.48, 3e-3), obj=OBJECT)
    rng = np.random.default_rng(0)
    small, large = rng.uniform(0, 1e3, (30, 40)), rng.uniform(0, 1e6, (30, 40))
    first = influence.gel(small)
    influence.total(large)
    np.testing.assert_array_equal(influence.gel(small), first)
    np.testing.assert_allclose(influence.total(small), influence.gel(small) + influence.object(small),
                               rtol=1e-5, atol=1e-6 * np.abs(first).max())


def test_layer_stiffening_is_the_gels_share_of_the_compliance():
    """Only the gel's part of the approach is a layer's: against an object as soft as the gel, half of it
    (this decides where the simulator may use Hertz, the record's provenance model)."""
    gel = Body(1.0e6, 0.5, 2e-3)
    rigid = Body(1.0e15, 0.3)
    twin = Body(1.0e6, 0.5)
    a = 2e-4
    alone = layer_stiffening(a, gel=gel, obj=rigid)
    assert alone == pytest.approx(0.751 * a / 2e-3, rel=5e-3)  # the documented nu = 0.5 coefficient
    assert layer_stiffening(a, gel=gel, obj=twin) == pytest.approx(0.5 * alone, rel=1e-6)


def test_gel_shear_moves_the_surface_by_the_documented_flow():
    """Around a small dent the surface flows outward by 1.5 x the depth-averaged flow U, with
    h div U = w screened over l = 2 h: at radius R, 1.5 V / (2 pi R h) (R / l) K1(R / l) (V the dent's
    volume). The marker pattern's motion in every simulated frame is this field."""
    from scipy.special import k1

    cell, n, h, sigma = 1e-4, 201, 3e-3, 0.4e-3
    offsets = (np.arange(n) - n // 2) * cell
    yy, xx = np.meshgrid(offsets, offsets, indexing="ij")
    dent = 1e-5 * np.exp(-(xx**2 + yy**2) / (2 * sigma**2))
    volume = dent.sum() * cell**2
    shear = gel_shear(dent, cell_m=(cell, cell), thickness_m=h)
    c = n // 2
    for k in (15, 25):
        radius, screen = k * cell, 2 * h
        expected = 1.5 * volume / (2 * np.pi * radius * h) * (radius / screen) * k1(radius / screen)
        assert shear[c, c + k, 0] == pytest.approx(expected, rel=0.03)  # columns to the right
        assert shear[c + k, c, 1] == pytest.approx(expected, rel=0.03)  # rows down
