"""Simulated grasps (teleop.sim.grasp, teleop.sim.motion): force targets, load-curve ladders, contact-model
choice, record windows and the operator loop's limits."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

import teleop.sim.grasp as grasp_module
import teleop.sim.motion as motion_module
from teleop.catalogue import ObjectSpec
from teleop.errors import SimulationError
from teleop.settings import load_settings
from teleop.sim.contact import hertz_sphere
from teleop.sim.grasp import (
    FINGER_STIFFNESS_SD,
    LOAD_LEVELS,
    POST_ROLL_S,
    PRE_ROLL_READINGS,
    RECORD_FORCE_N,
    LoadCurve,
    contact_grid,
    load_curve,
    simulate_grasp,
)
from teleop.sim.motion import FOLLOW_LATENCY_S, operator_motion
from teleop.sim.operator import OperatorCommand
from teleop.sim.shapes import Pose, Scene, make_scene

STEEL = ObjectSpec(name="steel_ball", shape="sphere", material="metal", modulus_pa=2.0e11, size_m=(0.025,) * 3)
RUBBER = ObjectSpec(name="rubber_ball", shape="sphere", material="rubber", modulus_pa=5.0e5, size_m=(0.03,) * 3)


class _Stop(Exception):
    """Raised by an intercepted load_curve: the grasp's inputs are seen, no grasp is rendered."""


def _load_curve_inputs(monkeypatch, settings, keyword: str, seeds: int) -> list[float]:
    """The ``keyword`` argument that load_curve gets in scripted grasps of STEEL of seeds 0 to
    ``seeds`` - 1, intercepted before anything is rendered."""
    seen = []

    def capture(*args, **kwargs):
        seen.append(kwargs[keyword])
        raise _Stop

    monkeypatch.setattr(grasp_module, "load_curve", capture)
    for seed in range(seeds):
        with pytest.raises(_Stop):
            simulate_grasp(STEEL, settings=settings, rng=np.random.default_rng(seed))
    return seen


def test_a_scripted_grasps_drawn_force_target_never_exceeds_the_grippers(settings, monkeypatch):
    """Each scripted grasp squeezes to a drawn 40-100 % of gripper.target_force_n, never beyond the
    gripper's force limit. (The load curve's top is the target; it is intercepted so that no grasp is
    rendered.)"""
    seen = _load_curve_inputs(monkeypatch, settings, "max_force_n", 40)
    cap = settings.gripper.target_force_n
    fractions = np.array(seen) / cap
    assert fractions.max() <= 1.0 and fractions.min() >= 0.4
    assert fractions.max() > 0.85 and fractions.min() < 0.55  # the whole range is drawn


def test_a_commanded_force_is_the_force_the_grasp_squeezes_to(settings):
    """simulate_grasp(force_n=F): the true force peaks at F (not at a drawn share of the cap) and the
    rest of the grasp (pose, fingers) is the uncommanded one's."""
    record, truth = simulate_grasp(STEEL, settings=settings, rng=np.random.default_rng(7), seed=7, force_n=3.0)
    _, drawn = simulate_grasp(STEEL, settings=settings, rng=np.random.default_rng(7), seed=7)
    assert truth.target_force_n == 3.0 and drawn.target_force_n != pytest.approx(3.0, rel=0.01)
    assert truth.force_n.max() == pytest.approx(3.0, rel=1e-9)
    assert record.force_n.value.max() == pytest.approx(3.0, rel=0.06)  # load-cell noise and gain error
    assert np.array_equal(truth.pose.rotation, drawn.pose.rotation)
    assert truth.finger_stiffness_n_per_m == drawn.finger_stiffness_n_per_m
    assert record.provenance.seed == 7  # the record says how to reproduce it


def _rubber_scene(settings):
    shape, cell = contact_grid(settings.sensors[0], settings.simulation.grid_px)
    return make_scene(RUBBER, Pose(rotation=np.eye(3), offset_m=(0.0, 0.0)), shape=shape, cell_m=cell,
                      fingers=("left", "right"), rng=np.random.default_rng(0), size=RUBBER.size_m)


