"""The robot node with franky-sim for the hand: its follows on a hardware gripper backend.

In a module of its own: franky-sim's simulation runs for the module (``franky_sim_robot``) and
would slow the tests after it.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable
from concurrent.futures import Future

import numpy as np
import pytest
from support.node_rig import drain, drive, killed_console_stops_the_fingers, node_rig, step_for

from teleop.errors import DeviceError
from teleop.record import Samples


def _on_franky(robot) -> Callable:
    def on_franky(settings):
        gripper = dataclasses.replace(settings.gripper, backend="franky", host=robot.hostname)
        return dataclasses.replace(settings, gripper=gripper)

    return on_franky


def _at_rest(cell, timeout_s: float) -> Samples:
    time.sleep(min(timeout_s, 1 / 80))
    return Samples(np.array([time.monotonic()]), np.zeros(1))


def test_a_silent_load_cell_stops_the_franky_sim_fingers_closing(franky_sim_robot):
    # The simulated load cell, silent without a grasp, stands in for a hardware cell gone silent; the
    # node does not tare it (it would wait for a force it never sends and refuse to start).
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
    # rest as a hardware cell does (the node closes the fingers only on fresh forces).
    monkeypatch.setattr(SimulatedLoadCell, "_take", _at_rest)

    node, operator, listener, _, sockets = node_rig(_on_franky(franky_sim_robot))
    try:
        assert not node.simulated
        step_for(node, 0.2)  # the load cell heard
        start = node.gripper.read_width()[1]
        target = 0.0 if start > 0.04 else 0.08
        # franky-sim's fingers creep on to the last step's goal: the step in flight, plus what they still
        # lagged behind the step before (franky-sim answers a move once its fingers barely move, short of
        # its goal; under load they lag more): within two steps at the follow speed.
        killed_console_stops_the_fingers(node, operator, listener, lambda t: target,
                                          still_m=2 * FOLLOW_SPEED_M_S * FOLLOW_STEP_S)
    finally:
        node.close()
        for sock in sockets:
            sock.close()


def _link_down(*args, **kwargs):
    raise DeviceError("franky gripper at 127.0.0.1: max_width read failed: Net Exception")


def _failed(*args, **kwargs) -> Future:
    future = Future()
    future.set_exception(DeviceError("franky gripper at 127.0.0.1: grasp failed: Net Exception"))
    return future


def _done(*args, **kwargs) -> Future:
    future = Future()
    future.set_result(True)
    return future


def _start_grasp(operator, grasp_id: str) -> None:
    operator.send("command", t_capture_s=time.monotonic(), action="start_grasp", grasp_id=grasp_id, params={})


def _step_until_ended(node, listener, grasp_id: str, within_s: float) -> list:
    """Step the node (each step must return) until the grasp's end went out; what the bus heard."""
    got, end = [], time.monotonic() + within_s
    while time.monotonic() < end:
        node.step(timeout_s=0.002)
        while (message := listener.recv(timeout_s=0)) is not None:
            got.append(message)
        if any(m.type == "grasp_event" and m.body["event"] == "end" and m.body["grasp_id"] == grasp_id for m in got):
            return got
    pytest.fail(f"grasp {grasp_id} did not end within {within_s} s: heard {[m.type for m in got]}")


def test_a_grasp_command_failing_on_franky_sim_ends_the_grasp_and_keeps_the_node_up(franky_sim_robot,
                                                                                    monkeypatch):
    # The link to franky-sim dies during the grasp: its command fails, and the gripper's commands
    # raise from then on (franky cannot read the hand's maximum width).
    node, operator, listener, _, sockets = node_rig(_on_franky(franky_sim_robot))
    try:
        monkeypatch.setattr(node.gripper, "grasp_async", _failed)
        monkeypatch.setattr(node.gripper, "move_async", _link_down)
        drain(listener)
        _start_grasp(operator, "g-lost")
        got = _step_until_ended(node, listener, "g-lost", node.settings.gripper.hold_s + 2.0)
        step_for(node, 0.1)  # the node carries on
        got += drain(listener)
        assert not [m for m in got if m.type == "robot_state" and m.body["mode"] == "holding"]
        notices = [m.body for m in got if m.type == "robot_notice"]
        assert any(n["event"] == "device" and n["action"] == "gripper" and n["grasp_id"] == "g-lost"
                   and "gripper command failed" in n["reason"] and "Net Exception" in n["reason"] for n in notices)
        events = [m.body["event"] for m in got if m.type == "grasp_event" and m.body["grasp_id"] == "g-lost"]
        assert events == ["start", "end"]
        assert not node.busy
        # The gripper still down: a new grasp is refused, with the reason, and the node stays up.
        monkeypatch.setattr(node.gripper, "grasp_async", _link_down)
        _start_grasp(operator, "g-again")
        step_for(node, 0.2)
        notices = [m.body for m in drain(listener) if m.type == "robot_notice"]
        assert any(n["event"] == "refused" and n["action"] == "start_grasp" and "Net Exception" in n["reason"]
                   for n in notices)
    finally:
        node.close()
        for sock in sockets:
            sock.close()


