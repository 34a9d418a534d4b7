"""Drawn contact mechanics (teleop.sim.mechanics, ``teleop simulate --vary-contact``): draws, laws, records."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from teleop.catalogue import ObjectSpec, load_catalogue
from teleop.cli import main
from teleop.errors import SimulationError
from teleop.record import read_record, write_record
from teleop.settings import load_settings
from teleop.sim.contact import layer_factor
from teleop.sim.grasp import contact_grid, load_curve, simulate_grasp
from teleop.sim.mechanics import (
    CONTACT_SPREAD,
    LOG_UNIFORM,
    ContactMechanics,
    densify,
    draw_mechanics,
    gent_stress,
    rubber_stiffen,
)
from teleop.sim.shapes import Pose, make_scene
from teleop.sim.simulate import grasp_filename, grasp_rng, mechanics_rng

SEED = 3
BALL = ObjectSpec(name="small rubber ball", shape="sphere", material="rubber", modulus_pa=8.0e5, size_m=(0.02,) * 3)
RUBBER = ObjectSpec(name="rubber_ball", shape="sphere", material="rubber", modulus_pa=5.0e5, size_m=(0.03,) * 3)


def neutral(obj: ObjectSpec, **changes) -> ContactMechanics:
    """The simulator's own mechanics as a draw (then ``changes``)."""
    values = dict(base_slip=0.0, thickness_factor=1.0, object_poisson=obj.poisson, densification_factor=1.0,
                  densification_sharpness=1.0, rubber_weight=0.0, gent_locking=100.0, friction_stiffening=0.0,
                  size_factors=(1.0, 1.0, 1.0))
    return ContactMechanics(**{**values, **changes})


# --------------------------------------------------------------------------- the draw


def test_a_seed_gives_the_same_mechanics_and_each_grasp_its_own():
    first = draw_mechanics(mechanics_rng(SEED, BALL, 0))
    assert draw_mechanics(mechanics_rng(SEED, BALL, 0)) == first
    others = [draw_mechanics(mechanics_rng(SEED, BALL, i)) for i in (1, 2)]
    others += [draw_mechanics(mechanics_rng(SEED + 1, BALL, 0)), draw_mechanics(mechanics_rng(SEED, RUBBER, 0))]
    for other in others:
        assert other.base_slip != first.base_slip and other.size_factors != first.size_factors
    # Its own stream: not the grasp's, whose draws (rig, pose, noise) stay those of a grasp without it.
    assert draw_mechanics(grasp_rng(SEED, BALL, 0)) != first


def test_every_drawn_value_is_inside_its_documented_range():
    rng = np.random.default_rng(0)
    draws = [draw_mechanics(rng) for _ in range(400)]
    for field in dataclasses.fields(CONTACT_SPREAD):
        name = field.name
        bounds = getattr(CONTACT_SPREAD, name)
        values = np.array([d.size_factors for d in draws]).ravel() if name == "size_factor" else np.array(
            [getattr(d, name) for d in draws])
        assert bounds[0] <= values.min() and values.max() <= bounds[1], name
        # The draws cover the range: both ends' quarters are reached (log quarters for log-uniform ones).
        scale = np.log if name in LOG_UNIFORM else (lambda x: x)
        lo, hi = scale(bounds[0]), scale(bounds[1])
        assert scale(values.min()) < lo + 0.25 * (hi - lo) and scale(values.max()) > hi - 0.25 * (hi - lo), name
    assert CONTACT_SPREAD.object_poisson == (0.3, 0.5) and CONTACT_SPREAD.thickness_factor == (0.6, 1.5)


def test_the_held_out_half_space_is_never_drawn(settings):
    sensor = settings.sensors[0]
    rng = np.random.default_rng(1)
    for _ in range(300):
        gel = draw_mechanics(rng).gel_body(sensor)
        assert gel.thickness_m is not None and 0.6 * sensor.gel_thickness_m <= gel.thickness_m
        assert gel.modulus_pa == sensor.gel_modulus_pa and gel.poisson == sensor.gel_poisson  # the gel's own
        # A layer: at a contact as wide as it is thick it yields at most 1 - 1/e of what a half-space would.
        assert layer_factor(1.0, poisson=gel.poisson, base_slip=gel.base_slip) < 0.64


