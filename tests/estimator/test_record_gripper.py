"""The estimator takes the rig's gripper from the record when it carries one, else from its settings;
it never reads the true rig a simulated record keeps in its provenance."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import estimator.measure as measure
from estimator.measure import estimate_grasp, measure_grasp
from teleop.catalogue import ObjectSpec
from teleop.record import read_record, write_record
from teleop.settings import load_settings
from teleop.sim.grasp import simulate_grasp
from teleop.sim.rig import draw

RUBBER = ObjectSpec(name="rubber_ball", shape="sphere", material="rubber", modulus_pa=5.0e5, size_m=(0.03,) * 3)
SOFT_FINGERS_N_PER_M = 5.0e4
SETTINGS_FINGERS_N_PER_M = 2.0e5


def with_fingers(settings, stiffness):
    return dataclasses.replace(settings, gripper=dataclasses.replace(settings.gripper,
                                                                     finger_stiffness_n_per_m=stiffness))


@pytest.fixture(scope="module")
def settings():
    """Shipped settings with 10 Hz cameras (quick to simulate) and the fingers the estimator is told of."""
    shipped = load_settings()
    quick = dataclasses.replace(shipped, sensors=tuple(dataclasses.replace(s, camera_hz=10.0)
                                                       for s in shipped.sensors))
    return with_fingers(quick, SETTINGS_FINGERS_N_PER_M)


@pytest.fixture(scope="module")
def soft_grasp(settings, tmp_path_factory):
    """A grasp on a rig with 50 kN/m fingers, its record carrying that rig's gripper (written and read),
    and the same record stating no gripper (an older record, or an import)."""
    rig = with_fingers(settings, SOFT_FINGERS_N_PER_M)
    record, _ = simulate_grasp(RUBBER, settings=rig, rng=np.random.default_rng(4), seed=4)
    path = write_record(record, tmp_path_factory.mktemp("g") / "r.grasp")
    return read_record(path), dataclasses.replace(record, gripper=None)


def no_tactile(record, settings):
    return estimate_grasp(record, "no_tactile", settings=settings, correct_width_lag=True)


def test_the_finger_stiffness_comes_from_the_record(soft_grasp, settings):
    carried, bare = soft_grasp
    assert carried.gripper.finger_stiffness_n_per_m == SOFT_FINGERS_N_PER_M
    m = measure_grasp(carried, settings=settings, tactile=False, correct_width_lag=True)
    assert m.finger_stiffness_n_per_m == SOFT_FINGERS_N_PER_M
    told_right = measure_grasp(bare, settings=with_fingers(settings, SOFT_FINGERS_N_PER_M), tactile=False,
                               correct_width_lag=True)
    told_wrong = measure_grasp(bare, settings=settings, tactile=False, correct_width_lag=True)
    assert np.array_equal(m.approach_m, told_right.approach_m)
    # Softer fingers bend more under the same force, so less of the closure is the object's.
    loaded = m.force_n > 1.0
    assert loaded.any() and np.all(m.approach_m[loaded] < told_wrong.approach_m[loaded])

    estimate = no_tactile(carried, settings)
    assert estimate.state == "ok"
    assert estimate.e_pa == no_tactile(bare, with_fingers(settings, SOFT_FINGERS_N_PER_M)).e_pa
    wrong = no_tactile(bare, settings)
    # Told the fingers are stiffer than they are, the estimator puts their bending on the object: softer, and
    # further from the label.
    assert wrong.e_pa < estimate.e_pa
    assert abs(np.log10(estimate.e_pa / RUBBER.modulus_pa)) < abs(np.log10(wrong.e_pa / RUBBER.modulus_pa))


def test_the_closing_speed_for_the_width_lag_comes_from_the_record(soft_grasp, settings, monkeypatch):
    carried, bare = soft_grasp
    speeds = []
    original = measure.estimate_width_lag

    def spy(*args, speed_m_s, **kwargs):
        speeds.append(speed_m_s)
        return original(*args, speed_m_s=speed_m_s, **kwargs)

    monkeypatch.setattr(measure, "estimate_width_lag", spy)
    fast = dataclasses.replace(carried.gripper, closing_speed_m_s=0.07)
    measure_grasp(dataclasses.replace(carried, gripper=fast), settings=settings, tactile=False, correct_width_lag=True)
    measure_grasp(bare, settings=settings, tactile=False, correct_width_lag=True)
    assert speeds == [0.07, settings.gripper.closing_speed_m_s]


def test_records_without_a_gripper_or_with_the_settings_one_measure_as_before(soft_grasp, settings):
    _, bare = soft_grasp
    assert bare.gripper is None
    same = dataclasses.replace(bare, gripper=settings.gripper)
    for lag in (False, True):
        a = measure_grasp(bare, settings=settings, tactile=False, correct_width_lag=lag)
        b = measure_grasp(same, settings=settings, tactile=False, correct_width_lag=lag)
        assert a.finger_stiffness_n_per_m == b.finger_stiffness_n_per_m == SETTINGS_FINGERS_N_PER_M
        assert a.width_lag_s == b.width_lag_s
        assert np.array_equal(a.approach_m, b.approach_m) and np.array_equal(a.hold_approach_m, b.hold_approach_m)
    assert no_tactile(bare, settings).e_pa == no_tactile(same, settings).e_pa


def test_the_true_rig_in_the_provenance_is_not_read(settings):
    rig = draw(settings, np.random.default_rng(11))
    record, truth = simulate_grasp(RUBBER, settings=rig.true, rng=np.random.default_rng(12), seed=12)
    record = rig.record(record, finger_stiffness_n_per_m=truth.finger_stiffness_n_per_m,
                        target_force_n=truth.target_force_n)
    assert record.provenance.extra["rig"]["gel_modulus_pa"]["left"] != record.sensor("left").gel_modulus_pa
    nonsense = {key: 1.0 for key in record.provenance.extra["rig"]}
    altered = dataclasses.replace(record, provenance=dataclasses.replace(record.provenance, extra={"rig": nonsense}))
    stripped = dataclasses.replace(record, provenance=dataclasses.replace(record.provenance, extra={}))
    measured = [measure_grasp(r, settings=settings, tactile=False, correct_width_lag=True)
                for r in (record, altered, stripped)]
    for m in measured:
        assert m.sensor.gel_modulus_pa == settings.sensor("left").gel_modulus_pa  # the catalogue gel, not the true one
        assert m.finger_stiffness_n_per_m == rig.known.gripper.finger_stiffness_n_per_m
        assert np.array_equal(m.approach_m, measured[0].approach_m)
    estimates = {no_tactile(r, settings).e_pa for r in (record, altered, stripped)}
    assert len(estimates) == 1


def test_a_simulated_record_carries_the_gripper_it_was_simulated_with(soft_grasp):
    carried, _ = soft_grasp
    assert carried.gripper == with_fingers(load_settings(), SOFT_FINGERS_N_PER_M).gripper


def test_a_force_limit_from_the_settings_gripper_is_said_to_be_theirs(soft_grasp, settings):
    # Read with a weaker gripper than the one that squeezed it, a grasp's forces exceed the limit: the
    # record's own gripper sets it when the record carries one; else the refusal names the settings'.
    carried, bare = soft_grasp
    peak_n = float(np.max(carried.force_n.value))
    weak = dataclasses.replace(settings, gripper=dataclasses.replace(settings.gripper, target_force_n=peak_n / 4))
    assert no_tactile(carried, weak).e_pa == no_tactile(carried, settings).e_pa
    refused = no_tactile(bare, weak)
    assert not refused and "beyond" in refused.reason
    assert "the limit is the settings' gripper's (the record states none)" in refused.reason
    assert refused.reason.endswith("(its target_force_n)? is the load cell's scale (counts_per_n) in newtons?")
    stated = no_tactile(dataclasses.replace(carried, gripper=weak.gripper), settings)  # the record's own limit
    assert not stated and "settings' gripper" not in stated.reason
    assert stated.reason.endswith(" maximum grasp force: is the load cell's scale (counts_per_n) in newtons?")
