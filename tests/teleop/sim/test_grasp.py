"""Simulated grasps (teleop.sim.grasp): physics departures from Hertz, limits, determinism, records."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from teleop.catalogue import ObjectSpec
from teleop.errors import SimulationError
from teleop.operator import FOLLOW_SPEED_M_S
from teleop.record import GRASP_DONE_EVENT, read_record, write_record
from teleop.settings import load_settings
from teleop.sim.contact import hertz_sphere
from teleop.sim.grasp import simulate_grasp

STEEL = ObjectSpec(name="steel_ball", shape="sphere", material="metal", modulus_pa=2.0e11, size_m=(0.025,) * 3)
FOAM = ObjectSpec(name="foam_block", shape="box", material="foam", modulus_pa=5.0e3, size_m=(0.04, 0.05, 0.03))
RUBBER = ObjectSpec(name="rubber_ball", shape="sphere", material="rubber", modulus_pa=5.0e5, size_m=(0.03,) * 3)


@pytest.fixture(scope="module")
def grasps(settings):
    return {obj.name: simulate_grasp(obj, settings=settings, rng=np.random.default_rng(7), seed=7)
            for obj in (STEEL, FOAM, RUBBER)}


def hold(record, truth):
    """Mask of the width readings stamped well inside the hold."""
    t = record.width_m.t_s
    return (t > truth.stall_s + 0.15) & (t < truth.release_s)


@pytest.mark.parametrize("name", [STEEL.name, FOAM.name])
def test_stiff_and_very_soft_objects_simulate_finitely_and_respect_the_force_target(grasps, name):
    record, truth = grasps[name]
    for samples in (record.force_n, record.width_m):
        assert len(samples) > 5 and np.isfinite(samples.t_s).all() and np.isfinite(samples.value).all()
    assert truth.force_n.max() == pytest.approx(truth.target_force_n, rel=1e-9)
    assert record.force_n.value.max() == pytest.approx(truth.target_force_n, rel=0.06)  # noise, gain error
    assert (record.width_m.value > 0).all() and (record.width_m.value < 0.08 + 1e-3).all()
    for stream in record.frames:
        assert len(stream) > 4 and stream.frame(len(stream) // 2).shape == (480, 640, 3)
    for array in (truth.curve.closure_m, truth.curve.gel_m, truth.curve.object_m, *truth.peak_gel_m.values()):
        assert np.isfinite(array).all()
    assert record.provenance.model == "bem-layer"


def test_soft_objects_close_far_and_stiff_ones_barely(grasps):
    steel, foam = grasps[STEEL.name][1].curve, grasps[FOAM.name][1].curve
    assert foam.closure_m[-1] > 5 * steel.closure_m[-1]
    # The stiff object's share of the approach vanishes; the gel takes it (the central hard case).
    assert steel.object_m[-1] < 1e-3 * steel.gel_m[-1]
    assert foam.object_m[-1] > 10 * foam.gel_m[-1]


def test_layer_stiffening_the_gel_layer_makes_contacts_stiffer_than_half_space_hertz(grasps):
    curve = grasps[RUBBER.name][1].curve
    sensor = load_settings().sensor("left")
    k_gel = sensor.gel_compliance_per_pa
    k_obj = (1 - RUBBER.poisson**2) / RUBBER.modulus_pa
    for mechanics in curve.fingers.values():
        approach = mechanics.gel_m + mechanics.object_m
        _, hertz, _ = hertz_sphere(curve.force_n[1:], radius_m=0.015, e_star_pa=1 / (k_gel + k_obj))
        ratio = approach / hertz
        assert (ratio < 1).all()
        assert ratio[-1] < ratio[0] - 0.1  # the wider the contact against the 3 mm gel, the stiffer
        # The gel's own share is below the half-space share d/delta = k_gel / (k_gel + k_obj).
        assert mechanics.gel_m[-1] / approach[-1] < k_gel / (k_gel + k_obj)


def test_bulk_compression_is_large_for_foam_and_negligible_for_steel(grasps):
    foam, steel = grasps[FOAM.name][1].curve, grasps[STEEL.name][1].curve
    assert foam.bulk_linear_m[-1] > 0.1 * foam.object_linear_m[-1]
    assert steel.bulk_linear_m[-1] < 1e-6
    # A finite body stiffens as it is squeezed: foam densifies instead of passing through itself.
    assert foam.object_m[-1] < foam.object_linear_m[-1]
    extent = grasps[FOAM.name][1].scene.extent_m
    assert foam.closure_m[-1] < extent


def test_finger_compliance_the_gripper_reports_the_motor_width(grasps, settings):
    record, truth = grasps[RUBBER.name]
    assert truth.finger_stiffness_n_per_m != settings.gripper.finger_stiffness_n_per_m
    during = hold(record, truth)
    assert during.sum() >= 2
    tips = np.interp(record.width_m.t_s[during], truth.t_s, truth.tip_width_m)
    opening = np.median(tips - record.width_m.value[during])
    assert opening == pytest.approx(truth.target_force_n / truth.finger_stiffness_n_per_m, abs=40e-6)


def test_sensor_noise_is_in_every_stream(grasps, settings):
    record, truth = grasps[RUBBER.name]
    before = record.force_n.t_s < truth.touch_s
    assert np.std(record.force_n.value[before]) == pytest.approx(settings.simulation.force_noise_n, rel=0.5)
    stream = record.stream("left")
    during = np.flatnonzero((stream.t_s > truth.stall_s + 0.05) & (stream.t_s < truth.release_s))
    first, second = stream.frame(during[0]).astype(float), stream.frame(during[-1]).astype(float)
    assert stream.encoded[during[0]] != stream.encoded[during[-1]]  # same gel, new camera noise
    assert 0.3 * settings.simulation.camera_noise < np.std(first - second) < 3 * settings.simulation.camera_noise


def test_frames_show_the_gel_change_only_in_contact(grasps):
    record, truth = grasps[RUBBER.name]
    stream = record.stream("left")
    before = stream.frames([0, 1]).astype(float)
    peak = stream.frame(int(np.argmin(np.abs(stream.t_s - 0.5 * (truth.stall_s + truth.release_s))))).astype(float)
    assert np.abs(before[0] - before[1]).mean() < np.abs(peak - before[0]).mean()


def test_record_round_trip(grasps, tmp_path):
    record, truth = grasps[RUBBER.name]
    back = read_record(write_record(record, tmp_path / "g.grasp"))
    for a, b in ((record.force_n, back.force_n), (record.width_m, back.width_m)):
        np.testing.assert_array_equal(a.t_s, b.t_s)
        np.testing.assert_array_equal(a.value, b.value)
    for a, b in zip(record.frames, back.frames, strict=True):
        assert a.encoded == b.encoded and a.encoding == b.encoding == "jpeg" and b.shape == (480, 640, 3)
        np.testing.assert_array_equal(a.t_s, b.t_s)
    assert back.label.object_name == RUBBER.name and back.label.modulus_pa == RUBBER.modulus_pa
    assert (back.label.material, back.label.shape) == ("rubber", "sphere")
    assert back.provenance.source == "simulated" and back.provenance.seed == 7
    assert back.provenance.model == "bem-layer" and not back.provenance.extra
    assert set(back.events) == {"command_grasp", "grasp_done", "command_release"}
    assert back.events["command_release"] == pytest.approx(truth.release_s)
    assert back.events["grasp_done"] == pytest.approx(truth.stall_s)
    assert back.sensors == record.sensors


def test_same_rng_state_gives_the_same_grasp(grasps, settings):
    again, _ = simulate_grasp(STEEL, settings=settings, rng=np.random.default_rng(7), seed=7)
    record = grasps[STEEL.name][0]
    assert [s.encoded for s in again.frames] == [s.encoded for s in record.frames]
    np.testing.assert_array_equal(again.force_n.value, record.force_n.value)
    np.testing.assert_array_equal(again.width_m.t_s, record.width_m.t_s)
    other, _ = simulate_grasp(STEEL, settings=settings, rng=np.random.default_rng(8), seed=8)
    assert not np.array_equal(other.force_n.value[:20], record.force_n.value[:20])


def test_hertz_only_where_it_is_exact(settings):
    """A thick gel and a tiny force: the contact is far smaller than the layer, so Hertz is used."""
    thick = tuple(dataclasses.replace(s, gel_thickness_m=0.02) for s in settings.sensors)
    quiet = dataclasses.replace(
        settings, sensors=thick, gripper=dataclasses.replace(settings.gripper, target_force_n=0.001),
        simulation=dataclasses.replace(settings.simulation, force_noise_n=0.0),
    )
    ball = ObjectSpec(name="bearing", shape="sphere", material="metal", modulus_pa=2e11, size_m=(0.01,) * 3,
                      texture_m=1e-10)
    record, truth = simulate_grasp(ball, settings=quiet, rng=np.random.default_rng(0), seed=0)
    assert record.provenance.model == "hertz"
    assert np.isfinite(record.force_n.value).all() and truth.curve.closure_m[-1] > 0
    with pytest.raises(SimulationError, match="two sensors"):
        simulate_grasp(ball, settings=dataclasses.replace(settings, sensors=settings.sensors[:1]),
                       rng=np.random.default_rng(0))


def test_a_half_space_gel_is_another_contact_model_softer_than_the_bonded_layer(settings, grasps):
    """``gel_model = "half-space"``: the same grasp on an unbounded gel, which the 3 mm bonded layer
    stiffens; a contact model for testing an estimator beyond the one it was trained on."""
    half = dataclasses.replace(settings, simulation=dataclasses.replace(settings.simulation, gel_model="half-space"))
    record, truth = simulate_grasp(FOAM, settings=half, rng=np.random.default_rng(7), seed=7)
    layered = grasps[FOAM.name][1].curve
    assert record.provenance.model == "bem-half-space"
    assert truth.target_force_n == grasps[FOAM.name][1].target_force_n  # the same draws
    for finger, mechanics in truth.curve.fingers.items():
        # The same force sinks an unbounded gel deeper than one bonded to a rigid backing 3 mm down.
        assert mechanics.gel_m[-1] > 1.2 * layered.fingers[finger].gel_m[-1]


# --------------------------------------------------------------------------- operator-driven grasps


@pytest.fixture(scope="module")
def operated(settings):
    return {obj.name: simulate_grasp(obj, settings=settings, rng=np.random.default_rng(7), seed=7, operator="sim")
            for obj in (STEEL, FOAM)}


@pytest.mark.parametrize("name", [STEEL.name, FOAM.name])
def test_an_operator_drives_the_fingers_force_capped_and_releases(operated, settings, name):
    record, truth = operated[name]
    assert record.provenance.style == "operator" and truth.operator is not None
    assert "description" in record.provenance.extra["operator"]
    assert GRASP_DONE_EVENT not in record.events and "command_release" in record.events
    assert truth.force_n.max() <= settings.gripper.target_force_n + 1e-9  # the gripper's force limit
    assert truth.force_n.max() > 1.0 and truth.force_n[-1] == 0.0  # it squeezed, then let go
    # The fingers follow no faster than they can, and stay between closed and open.
    speed = np.abs(np.diff(truth.motor_width_m)) / np.diff(truth.t_s)
    assert speed.max() <= max(FOLLOW_SPEED_M_S, settings.gripper.closing_speed_m_s) + 1e-6
    assert (truth.motor_width_m >= 0).all() and (truth.motor_width_m <= settings.gripper.max_width_m + 1e-12).all()
    assert truth.touch_s < truth.stall_s < truth.release_s
    assert record.force_n.t_s[0] < truth.stall_s and record.force_n.t_s[-1] > truth.release_s
    assert len(record.frames[0]) > 4


def test_an_operator_grasp_places_the_object_as_the_scripted_one_and_repeats(operated, grasps, settings):
    record, truth = operated[STEEL.name]
    _, scripted = grasps[STEEL.name]
    assert np.array_equal(truth.pose.rotation, scripted.pose.rotation)
    assert truth.finger_stiffness_n_per_m == scripted.finger_stiffness_n_per_m
    again, truth_again = simulate_grasp(STEEL, settings=settings, rng=np.random.default_rng(7), seed=7, operator="sim")
    assert truth_again.operator.style == truth.operator.style
    assert np.array_equal(again.force_n.value, record.force_n.value)


def test_an_operator_grasp_round_trips_with_its_style(operated, tmp_path):
    record, _ = operated[FOAM.name]
    back = read_record(write_record(record, tmp_path / "op.grasp"))
    assert back.provenance == record.provenance and back.events == record.events


def test_an_unknown_operator_is_refused(settings):
    with pytest.raises(SimulationError, match="operator 'person'"):
        simulate_grasp(STEEL, settings=settings, rng=np.random.default_rng(0), operator="person")


@pytest.mark.parametrize(("kwargs", "message"), [
    ({"obj": "steel_ball"}, r"obj: expected an ObjectSpec .*got str"),
    ({"settings": None}, r"settings: expected Settings .*got NoneType"),
    ({"rng": 0}, r"rng: expected a numpy Generator .*got 0"),
    ({"force_n": -1.0}, r"force_n = -1\.0: expected None or a finite number > 0 \(N\)"),
    ({"force_n": 0.0}, r"force_n = 0\.0: expected"),
    ({"force_n": float("nan")}, r"force_n = nan: expected"),
    ({"force_n": True}, r"force_n = True: expected"),
    ({"force_n": "5"}, r"force_n = '5': expected"),
])
def test_simulate_grasp_refuses_misused_arguments(settings, kwargs, message):
    arguments = {"obj": STEEL, "settings": settings, "rng": np.random.default_rng(0)} | kwargs
    obj = arguments.pop("obj")
    with pytest.raises(SimulationError, match=message):
        simulate_grasp(obj, **arguments)