# --------------------------------------------------------------------------- the object's laws


def test_the_densification_family_holds_the_simulators_law():
    x = np.geomspace(1e-7, 0.1, 40)
    limit = 0.02
    np.testing.assert_allclose(densify(x, limit, sharpness=1.0), limit * -np.expm1(-x / limit), rtol=1e-14)
    gentle, sharp = densify(x, limit, sharpness=0.6), densify(x, limit, sharpness=3.0)
    for law in (gentle, sharp):
        assert np.all(law <= x * (1 + 1e-12)) and np.all(law <= limit)
        assert law[0] == pytest.approx(x[0], rel=1e-3)  # the small-force response is kept
    # A sharp wall stays linear longer, then stops closer to the limit.
    below, beyond = x < 0.3 * limit, x > 3 * limit
    assert np.all(sharp[below] > gentle[below]) and np.all(sharp[beyond] > gentle[beyond])


def test_gent_stress_is_neo_hookean_until_its_chains_lock():
    eps = np.array([1e-3, 0.1, 0.3, 0.5])
    stretch = 1 - eps
    np.testing.assert_allclose(gent_stress(eps, locking=1e12), (stretch**-2 - stretch) / 3, rtol=1e-9)
    assert gent_stress(1e-9, locking=1.0) == pytest.approx(1e-9, rel=1e-8)  # slope 1: E at small strain
    assert np.all(gent_stress(eps[1:], locking=2.0) > gent_stress(eps[1:], locking=1e12))
    assert gent_stress(0.9, locking=2.0) == np.inf and gent_stress(1.2, locking=1e12) == np.inf


def test_rubber_stiffening_is_stiffer_at_high_force_and_equal_at_low_force():
    extent = 0.03
    linear = np.geomspace(1e-9, 0.6 * extent, 30)  # Hookean displacements up to 60 % strain
    hookean = rubber_stiffen(linear, extent_m=extent, weight=0.0, locking=10.0)
    np.testing.assert_allclose(hookean, linear, rtol=1e-12)
    neo = rubber_stiffen(linear, extent_m=extent, weight=1.0, locking=1e6)
    gent = rubber_stiffen(linear, extent_m=extent, weight=1.0, locking=1.0)
    half = rubber_stiffen(linear, extent_m=extent, weight=0.5, locking=1.0)
    assert neo[0] == pytest.approx(linear[0], rel=1e-6) and gent[0] == pytest.approx(linear[0], rel=1e-6)
    assert neo[-1] < 0.75 * linear[-1] and gent[-1] < neo[-1] and gent[-1] < half[-1] < linear[-1]
    assert np.all(np.diff(gent) > 0)  # still a monotone response
    # Each is the inverse of its stress law: E * stress(eps) at its strain is the Hookean stress.
    eps = gent / extent
    np.testing.assert_allclose(gent_stress(eps, locking=1.0), linear / extent, rtol=1e-9)


def test_a_stiff_objects_solver_noise_keeps_its_sign_through_the_laws():
    """A steel object's displacement can come out a hair below zero: the laws are odd, never NaN."""
    mechanics = neutral(RUBBER, rubber_weight=0.8, gent_locking=2.0, densification_sharpness=0.7)
    noise = np.array([-4e-9, 0.0, 4e-9])
    response = mechanics.object_response(noise, extent_m=0.06, densification_strain=0.5)
    assert response[0] == -response[2] and response[1] == 0.0
    np.testing.assert_allclose(response, noise, rtol=1e-3)


# --------------------------------------------------------------------------- the load curve