def test_the_load_curve_stays_invertible_through_solver_noise(settings, monkeypatch):
    """One level's contact coming out low (solver noise) must not fold the closure back: the motion
    inverts force(closure), so closure_m never decreases over the ladder."""
    scene = _rubber_scene(settings)
    sensors = {s.finger: s for s in settings.sensors}
    real = grasp_module.solve_contact
    calls = []

    def noisy(*args, **kwargs):
        solution = real(*args, **kwargs)
        calls.append(1)
        if len(calls) == 7:  # one level of the first finger comes out short
            solution = dataclasses.replace(solution, approach_m=0.3 * solution.approach_m)
        return solution

    monkeypatch.setattr(grasp_module, "solve_contact", noisy)
    curve = load_curve(RUBBER, scene, sensors=sensors, grid_px=settings.simulation.grid_px, max_force_n=20.0,
                       finger_stiffness_n_per_m=1e5, size=RUBBER.size_m)
    assert np.all(np.diff(curve.closure_m) >= 0)
    assert curve.force_at(np.array([curve.closure_m[-1]]))[0] == pytest.approx(20.0)


@pytest.mark.parametrize("top", [0.02, 0.3])
def test_a_light_force_target_gets_its_own_ladder(settings, top):
    """A grasp commanded to a light force (below ten times the 0.05 N floor) still gets an ascending
    ladder of LOAD_LEVELS levels a decade deep, ending at its target."""
    curve = load_curve(RUBBER, _rubber_scene(settings), sensors={s.finger: s for s in settings.sensors},
                       grid_px=settings.simulation.grid_px, max_force_n=top, finger_stiffness_n_per_m=1e5,
                       size=RUBBER.size_m)
    levels = curve.force_n[1:]
    assert len(levels) == LOAD_LEVELS and np.all(np.diff(curve.force_n) > 0)
    assert levels[-1] == pytest.approx(top) and levels[0] == pytest.approx(top / 10)
    assert np.all(np.diff(curve.closure_m) > 0)


def test_hertz_is_not_used_for_a_contact_at_the_pads_edge(settings):
    """Where Hertz would be exact in the pad's middle (thick gel, tiny force, a hard smooth ball), a
    contact one cell from the pad's edge is solved on the grid: the pad cuts it (provenance model)."""
    thick = {s.finger: dataclasses.replace(s, gel_thickness_m=0.02) for s in settings.sensors}
    ball = ObjectSpec(name="bearing", shape="sphere", material="metal", modulus_pa=2e11, size_m=(0.01,) * 3,
                      texture_m=1e-10)
    (rows, cols), cell = contact_grid(settings.sensors[0], settings.simulation.grid_px)
    models = {}
    for where, offset in {"middle": (0.0, 0.0), "edge": ((cols / 2 - 1.5) * cell[1], 0.0)}.items():
        scene = make_scene(ball, Pose(rotation=np.eye(3), offset_m=offset), shape=(rows, cols), cell_m=cell,
                           fingers=tuple(thick), rng=np.random.default_rng(0), size=ball.size_m)
        curve = load_curve(ball, scene, sensors=thick, grid_px=settings.simulation.grid_px, max_force_n=0.001,
                           finger_stiffness_n_per_m=1e5, size=ball.size_m)
        models[where] = curve.model
        if where == "edge":
            assert all(min(c, cols - 1 - c) <= 2 for _, c in scene.first_contact_rc.values())
    assert models == {"middle": "hertz", "edge": "bem-layer"}


def _ladder_curve():
    levels = np.geomspace(0.05, 5.0, 12)
    zero = np.concatenate([[0.0], levels])
    return LoadCurve(force_n=zero, closure_m=zero * 1e-4, gel_m=zero, object_m=zero, object_linear_m=zero,
                     bulk_linear_m=zero, finger_m=zero, fingers={}, model="bem-layer")


def test_frames_below_the_first_level_scale_as_hertz_and_above_the_top_hold_it():
    """The gel field of a frame below the ladder's first level is that level's scaled as F^(2/3) (a Hertzian
    depth); at or beyond the top it is the top level's, never extrapolated; between, linear in log F."""
    curve = _ladder_curve()
    first, top = curve.force_n[1], curve.force_n[-1]
    (level, weight), = curve.level_weights(0.25 * first)
    assert level == 0 and weight == pytest.approx(0.25 ** (2.0 / 3.0))
    assert curve.level_weights(2.0 * top) == [(11, 1.0)]
    assert curve.level_weights(0.0) == []
    middle = math.sqrt(curve.force_n[3] * curve.force_n[4])
    assert curve.level_weights(middle) == [(2, pytest.approx(0.5)), (3, pytest.approx(0.5))]


