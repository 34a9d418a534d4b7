"""The live simulation's finger motor and stall width (teleop.sim.live), driven directly: no object is
prepared, a LiveObject is built from a stand-in scene and load curve."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from teleop.errors import SimulationError
from teleop.sim.live import HISTORY_S, LiveObject, Motor


def test_the_motor_never_closes_past_its_stall_width():
    # Past the stall width the fingers would squeeze beyond the maximum force.
    motor = Motor(0.05, 0.0, stall_width_m=0.02)
    arrives_s = motor.command(0.0, 0.1, 0.0)
    assert motor.target_m() == pytest.approx(0.02)
    assert arrives_s == pytest.approx(0.3)
    assert motor.width_at(5.0) == pytest.approx(0.02)
    assert motor.stalled(5.0) and not motor.stalled(0.1)


def test_a_motor_started_inside_its_stall_width_stands_at_it():
    motor = Motor(0.01, 0.0, stall_width_m=0.02)
    assert motor.width_at(0.0) == pytest.approx(0.02) and motor.stalled(0.0)


def test_a_motor_standing_exactly_at_its_stall_width_is_stalled():
    assert Motor(0.02, 0.0, stall_width_m=0.02).stalled(0.0)
    assert not Motor(0.0, 0.0, stall_width_m=0.0).stalled(0.0)  # no stall width: the fingers met


def test_the_arrival_time_is_in_the_future_when_closing_and_when_opening():
    motor = Motor(0.05, 10.0, stall_width_m=0.0)
    assert motor.command(0.03, 0.01, 10.0) == pytest.approx(12.0)
    assert motor.command(0.05, 0.01, 12.0) == pytest.approx(14.0)


def test_widths_of_the_recent_past_are_kept():
    # A sensor sampled in the recent past reads the width the motor had then.
    motor = Motor(0.05, 0.0, stall_width_m=0.0)
    motor.command(0.03, 0.01, 0.0)  # closing 1 cm/s
    motor.command(0.05, 0.01, 1.0)  # opening again from 0.04
    motor.command(0.05, 0.01, 1.5)
    assert HISTORY_S > 1.5 - 0.5  # 0.5 s is within the kept history at 1.5 s
    assert motor.width_at(0.5) == pytest.approx(0.045)
    assert motor.width_at(1.25) == pytest.approx(0.0425)


@pytest.mark.parametrize("to_m", [float("nan"), float("inf"), -float("inf")])
def test_a_command_to_no_finite_width_is_refused(to_m):
    motor = Motor(0.05, 0.0, stall_width_m=0.0)
    with pytest.raises(SimulationError, match="motor command"):
        motor.command(to_m, 0.1, 0.0)
    assert motor.width_at(1.0) == pytest.approx(0.05)


def test_the_stall_width_is_zero_when_the_fingers_meet_before_the_maximum_force():
    # A negative stall width would let the motor close past the fingers meeting.
    def live(extent_m, closure_m):
        return LiveObject("stand-in", SimpleNamespace(extent_m=extent_m),
                          SimpleNamespace(closure_m=np.array([0.0, closure_m])), 20.0, {}, {})

    assert live(0.01, 0.02).stall_width_m == 0.0
    assert live(0.03, 0.01).stall_width_m == pytest.approx(0.02)