def test_a_release_failing_on_franky_sim_after_the_hold_ends_the_grasp_and_keeps_the_node_up(franky_sim_robot,
                                                                                             monkeypatch):
    node, operator, listener, _, sockets = node_rig(_on_franky(franky_sim_robot))
    try:
        monkeypatch.setattr(node.gripper, "grasp_async", _done)  # the fingers closed; then the link dies
        monkeypatch.setattr(node.gripper, "move_async", _link_down)
        drain(listener)
        _start_grasp(operator, "g-held")
        got = _step_until_ended(node, listener, "g-held", node.settings.gripper.hold_s + 2.0)
        step_for(node, 0.1)
        got += drain(listener)
        notices = [m.body for m in got if m.type == "robot_notice"]
        assert any(n["event"] == "device" and n["action"] == "gripper" and n["grasp_id"] == "g-held"
                   and "max_width read failed" in n["reason"] for n in notices)
        assert not node.busy
        assert [m.body["mode"] for m in got if m.type == "robot_state"][-1] == "idle"
    finally:
        node.close()
        for sock in sockets:
            sock.close()


def test_a_failure_handled_while_its_wake_up_is_queued_ends_the_grasp_once(franky_sim_robot, monkeypatch):
    # The grasp command fails between the node's draining of its queue and its advancing of the grasp:
    # the failure is handled there while the command's wake-up still waits in the queue.
    node, operator, listener, _, sockets = node_rig(_on_franky(franky_sim_robot))
    try:
        pending = Future()
        monkeypatch.setattr(node.gripper, "grasp_async", lambda *args, **kwargs: pending)
        drain(listener)
        _start_grasp(operator, "g-late")
        end = time.monotonic() + 5.0
        while node._grasp is None or node._grasp.phase != "grasping":
            assert time.monotonic() < end, "the grasp did not start"
            node.step(timeout_s=0.002)
        pending.set_exception(DeviceError("franky gripper at 127.0.0.1: grasp failed: Net Exception"))
        node._gripper_failed(pending.exception())  # as step() does when _advance raises it
        step_for(node, 0.1)
        events = [m.body["event"] for m in drain(listener)
                  if m.type == "grasp_event" and m.body["grasp_id"] == "g-late"]
        assert events == ["start", "end"] and not node.busy
    finally:
        node.close()
        for sock in sockets:
            sock.close()


class _DeadLink:
    """What a ``franky.Gripper`` does once its robot went away: every call fails."""

    def __getattr__(self, name: str):
        import franky

        raise franky.Exception("Net Exception")


def test_a_franky_sim_link_lost_while_idle_is_said_once_and_the_gripper_is_opened_again(franky_sim_robot,
                                                                                        monkeypatch):
    from teleop import node_devices

    monkeypatch.setattr(node_devices, "REOPEN_S", 0.2)
    node, operator, listener, _, sockets = node_rig(_on_franky(franky_sim_robot))
    try:
        step_for(node, 0.3)
        drain(listener)
        node.gripper._gripper = _DeadLink()  # the robot went away; franky-sim, still up, takes it back
        got, end = [], time.monotonic() + 15.0
        while not any(m.type == "robot_notice" and m.body["reason"] == "reading again" for m in got):
            assert time.monotonic() < end, f"heard {[m.body for m in got if m.type == 'robot_notice']}"
            node.step(timeout_s=0.002)
            got.extend(iter(lambda: listener.recv(timeout_s=0), None))
        step_for(node, 0.5)
        got += drain(listener)
        notices = [m.body for m in got if m.type == "robot_notice" and m.body["action"] == "gripper"]
        assert [n["event"] for n in notices] == ["device", "device"]  # once, then that it reads again
        assert "Net Exception" in notices[0]["reason"] and notices[1]["reason"] == "reading again"
        back = next(i for i, m in enumerate(got) if m.type == "robot_notice" and m.body["reason"] == "reading again")
        assert any(m.type == "width" for m in got[back:])  # the width stream is back
        assert node.gripper.read_width()[1] > 0.0
    finally:
        node.close()
        for sock in sockets:
            sock.close()