@pytest.mark.parametrize("seed", range(4))
def test_a_10_hz_load_cell_keeps_eight_readings_before_the_touch(settings, seed):
    """The HX711 at 10 Hz: the record keeps PRE_ROLL_READINGS (8) load-cell readings before the first
    one that reads the touch, not just PRE_ROLL_S (0.2 s, two readings): the estimator's baseline.
    The readings' stamps jitter, so this holds over several draws, not by luck on one."""
    slow = dataclasses.replace(settings, load_cell=dataclasses.replace(settings.load_cell, sample_rate_hz=10.0))
    record, truth = simulate_grasp(STEEL, settings=slow, rng=np.random.default_rng(seed), seed=seed)
    values = record.force_n.value
    touched = int(np.flatnonzero(values > min(RECORD_FORCE_N, 0.5 * truth.force_n.max()))[0])
    assert touched >= PRE_ROLL_READINGS
    assert record.force_n.t_s[touched] - record.force_n.t_s[0] >= 0.7


@pytest.mark.parametrize("obj", [STEEL, RUBBER], ids=lambda o: o.name)
def test_an_operator_cannot_squeeze_the_fingers_past_the_force_cap(settings, obj):
    """The gripper stalls on its force limit: however far the operator commands, the reported motor width
    never drops below the width at which the load curve reaches the cap."""
    _, truth = simulate_grasp(obj, settings=settings, rng=np.random.default_rng(7), seed=7, operator="sim")
    stall_width = truth.scene.extent_m - min(truth.curve.closure_m[-1], truth.scene.extent_m)
    assert truth.motor_width_m.min() >= stall_width - 1e-12
    assert truth.curve.force_n[-1] == settings.gripper.target_force_n
    assert truth.target_force_n == truth.force_n.max()  # an operator grasp's target: the peak it reached


def test_hertz_is_not_used_beyond_small_strain(settings):
    """A 2 mm bead pressed to 1 mN opens a contact wider than R / 10 (a ~ 0.14 mm): beyond Hertz's small-strain
    assumption, so the grid solves it even on a thick gel with a smooth bead in the pad's middle."""
    thick = {s.finger: dataclasses.replace(s, gel_thickness_m=0.02) for s in settings.sensors}
    bead = ObjectSpec(name="bead", shape="sphere", material="metal", modulus_pa=2e11, size_m=(0.002,) * 3,
                      texture_m=1e-10)
    sensor = settings.sensors[0]
    e_star = 1.0 / ((1 - sensor.gel_poisson**2) / sensor.gel_modulus_pa + (1 - 0.3**2) / 2e11)
    assert float(hertz_sphere(0.001, radius_m=0.001, e_star_pa=e_star)[0]) > 1e-4
    (rows, cols), cell = contact_grid(sensor, settings.simulation.grid_px)
    scene = make_scene(bead, Pose(rotation=np.eye(3), offset_m=(0.0, 0.0)), shape=(rows, cols), cell_m=cell,
                       fingers=tuple(thick), rng=np.random.default_rng(0), size=bead.size_m)
    curve = load_curve(bead, scene, sensors=thick, grid_px=settings.simulation.grid_px, max_force_n=0.001,
                       finger_stiffness_n_per_m=1e5, size=bead.size_m)
    assert curve.model == "bem-layer"


def test_hertz_is_not_used_where_the_balls_roughness_rivals_its_approach(settings):
    """The same bearing, thick gel and 1 mN that Hertz solves when smooth (texture 1e-10 m) is solved on the
    grid with a metal's typical roughness (2 um against a sub-micrometre approach)."""
    thick = {s.finger: dataclasses.replace(s, gel_thickness_m=0.02) for s in settings.sensors}
    (rows, cols), cell = contact_grid(settings.sensors[0], settings.simulation.grid_px)
    models = []
    for texture in (1e-10, 0.0):  # 0: the material's typical roughness
        ball = ObjectSpec(name="bearing", shape="sphere", material="metal", modulus_pa=2e11, size_m=(0.01,) * 3,
                          texture_m=texture)
        scene = make_scene(ball, Pose(rotation=np.eye(3), offset_m=(0.0, 0.0)), shape=(rows, cols), cell_m=cell,
                           fingers=tuple(thick), rng=np.random.default_rng(0), size=ball.size_m)
        models.append(load_curve(ball, scene, sensors=thick, grid_px=settings.simulation.grid_px,
                                 max_force_n=0.001, finger_stiffness_n_per_m=1e5, size=ball.size_m).model)
    assert models == ["hertz", "bem-layer"]


