"""The simulated operator backend: seeded, closed loop on a spring, release then next."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from haptics.errors import OperatorInputError
from haptics.inputs import make_input
from haptics.inputs.sim import SimulatedInput
from teleop.operator import FOLLOW_SPEED_M_S, grip_to_width_m

DT_S = 0.02  # the operator side's follow period (50 Hz)
MAX_WIDTH_M = 0.08
MAX_FORCE_N = 30.0


class SpringGripper:
    """Fingers following the target width at up to 0.1 m/s, an object of ``stiffness`` N/m from
    ``contact_m`` inward, and the gripper's force cap: it stops closing at ``MAX_FORCE_N``."""

    def __init__(self, *, stiffness: float, contact_m: float) -> None:
        self.stiffness, self.contact_m = stiffness, contact_m
        self.width_m = MAX_WIDTH_M

    def force_at(self, width_m: float) -> float:
        return self.stiffness * max(self.contact_m - width_m, 0.0)

    def follow(self, target_m: float) -> None:
        step = float(np.clip(target_m - self.width_m, -FOLLOW_SPEED_M_S * DT_S, FOLLOW_SPEED_M_S * DT_S))
        width = self.width_m + step
        if step < 0 and self.force_at(width) > MAX_FORCE_N:  # force-capped: stall at the limit
            width = max(width, self.contact_m - MAX_FORCE_N / self.stiffness)
        self.width_m = width

    @property
    def force_n(self) -> float:
        return self.force_at(self.width_m)


def run_grasp(device: SimulatedInput, gripper: SpringGripper, clock, *, limit_s: float = 60.0):
    """Drive one grasp as the node would: follow while enabled, open on release; the readings."""
    readings, released = [], False
    for _ in range(int(limit_s / DT_S)):
        next(clock)
        reading = device.read(timeout_s=0.0)
        readings.append(reading)
        if "release" in reading.buttons:
            released = True
        if released:
            gripper.follow(MAX_WIDTH_M)  # the node opens the fingers on release
        elif reading.enable:
            gripper.follow(grip_to_width_m(reading.grip, max_width_m=MAX_WIDTH_M))
        device.feel(force_n=gripper.force_n, width_m=gripper.width_m, stiffness=None)
        if reading.buttons & {"next", "quit"}:
            return readings
    raise AssertionError(f"the grasp did not finish in {limit_s} s")


def sim(seed: int, **options) -> tuple[SimulatedInput, itertools.count]:
    ticks = itertools.count()
    now = {"t": 0.0}

    def clock() -> float:
        return now["t"]

    class Ticker:
        def __next__(self):
            now["t"] = next(ticks) * DT_S

    device = SimulatedInput(seed=seed, max_width_m=MAX_WIDTH_M, max_force_n=MAX_FORCE_N, clock=clock, **options)
    return device, Ticker()


@pytest.mark.parametrize(("seed", "stiffness"), [(0, 2e3), (1, 2e4), (2, 3e5), (3, 800.0), (4, 5e3)])
def test_a_grasp_closes_on_the_object_releases_then_says_next(seed, stiffness):
    device, clock = sim(seed)
    gripper = SpringGripper(stiffness=stiffness, contact_m=0.05)
    with device:
        readings = run_grasp(device, gripper, clock)
    presses = [(i, r.buttons) for i, r in enumerate(readings) if r.buttons]
    assert [b for _, b in presses] == [{"release"}, {"next"}]
    released_at = presses[0][0]
    squeezing = readings[:released_at]
    assert any(r.enable for r in squeezing)  # the dead-man was held while it squeezed
    assert not any(r.enable for r in readings[released_at:])  # and let go from the release on
    closest = min(grip_to_width_m(r.grip, max_width_m=MAX_WIDTH_M) for r in squeezing)
    assert closest < 0.05  # it squeezed into the object
    felt = max(r.force_n for r in readings)
    assert 0.3 <= felt <= MAX_FORCE_N + 1e-9
    assert gripper.width_m >= MAX_WIDTH_M - 0.001  # "next" only once the fingers are open
    assert all(0.0 <= r.grip <= 1.0 for r in readings)
    assert readings[-1].t_s == pytest.approx((len(readings) - 1) * DT_S)


def test_the_same_seed_gives_the_same_grasps_and_each_grasp_a_new_operator():
    runs = []
    for _ in range(2):
        device, clock = sim(7, grasps=3)
        gripper = SpringGripper(stiffness=5e3, contact_m=0.045)
        styles, grips = [], []
        with device:
            for _ in range(3):
                readings = run_grasp(device, gripper, clock)
                styles.append(device.operator.style)
                grips.append([r.grip for r in readings])
            assert readings[-1].buttons == {"quit"} and device.grasps_done == 3
            idle = device.read()
            assert (idle.grip, idle.enable, idle.buttons) == (0.0, False, frozenset())
        runs.append((styles, grips))
    assert runs[0] == runs[1]
    styles = runs[0][0]
    assert len(set(styles)) == 3  # a new operator for every grasp


def test_grasp_k_does_not_depend_on_what_came_before():
    first, clock = sim(11)
    with first:
        run_grasp(first, SpringGripper(stiffness=1e3, contact_m=0.06), clock)
        run_grasp(first, SpringGripper(stiffness=1e3, contact_m=0.06), clock)
        second_style = first.operator.style
    other, clock = sim(11)
    with other:
        run_grasp(other, SpringGripper(stiffness=9e4, contact_m=0.03), clock)  # another object first
        run_grasp(other, SpringGripper(stiffness=1e3, contact_m=0.06), clock)
        assert other.operator.style == second_style


def test_connect_starts_over_and_the_seed_comes_from_the_settings(settings, with_operator):
    device = make_input("sim", with_operator(sim_seed=5))
    assert (device.seed, device.max_width_m, device.max_force_n) == (5, 0.08, 30.0)
    assert make_input("sim", settings, seed=9).seed == 9
    with device:
        device.read()
        device.read()
        assert device.operator is not None
    with device:
        assert device.operator is None and device.grasps_done == 0


def test_the_first_read_after_connect_has_the_enable_released_then_the_operator_holds_it():
    # A person sits down before pressing the dead-man: an operator's loop drives only an enable it
    # has read let go first, so the simulated operator's first read after connect() is idle.
    device, clock = sim(4)
    for _ in range(2):  # and again after connecting again
        with device:
            next(clock)
            first = device.read()
            assert (first.grip, first.enable, first.buttons) == (0.0, False, frozenset())
            assert device.operator is None
            next(clock)
            assert device.read().enable and device.operator is not None
    device, clock = sim(4, starts_released=False)
    with device:
        assert device.read().enable


@pytest.mark.parametrize(("options", "match"), [({"seed": -1}, "seed"), ({"seed": 1.5}, "seed"),
                                                ({"grasps": 0}, "grasps"), ({"grasps": True}, "grasps")])
def test_bad_options_are_refused(options, match):
    with pytest.raises(OperatorInputError, match=match):
        SimulatedInput(**options)
