"""The robot node on simulated hardware with an operator's bus for tests: follows sent at the
console's rate while the node steps, and what the bus heard."""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager

import pytest

from teleop.bus.pubsub import Publisher, Subscriber
from teleop.node import COMMAND_TOPICS, RobotNode
from teleop.operator import FOLLOW_RATE_HZ, WATCHDOG_S
from teleop.scene import load_scene

TOPICS = ("frame", "force", "width", "grasp_event", "robot_state", "robot_notice")


def node_rig(settings_of: Callable = lambda s: s):
    scene = load_scene("quick")
    robot = Publisher("tcp://127.0.0.1:*", lossless=True, source="robot")
    operator = Publisher("tcp://127.0.0.1:*", lossless=True, source="operator")
    commands = Subscriber(operator.endpoint, COMMAND_TOPICS)
    listener = Subscriber(robot.endpoint, TOPICS)
    node = RobotNode(settings_of(scene.settings), publisher=robot, commands=commands, scene=scene).connect()
    robot.wait_for_subscriber(*TOPICS, timeout_s=5.0)
    operator.wait_for_subscriber("command", "follow", timeout_s=5.0)
    return node, operator, listener, scene, (robot, operator, commands, listener)


@contextmanager
def running_node() -> Iterator[tuple[RobotNode, Publisher, Subscriber, object]]:
    """:func:`node_rig` as ``(node, operator, listener, scene)``, closed on leaving."""
    node, operator, listener, scene, sockets = node_rig()
    try:
        yield node, operator, listener, scene
    finally:
        node.close()
        for sock in sockets:
            sock.close()


def drive(node: RobotNode, operator: Publisher, target: Callable[[float], float], duration_s: float, *,
          grasp_id: str | None = "g-follow", enable: bool = True) -> float:
    """Send follows at FOLLOW_RATE_HZ for ``duration_s`` (target width of the time since the start),
    stepping the node; returns when the last follow went out."""
    start = next_s = time.monotonic()
    last = start
    while (now := time.monotonic()) - start < duration_s:
        if now >= next_s:
            operator.send("follow", t_capture_s=now, grasp_id=grasp_id, target_width_m=target(now - start),
                          enable=enable)
            last, next_s = now, next_s + 1.0 / FOLLOW_RATE_HZ
        node.step(timeout_s=0.002)
    return last


def step_for(node: RobotNode, duration_s: float) -> None:
    end = time.monotonic() + duration_s
    while time.monotonic() < end:
        node.step(timeout_s=0.002)


def drain(listener: Subscriber) -> list:
    got = []
    while (message := listener.recv(timeout_s=0.2)) is not None:
        got.append(message)
    return got


def wait_prepared(node: RobotNode) -> None:
    """Step the node until the first object (prepared at connect) is ready: a node left unstepped
    that long would take it for a stall of its own, and its watchdog would end the next grasp."""
    prepared, deadline = node._next_live[1], time.monotonic() + 30.0
    while not prepared.done():
        assert time.monotonic() < deadline, "the first object was not prepared within 30 s"
        node.step(timeout_s=0.002)
    prepared.result()


def killed_console_stops_the_fingers(node: RobotNode, operator: Publisher, listener: Subscriber,
                                     closing: Callable[[float], float], still_m: float) -> None:
    """Drive the fingers closing, go silent (the console killed), and check that the fingers stand
    still from the watchdog's stop on (due 200 ms after the last follow), with the watchdog's notice
    and the grasp's end."""
    watchdogs = node.stats.watchdogs
    started = time.monotonic()
    last = drive(node, operator, closing, 0.5)
    moving_from = node.gripper.read_width()[1]
    short_of_target_m = abs(closing(last - started) - moving_from)  # how far the last follow still had to go
    # Step until the watchdog stopped the fingers, however slowly this machine runs (the notice's
    # stamp below says how soon that was); the width read then is where they stopped.
    while node.stats.watchdogs == watchdogs:
        assert time.monotonic() < last + 5.0, "no watchdog within 5 s of the last follow"
        node.step(timeout_s=0.002)
    stopped = node.gripper.read_width()[1]
    step_for(node, 0.35)
    # Moving when the console died: they moved on until the stop, or (a loaded machine starving the
    # simulation) had not reached the last follow's target, so the stop had fingers to hold.
    assert abs(moving_from - stopped) > 1e-3 or short_of_target_m > 1e-3, \
        "the fingers were not moving when the console died"
    after = node.gripper.read_width()[1]
    assert after == pytest.approx(stopped, abs=still_m), \
        f"the fingers moved {abs(after - stopped) * 1e3:.2f} mm after the stop (at most {still_m * 1e3:.2f} mm)"
    got = drain(listener)
    notices = [m for m in got if m.type == "robot_notice"]
    assert [m.body["event"] for m in notices] == ["watchdog"]
    # Not before the watchdog's time; after it by at most one late node step. 150 ms rather than the
    # 50 ms an idle machine needs: a loaded one (two test workers on two cores) delays a step that much.
    assert WATCHDOG_S <= notices[0].t_capture_s - last < WATCHDOG_S + 0.15
    assert [m.body["event"] for m in got if m.type == "grasp_event"] == ["start", "end"]
    assert [m.body["mode"] for m in got if m.type == "robot_state"][-1] == "stopped"
    assert not node.busy
