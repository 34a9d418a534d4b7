"""The robot node with franky-sim for the hand: its follows on a hardware gripper backend.

In a module of its own: franky-sim's simulation runs for the module (``franky_sim_robot``) and
would slow the tests after it.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable

import numpy as np
from support.node_rig import drain, drive, killed_console_stops_the_fingers, node_rig, step_for

from teleop.record import Samples


def _on_franky(robot) -> Callable:
    def on_franky(settings):
        gripper = dataclasses.replace(settings.gripper, backend="franky", host=robot.hostname)
        return dataclasses.replace(settings, gripper=gripper)

    return on_franky


def _at_rest(cell, timeout_s: float) -> Samples:
    time.sleep(min(timeout_s, 1 / 80))
    return Samples(np.array([time.monotonic()]), np.zeros(1))


def test_a_silent_load_cell_stops_the_franky_sim_fingers_closing(franky_sim_robot, monkeypatch):
    from teleop.devices.playback import SimulatedLoadCell

    # The simulated load cell, silent without a grasp, stands in for a hardware cell gone silent.
    monkeypatch.setattr(SimulatedLoadCell, "tare", lambda self: 0.0)
    node, operator, listener, _, sockets = node_rig(_on_franky(franky_sim_robot))
    try:
        start = node.gripper.read_width()[1]
        drive(node, operator, lambda t: 0.0, 0.5)
        assert node.gripper.read_width()[1] > start - 1e-3  # never closed: it could not have been capped
        notices = [m.body for m in drain(listener) if m.type == "robot_notice"]
        assert notices and all(n["event"] == "refused" and "load cell has sent no force" in n["reason"]
                               for n in notices)
    finally:
        node.close()
        for sock in sockets:
            sock.close()


def test_killing_the_console_stops_the_franky_sim_gripper_within_250_ms(franky_sim_robot, monkeypatch):
    from teleop.devices.franky_gripper import FOLLOW_STEP_S
    from teleop.devices.gripper import FOLLOW_SPEED_M_S
    from teleop.devices.playback import SimulatedLoadCell

    # franky-sim stands in for the hand; the simulated load cell for the bridge, streaming no force at
    # rest as a hardware cell does (the node tares it when it connects, and closes the fingers only on
    # fresh forces).
    monkeypatch.setattr(SimulatedLoadCell, "tare", lambda self: 0.0)
    monkeypatch.setattr(SimulatedLoadCell, "_take", _at_rest)

    node, operator, listener, _, sockets = node_rig(_on_franky(franky_sim_robot))
    try:
        assert not node.simulated
        step_for(node, 0.2)  # the load cell heard
        start = node.gripper.read_width()[1]
        target = 0.0 if start > 0.04 else 0.08
        # franky-sim's fingers creep toward the last step's goal: within one step at the follow speed.
        killed_console_stops_the_fingers(node, operator, listener, lambda t: target,
                                          still_m=FOLLOW_SPEED_M_S * FOLLOW_STEP_S)
    finally:
        node.close()
        for sock in sockets:
            sock.close()