@pytest.fixture(scope="module")
def rubber_scene(settings):
    shape, cell = contact_grid(settings.sensors[0], settings.simulation.grid_px)
    pose = Pose(rotation=np.eye(3), offset_m=(0.0, 0.0))
    scene = make_scene(RUBBER, pose, shape=shape, cell_m=cell, fingers=("left", "right"),
                       rng=np.random.default_rng(0), size=RUBBER.size_m)
    sensors = {s.finger: s for s in settings.sensors}

    def curve(mechanics=None):
        return load_curve(RUBBER, scene, sensors=sensors, grid_px=settings.simulation.grid_px, max_force_n=20.0,
                          finger_stiffness_n_per_m=1e5, size=RUBBER.size_m, mechanics=mechanics)

    return curve


def test_a_neutral_draw_is_the_simulators_own_load_curve(rubber_scene):
    plain, drawn = rubber_scene(), rubber_scene(neutral(RUBBER))
    for name in ("closure_m", "gel_m", "object_m", "object_linear_m", "bulk_linear_m"):
        np.testing.assert_allclose(getattr(drawn, name), getattr(plain, name), rtol=1e-12, err_msg=name)


@pytest.mark.slow
def test_each_drawn_quantity_moves_the_load_curve_its_way(rubber_scene):
    plain = rubber_scene()

    def top(curve, name):
        return float(getattr(curve, name)[-1])

    # The gel: sliding on its backing, or effectively thicker, it yields more; thinner, less.
    assert top(rubber_scene(neutral(RUBBER, base_slip=1.0)), "gel_m") > 1.5 * top(plain, "gel_m")
    assert top(rubber_scene(neutral(RUBBER, thickness_factor=1.5)), "gel_m") > 1.2 * top(plain, "gel_m")
    assert top(rubber_scene(neutral(RUBBER, thickness_factor=0.6)), "gel_m") < 0.8 * top(plain, "gel_m")
    # The object's contact (its linear displacement less the bulk): friction and a Poisson's ratio
    # nearer 0.5 stiffen it; the bulk term keeps the catalogue's modulus.
    contact = top(plain, "object_linear_m") - top(plain, "bulk_linear_m")
    rough = rubber_scene(neutral(RUBBER, friction_stiffening=0.05))
    assert top(rough, "object_linear_m") - top(rough, "bulk_linear_m") < 0.99 * contact
    assert top(rough, "bulk_linear_m") == top(plain, "bulk_linear_m")
    loose = rubber_scene(neutral(RUBBER, object_poisson=0.3))
    firm = rubber_scene(neutral(RUBBER, object_poisson=0.5))
    assert top(firm, "object_linear_m") < contact + top(plain, "bulk_linear_m") < top(loose, "object_linear_m")
    # Rubber-like stiffening: the same at the lightest touch, stiffer at the top of the ladder.
    rubbery = rubber_scene(neutral(RUBBER, rubber_weight=1.0, gent_locking=1.0))
    assert rubbery.object_m[1] == pytest.approx(plain.object_m[1], rel=0.01)
    assert rubbery.object_m[-1] < plain.object_m[-1] and rubbery.closure_m[-1] < plain.closure_m[-1]


def test_a_grasp_with_drawn_mechanics_keeps_its_rig_and_pose_and_refuses_the_half_space(settings):
    mechanics = draw_mechanics(mechanics_rng(SEED, RUBBER, 0))
    record, truth = simulate_grasp(RUBBER, settings=settings, rng=np.random.default_rng(7), seed=7,
                                   mechanics=mechanics)
    _, plain = simulate_grasp(RUBBER, settings=settings, rng=np.random.default_rng(7), seed=7)
    assert np.array_equal(truth.pose.rotation, plain.pose.rotation)
    assert truth.finger_stiffness_n_per_m == plain.finger_stiffness_n_per_m
    assert truth.size_m == pytest.approx(tuple(0.03 * mechanics.size_factors[0] for _ in range(3)))
    assert not np.array_equal(truth.curve.closure_m, plain.curve.closure_m)
    assert record.provenance.extra["mechanics"] == {**mechanics.provenance(), "size_m": list(truth.size_m)}
    half = dataclasses.replace(settings, simulation=dataclasses.replace(settings.simulation, gel_model="half-space"))
    with pytest.raises(SimulationError, match="held-out"):
        simulate_grasp(RUBBER, settings=half, rng=np.random.default_rng(7), mechanics=mechanics)


