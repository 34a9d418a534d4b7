"""Randomized rigs (teleop.sim.rig, ``teleop simulate --randomize-rig``): draws, ranges, what records carry."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from teleop.catalogue import ObjectSpec, load_catalogue
from teleop.record import read_record, write_record
from teleop.settings import load_settings
from teleop.sim.grasp import simulate_grasp
from teleop.sim.rig import LOG_UNIFORM, RIG_SPREAD, RigSpread, draw
from teleop.sim.simulate import grasp_filename, grasp_rng

SEED = 3
BALL = ObjectSpec(name="small rubber ball", shape="sphere", material="rubber", modulus_pa=8.0e5, size_m=(0.02,) * 3)


@pytest.fixture(scope="module")
def settings():
    return load_settings()


def test_a_seed_gives_the_same_rig_and_each_grasp_its_own(settings):
    obj = BALL
    first = draw(settings, grasp_rng(SEED, obj, 0))
    assert draw(settings, grasp_rng(SEED, obj, 0)) == first
    others = [draw(settings, grasp_rng(SEED, obj, i)) for i in (1, 2)] + [draw(settings, grasp_rng(SEED + 1, obj, 0))]
    for other in others:
        assert other != first
        assert other.known.gripper.finger_stiffness_n_per_m != first.known.gripper.finger_stiffness_n_per_m
        assert other.true.sensors[0].gel_modulus_pa != first.true.sensors[0].gel_modulus_pa
    # Pure: the settings drawn around are left as they were.
    assert settings == load_settings()


def test_every_drawn_value_is_inside_its_documented_range(settings):
    rng = np.random.default_rng(0)
    rigs = [draw(settings, rng) for _ in range(300)]
    spread = RIG_SPREAD

    def inside(values, bounds, name):
        values = np.asarray(values)
        assert values.min() >= bounds[0] and values.max() <= bounds[1], name
        # The draws cover the range: both ends' quarters are reached (log quarters for log-uniform ones).
        scale = np.log if name in LOG_UNIFORM else (lambda x: x)
        lo, hi = scale(bounds[0]), scale(bounds[1])
        assert scale(values.min()) < lo + 0.25 * (hi - lo) and scale(values.max()) > hi - 0.25 * (hi - lo), name

    gripper = [r.known.gripper for r in rigs]
    sim = [r.known.simulation for r in rigs]
    for name in ("finger_stiffness_n_per_m", "target_force_n", "closing_speed_m_s", "width_read_hz"):
        inside([getattr(g, name) for g in gripper], getattr(spread, name), name)
    for name in ("force_noise_n", "width_noise_m", "width_latency_s", "camera_noise", "camera_offset_s"):
        inside([getattr(s, name) for s in sim], getattr(spread, name), name)
    inside([r.true.simulation.illumination_gain for r in rigs], spread.illumination_gain, "illumination_gain")
    inside([s.camera_hz for r in rigs for s in r.known.sensors], spread.camera_hz, "camera_hz")
    assert all(len({s.camera_hz for s in r.known.sensors}) == 1 for r in rigs)  # both cameras alike
    assert {r.known.load_cell.sample_rate_hz for r in rigs} == {10.0, 80.0}
    for nominal_index, nominal in enumerate(settings.sensors):
        modulus = [r.true.sensors[nominal_index].gel_modulus_pa / nominal.gel_modulus_pa - 1 for r in rigs]
        thickness = [r.true.sensors[nominal_index].gel_thickness_m / nominal.gel_thickness_m - 1 for r in rigs]
        inside(modulus, (-spread.gel_modulus_tolerance, spread.gel_modulus_tolerance), "gel_modulus")
        inside(thickness, (-spread.gel_thickness_tolerance, spread.gel_thickness_tolerance), "gel_thickness")
    # The lab knows its gels only to the catalogue; true and known differ in the gels alone.
    for r in rigs:
        assert [(s.gel_modulus_pa, s.gel_thickness_m) for s in r.known.sensors] == [
            (s.gel_modulus_pa, s.gel_thickness_m) for s in settings.sensors]
        assert dataclasses.replace(r.true, sensors=r.known.sensors) == r.known
        assert r.true.gripper == r.known.gripper  # the finger's calibration error is the grasp simulator's


def test_varying_the_gel_draws_another_sensors_datasheet_and_leaves_the_rest(settings):
    rigs = [draw(settings, grasp_rng(SEED, BALL, i), vary_gel=True) for i in range(200)]
    moduli = [r.known.sensors[0].gel_modulus_pa for r in rigs]
    thicknesses = [r.known.sensors[0].gel_thickness_m for r in rigs]
    assert RIG_SPREAD.gel_modulus_pa[0] <= min(moduli) < 1.6e5 and 3.0e5 < max(moduli) <= RIG_SPREAD.gel_modulus_pa[1]
    assert RIG_SPREAD.gel_thickness_m[0] <= min(thicknesses) < 3e-3 < 4e-3 < max(thicknesses)
    for i, rig in enumerate(rigs[:20]):
        assert len({(s.gel_modulus_pa, s.gel_thickness_m) for s in rig.known.sensors}) == 1  # one gel per rig
        for known, true in zip(rig.known.sensors, rig.true.sensors, strict=True):  # tolerances around it
            assert abs(true.gel_modulus_pa / known.gel_modulus_pa - 1) <= RIG_SPREAD.gel_modulus_tolerance
        # The rest of the rig is the one drawn without the option.
        plain = draw(settings, grasp_rng(SEED, BALL, i))
        assert rig.known.gripper == plain.known.gripper and rig.known.simulation == plain.known.simulation
        assert [s.camera_hz for s in rig.known.sensors] == [s.camera_hz for s in plain.known.sensors]


def test_a_narrower_spread_is_honoured(settings):
    spread = RigSpread(finger_stiffness_n_per_m=(5e4, 5e4), camera_hz=(40.0, 40.0), load_cell_hz=(80.0,),
                       gel_modulus_tolerance=0.0)
    rig = draw(settings, np.random.default_rng(1), spread)
    assert rig.known.gripper.finger_stiffness_n_per_m == pytest.approx(5e4)
    assert all(s.camera_hz == 40.0 for s in rig.true.sensors) and rig.known.load_cell.sample_rate_hz == 80.0
    assert [s.gel_modulus_pa for s in rig.true.sensors] == [s.gel_modulus_pa for s in settings.sensors]


@pytest.mark.slow
def test_without_the_option_the_records_are_those_of_the_settings_rig(tmp_path, catalogue, quick_settings, simulate_cli):
    plain = simulate_cli(tmp_path / "plain", seed=SEED)
    (obj,) = load_catalogue(catalogue)
    assert plain.name == grasp_filename(obj, 0)
    record, _ = simulate_grasp(obj, settings=load_settings(quick_settings), rng=grasp_rng(SEED, obj, 0), seed=SEED)
    expected = write_record(record, tmp_path / "direct.grasp")
    assert plain.read_bytes() == expected.read_bytes()
    back = read_record(plain)
    assert back.gripper == load_settings(quick_settings).gripper and "rig" not in back.provenance.extra

    randomized = simulate_cli(tmp_path / "rig", "--randomize-rig", seed=SEED)
    assert randomized.read_bytes() != plain.read_bytes()
    again = simulate_cli(tmp_path / "again", "--randomize-rig", seed=SEED)
    assert again.read_bytes() == randomized.read_bytes()


def test_a_randomized_record_carries_the_known_rig_and_its_provenance_the_true_one(tmp_path, catalogue, quick_settings, simulate_cli):
    path = simulate_cli(tmp_path / "rig", "--randomize-rig", seed=SEED)
    (obj,) = load_catalogue(catalogue)
    settings = load_settings(quick_settings)
    rig = draw(settings, grasp_rng(SEED, obj, 0))
    record = read_record(path)
    assert record.sensors == rig.known.sensors and record.gripper == rig.known.gripper
    assert [s.gel_modulus_pa for s in record.sensors] == [s.gel_modulus_pa for s in settings.sensors]
    assert record.gripper != settings.gripper
    # The frames come at the rig's rate, not the settings' 10 Hz.
    stream = record.stream("left")
    assert np.median(np.diff(stream.t_s)) == pytest.approx(1.0 / record.sensor("left").camera_hz, rel=0.05)

    truth = record.provenance.extra["rig"]
    assert truth["gel_modulus_pa"] == {s.finger: s.gel_modulus_pa for s in rig.true.sensors}
    assert truth["gel_thickness_m"] == {s.finger: s.gel_thickness_m for s in rig.true.sensors}
    assert truth["gel_modulus_pa"]["left"] != record.sensor("left").gel_modulus_pa
    assert truth["finger_stiffness_n_per_m"] == rig.known.gripper.finger_stiffness_n_per_m
    # The grasp's own true stiffness: the configured one times the calibration error (log-normal, 10 % s.d.).
    ratio = truth["grasp_finger_stiffness_n_per_m"] / truth["finger_stiffness_n_per_m"]
    assert ratio != 1.0 and abs(math.log(ratio)) < 0.5
    assert 0.4 * rig.known.gripper.target_force_n <= truth["grasp_target_force_n"] <= rig.known.gripper.target_force_n
    assert {k: v for k, v in truth.items() if not k.startswith("grasp_")} == rig.provenance()
    assert 0.7 <= truth["illumination_gain"] <= 1.3
    # Simulated with the true rig: the force samples come at the drawn load cell's rate.
    period = np.median(np.diff(record.force_n.t_s))
    assert period == pytest.approx(1.0 / truth["load_cell_hz"], rel=0.1)
