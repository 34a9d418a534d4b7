"""The fingers' motion of a scripted grasp and of an operator-driven one.

Both give the fingers' true motor width and force on a fine time grid over a grasp's
:class:`~teleop.sim.grasp.LoadCurve`, with the times and record events
:func:`~teleop.sim.grasp.simulate_grasp` needs (its module notes describe the two styles).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from teleop.errors import SimulationError
from teleop.operator import FOLLOW_RATE_HZ, FOLLOW_SPEED_M_S
from teleop.record import GRASP_DONE_EVENT
from teleop.settings import GripperSettings
from teleop.sim.operator import SimulatedOperator
from teleop.sim.shapes import Scene

if TYPE_CHECKING:
    from teleop.sim.grasp import LoadCurve

__all__ = [
    "FOLLOW_LATENCY_S",
    "HOST_DELAY_S",
    "MAX_OPERATOR_S",
    "MOTION_DELAY_S",
    "TIME_STEP_S",
    "Motion",
    "operator_motion",
    "scripted_motion",
]

MOTION_DELAY_S = (0.02, 0.08)  # command to motion start
HOST_DELAY_S = (0.0, 0.05)  # grasp done to release command, beyond hold_s
TIME_STEP_S = 1e-3
FOLLOW_LATENCY_S = (0.005, 0.03)  # operator command to the gripper (bus and controller), uniform
MAX_OPERATOR_S = 120.0  # an operator grasp that has not finished by then is a simulation error


def _motion(t: np.ndarray, *, start_s: float, from_m: float, speed_m_s: float, sign: float) -> np.ndarray:
    return from_m + sign * speed_m_s * np.clip(t - start_s, 0.0, None)


@dataclass(frozen=True)
class Motion:
    """The fingers' true motion on the fine grid and the times the record and truth need."""

    t_s: np.ndarray
    motor_width_m: np.ndarray
    force_n: np.ndarray
    touch_s: float
    stall_s: float
    release_s: float
    lost_s: float  # the fingers have left the object
    events: dict[str, float]


def scripted_motion(curve: LoadCurve, scene: Scene, gripper: GripperSettings,
                    rng: np.random.Generator) -> Motion:
    """The paper's grasp: close at the closing speed until the force target stalls the fingers,
    hold ``hold_s``, release and open at the same speed."""
    speed = gripper.closing_speed_m_s
    command_s = 0.0
    move_s = command_s + rng.uniform(*MOTION_DELAY_S)
    touch_s = move_s + (gripper.max_width_m - scene.extent_m) / speed
    stall_closure = min(float(curve.closure_m[-1]), scene.extent_m)  # the fingers cannot pass each other
    stall_s = touch_s + stall_closure / speed
    release_s = stall_s + gripper.hold_s + rng.uniform(*HOST_DELAY_S)
    open_s = release_s + rng.uniform(*MOTION_DELAY_S)
    lost_s = open_s + stall_closure / speed
    t = np.arange(touch_s - 2.0, lost_s + 2.0, TIME_STEP_S)
    closing = np.minimum(_motion(t, start_s=move_s, from_m=gripper.max_width_m, speed_m_s=speed, sign=-1.0),
                         gripper.max_width_m)
    stall_width = scene.extent_m - stall_closure
    motor_width = np.where(t < open_s, np.maximum(closing, stall_width),
                           np.minimum(_motion(t, start_s=open_s, from_m=stall_width, speed_m_s=speed, sign=1.0),
                                      gripper.max_width_m))
    force = curve.force_at(scene.extent_m - motor_width)
    return Motion(t, motor_width, force, touch_s, stall_s, release_s, lost_s,
                  {"command_grasp": command_s, GRASP_DONE_EVENT: stall_s, "command_release": release_s})


def operator_motion(curve: LoadCurve, scene: Scene, gripper: GripperSettings, operator: SimulatedOperator,
                    rng: np.random.Generator) -> Motion:
    """A leader-follower grasp (:mod:`teleop.sim.grasp` notes): the operator commands a target
    width at FOLLOW_RATE_HZ from the force it feels; the fingers follow at up to FOLLOW_SPEED_M_S,
    stalled by the force cap (the curve's top) and by each other; after the release they open at
    the closing speed."""
    dt = TIME_STEP_S
    every = max(round(1.0 / (FOLLOW_RATE_HZ * dt)), 1)
    latency = max(round(rng.uniform(*FOLLOW_LATENCY_S) / dt), 1)
    open_delay = rng.uniform(*MOTION_DELAY_S)
    stall_width = scene.extent_m - min(float(curve.closure_m[-1]), scene.extent_m)
    open_m, step_m = gripper.max_width_m, FOLLOW_SPEED_M_S * dt
    width, target, release_s, done_s = open_m, open_m, None, None
    pending: list[tuple[int, float]] = []  # (step it reaches the gripper, target width)
    widths = []
    for i in range(round(MAX_OPERATOR_S / dt)):
        t_s = i * dt
        command = None
        if i % every == 0:
            force = float(curve.force_at(np.array(scene.extent_m - width)))
            command = operator.step(t_s, force_n=force, width_m=width)
            if command.release and release_s is None:
                release_s = t_s
            elif command.enable and release_s is None:
                pending.append((i + latency, command.target_width_m))
        while pending and pending[0][0] <= i:
            target = pending.pop(0)[1]
        if release_s is None:
            width = max(width + min(max(target - width, -step_m), step_m), stall_width)
        elif t_s >= release_s + open_delay:
            width = min(width + gripper.closing_speed_m_s * dt, open_m)
        widths.append(width)
        if command is not None and operator.done:
            done_s = t_s
            break
    if done_s is None:
        raise SimulationError(f"the simulated operator had not finished its grasp after {MAX_OPERATOR_S:g} s "
                              f"({operator.style.describe()})")
    t = np.arange(-2.0, done_s + 2.0, dt)[: len(widths) + round(4.0 / dt)]
    motor_width = np.full(t.shape, open_m)
    begin = round(2.0 / dt)
    motor_width[begin : begin + len(widths)] = widths
    tail = motor_width[begin + len(widths):]  # the fingers finish opening
    tail[:] = np.minimum(widths[-1] + gripper.closing_speed_m_s * dt * np.arange(1, tail.size + 1), open_m)
    force = curve.force_at(scene.extent_m - motor_width)
    touched = np.flatnonzero(force > 0)
    touch_s = float(t[touched[0]]) if touched.size else float(t[begin])
    stall_s = float(t[int(np.argmax(force))])
    lost_s = float(t[touched[-1]]) if touched.size else done_s
    return Motion(t, motor_width, force, touch_s, stall_s, release_s, lost_s,
                  {"command_grasp": 0.0, "command_release": release_s})