# --------------------------------------------------------------------------- teleop simulate --vary-contact


@pytest.mark.parametrize("extra", [[], ["--operator", "sim", "--randomize-rig", "--vary-gel"]],
                         ids=["scripted", "operator on a drawn rig"])
@pytest.mark.slow
def test_a_varied_record_is_valid_and_its_provenance_holds_the_drawn_mechanics(tmp_path, catalogue, extra, simulate_cli):
    (obj,) = load_catalogue(catalogue)
    path = simulate_cli(tmp_path / "varied", "--vary-contact", *extra, seed=SEED)
    plain = simulate_cli(tmp_path / "plain", *extra, seed=SEED)
    assert path.name == grasp_filename(obj, 0) and path.read_bytes() != plain.read_bytes()
    again = simulate_cli(tmp_path / "again", "--vary-contact", *extra, seed=SEED)
    assert again.read_bytes() == path.read_bytes()
    record, without = read_record(path), read_record(plain)
    drawn = record.provenance.extra["mechanics"]
    expected = draw_mechanics(mechanics_rng(SEED, obj, 0)).provenance()
    assert {k: v for k, v in drawn.items() if k != "size_m"} == expected
    assert drawn["size_m"] == pytest.approx([0.02 * expected["size_factors"][0]] * 3)
    # The estimator's inputs: the rig the lab knows (the same as without), frames, forces, widths.
    assert record.sensors == without.sensors and record.gripper == without.gripper and record.label == without.label
    assert record.provenance.style == without.provenance.style
    rigs = [{k: v for k, v in r.provenance.extra.get("rig", {}).items() if k != "grasp_target_force_n"}
            for r in (record, without)]  # an operator's peak force depends on the object's response
    assert rigs[0] == rigs[1]
    assert len(record.force_n) > 10 and np.isfinite(record.force_n.value).all() and all(len(s) > 4 for s in record.frames)
    assert read_record(write_record(record, tmp_path / "copy.grasp")).provenance == record.provenance


def test_without_the_option_the_records_are_the_plain_simulators(tmp_path, catalogue, quick_settings, simulate_cli):
    plain = simulate_cli(tmp_path / "plain", seed=SEED)
    (obj,) = load_catalogue(catalogue)
    record, _ = simulate_grasp(obj, settings=load_settings(quick_settings), rng=grasp_rng(SEED, obj, 0), seed=SEED)
    assert plain.read_bytes() == write_record(record, tmp_path / "direct.grasp").read_bytes()
    assert "mechanics" not in read_record(plain).provenance.extra


@pytest.mark.parametrize("how", ["option", "settings"])
def test_the_held_out_half_space_gel_is_refused(tmp_path, catalogue, quick_settings, capsys, how):
    argv = ["--gel-model", "half-space"]
    if how == "settings":
        path = tmp_path / "half.toml"
        path.write_text(quick_settings.read_text().replace("[simulation]", '[simulation]\ngel_model = "half-space"'))
        assert load_settings(path).simulation.gel_model == "half-space"
        quick_settings, argv = path, []
    code = main(["simulate", "--objects", str(catalogue), "--out", str(tmp_path / "o"), "--settings",
                 str(quick_settings), "--vary-contact", *argv])
    err = capsys.readouterr().err
    assert code == 2 and "--vary-contact" in err and "held-out 'half-space'" in err and "Traceback" not in err
    assert len(err.strip().splitlines()) == 1 and not (tmp_path / "o").exists()