def test_the_true_finger_stiffness_is_drawn_near_the_setting(settings, monkeypatch):
    """Each grasp's true finger stiffness is the setting times a log-normal factor of sd 0.1
    (FINGER_STIFFNESS_SD): the rig's linear correction is off by some per cent, never by a factor."""
    seen = _load_curve_inputs(monkeypatch, settings, "finger_stiffness_n_per_m", 30)
    logs = np.log(np.array(seen) / settings.gripper.finger_stiffness_n_per_m)
    assert np.abs(logs).max() < 4 * FINGER_STIFFNESS_SD
    assert 0.5 * FINGER_STIFFNESS_SD < logs.std() < 1.5 * FINGER_STIFFNESS_SD


def test_the_record_runs_past_the_release_by_the_post_roll(settings):
    """The host keeps POST_ROLL_S (0.1 s) of readings after its load cell first reads the release."""
    record, truth = simulate_grasp(STEEL, settings=settings, rng=np.random.default_rng(7), seed=7)
    t, value = record.force_n.t_s, record.force_n.value
    threshold = min(RECORD_FORCE_N, 0.5 * truth.force_n.max())
    released = t[np.flatnonzero((t > truth.release_s) & (value <= threshold))[0]]
    assert t[-1] - released >= POST_ROLL_S - 2.0 / settings.load_cell.sample_rate_hz


def test_an_operator_that_never_finishes_is_a_named_simulation_error(settings, monkeypatch):
    """An operator grasp still going after MAX_OPERATOR_S is refused as a SimulationError naming the
    operator's style (teleop simulate reports it per grasp), not a crash further down."""
    monkeypatch.setattr(motion_module, "MAX_OPERATOR_S", 0.3)  # far shorter than any operator's grasp
    with pytest.raises(SimulationError, match="had not finished its grasp after 0.3 s"):
        simulate_grasp(STEEL, settings=settings, rng=np.random.default_rng(7), seed=7, operator="sim")


class _StubOperator:
    """Commands the fingers to 1 cm from the first step on, lets go after 0.2 s."""

    def __init__(self):
        self.done = False

    def step(self, t_s, *, force_n, width_m):
        release = t_s >= 0.2
        self.done = t_s >= 0.3
        return OperatorCommand(target_width_m=0.01, enable=not release, release=release)


def _stub_operator_motion(gripper, seed):
    """The motion of fingers driven by _StubOperator onto a 5 mm object that yields 1 mm per newton."""
    zero = np.array([0.0, 1.0])
    curve = LoadCurve(force_n=zero, closure_m=zero * 1e-3, gel_m=zero, object_m=zero, object_linear_m=zero,
                      bulk_linear_m=zero, finger_m=zero, fingers={}, model="bem-layer")
    scene = Scene(gap_m={}, extent_m=0.005, cross_section_m2=1e-4, first_contact_rc={})
    return operator_motion(curve, scene, gripper, _StubOperator(), np.random.default_rng(seed))


@pytest.mark.parametrize("seed", range(6))
def test_operator_commands_reach_the_fingers_after_the_bus_latency(seed):
    """The first command (sent at t = 0) moves the fingers only FOLLOW_LATENCY_S (5-30 ms) later."""
    gripper = load_settings().gripper
    motion = _stub_operator_motion(gripper, seed)
    moved = motion.t_s[np.flatnonzero(motion.motor_width_m < gripper.max_width_m)[0]]
    assert FOLLOW_LATENCY_S[0] - 1e-3 <= moved <= FOLLOW_LATENCY_S[1] + 2e-3


def test_after_an_operators_release_the_fingers_open_at_the_closing_speed():
    """Once the operator lets go the fingers open as after a scripted grasp: at gripper.closing_speed_m_s
    (not at the leader-follower speed) up to fully open."""
    gripper = load_settings().gripper
    motion = _stub_operator_motion(gripper, 0)
    after = motion.t_s > motion.release_s
    speed = np.diff(motion.motor_width_m[after]) / np.diff(motion.t_s[after])
    assert speed.max() == pytest.approx(gripper.closing_speed_m_s, rel=1e-6)
    assert motion.motor_width_m[-1] == gripper.max_width_m
