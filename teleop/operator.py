"""What the operator side and the robot node agree on about driving the fingers.

Leader-follower drives the fingers' **target width**, force-capped (position-position): the
gripper measures no force and the Franka hand takes width targets, while a loop closed on the
load cell's 80 Hz force, read with latency, chatters on stiff objects. The operator closes the
loop on force through the softness display, and the fingers never exceed the settings' maximum
grasp force (``gripper.target_force_n``): the node stops closing there.

The operator side sends ``follow`` messages (:mod:`teleop.bus.wire`) at :data:`FOLLOW_RATE_HZ`;
they count only while the dead-man enable is held, and the node stops the fingers when none has
come for :data:`WATCHDOG_S`. A grip (or trigger) position in [0, 1], 0 open and 1 fully
squeezed, maps linearly onto the fingers' width: open grip, open fingers.
"""

from __future__ import annotations

import math

__all__ = ["BUTTONS", "FOLLOW_RATE_HZ", "FOLLOW_SPEED_M_S", "WATCHDOG_S", "grip_to_width_m", "width_to_grip"]

FOLLOW_RATE_HZ = 50.0
# The fingers follow an operator's target at up to this speed (m/s): faster than a grasp closes.
FOLLOW_SPEED_M_S = 0.1
WATCHDOG_S = 0.2
# Discrete operator buttons, as every input backend names them.
BUTTONS = ("grasp", "release", "stop", "next", "quit")


def _check(name: str, value: float) -> float:
    if not (isinstance(value, int | float) and math.isfinite(value)):
        raise ValueError(f"{name} = {value!r}: expected a finite number")
    return float(value)


def grip_to_width_m(grip: float, *, max_width_m: float) -> float:
    """The fingers' target width (m) for a grip position in [0, 1] (clipped), 0 = open."""
    grip = min(max(_check("grip", grip), 0.0), 1.0)
    return _check("max_width_m", max_width_m) * (1.0 - grip)


def width_to_grip(width_m: float, *, max_width_m: float) -> float:
    """The grip position in [0, 1] that asks for ``width_m`` (inverse of :func:`grip_to_width_m`)."""
    span = _check("max_width_m", max_width_m)
    if span <= 0:
        raise ValueError(f"max_width_m = {max_width_m!r}: expected a number > 0")
    return min(max(1.0 - _check("width_m", width_m) / span, 0.0), 1.0)