def test_drawn_sizes_stay_graspable():
    """A ball near the top of the catalogue's size range, grown by the draw, is shrunk back to fit."""
    big = ObjectSpec(name="big ball", shape="sphere", material="plastic", modulus_pa=1e9, size_m=(0.074,) * 3)
    rng = np.random.default_rng(2)
    for _ in range(30):
        mechanics = draw_mechanics(rng)
        size = mechanics.object_size(big, big.size_m, max_width_m=0.08)
        assert len(set(size)) == 1 and size[0] <= 0.074 * 1.001  # at most what the catalogue's fitted
        if mechanics.size_factors[0] < 0.95:
            assert size[0] == pytest.approx(0.074 * mechanics.size_factors[0])
        # Where the gripper is no limit, the drawn factor is the size's.
        assert mechanics.object_size(big, big.size_m, max_width_m=1.0)[0] == pytest.approx(
            0.074 * mechanics.size_factors[0])


@pytest.mark.parametrize("factor", [0.75, 1.15])
def test_the_drawn_densification_factor_scales_the_objects_limit(factor):
    """A draw's densification factor moves where the object stops yielding: crushed far beyond its
    limit it moves (material strain) x factor x extent, not the material's own limit."""
    extent, strain = 0.03, 0.8
    crushed = np.array([20.0 * extent])
    moved = neutral(RUBBER, densification_factor=factor).object_response(crushed, extent_m=extent,
                                                                 densification_strain=strain)
    assert float(moved[0]) == pytest.approx(strain * factor * extent, rel=1e-6)
    small = np.array([1e-7])  # the small-force response is the linear one whatever the factor
    assert float(neutral(RUBBER, densification_factor=factor).object_response(
        small, extent_m=extent, densification_strain=strain)[0]) == pytest.approx(1e-7, rel=1e-4)


def test_the_log_uniform_fields_are_drawn_log_uniformly():
    """Gent's J_m spans two decades: half the draws lie below the geometric mean (10), not the
    arithmetic one (50.5); likewise the sharpness and the thickness factor (module notes' table)."""
    assert {"gent_locking", "densification_sharpness", "thickness_factor"} <= LOG_UNIFORM
    rng = np.random.default_rng(0)
    draws = [draw_mechanics(rng) for _ in range(2000)]
    for name in ("gent_locking", "densification_sharpness", "thickness_factor"):
        lo, hi = getattr(CONTACT_SPREAD, name)
        values = np.array([getattr(d, name) for d in draws])
        below = float(np.mean(values < math.sqrt(lo * hi)))
        assert below == pytest.approx(0.5, abs=0.05), name


def test_a_draw_takes_the_streams_values_in_the_documented_order():
    """draw_mechanics is pure and documented: the fields in order, then the three size factors (x, y, z)
    last; the same seed redraws the same mechanics in every version that keeps this contract."""
    drawn = draw_mechanics(np.random.default_rng(11))
    rng = np.random.default_rng(11)
    for field in dataclasses.fields(CONTACT_SPREAD):
        if field.name == "size_factor":
            continue
        lo, hi = getattr(CONTACT_SPREAD, field.name)
        expected = (math.exp(rng.uniform(math.log(lo), math.log(hi))) if field.name in LOG_UNIFORM
                    else rng.uniform(lo, hi))
        assert getattr(drawn, field.name) == expected, field.name
    assert drawn.size_factors == tuple(rng.uniform(*CONTACT_SPREAD.size_factor, size=3))


def test_the_provenance_keeps_every_drawn_value():
    """provenance.extra["mechanics"] is the analysis's only record of a draw: every field, as drawn."""
    mechanics = neutral(RUBBER, base_slip=0.3, friction_stiffening=0.02, gent_locking=7.0, size_factors=(0.9, 1.0, 1.1))
    kept = mechanics.provenance()
    names = {f.name for f in dataclasses.fields(ContactMechanics)}
    assert set(kept) == names
    for name in names - {"size_factors"}:
        assert kept[name] == getattr(mechanics, name), name
    assert kept["size_factors"] == [0.9, 1.0, 1.1]
