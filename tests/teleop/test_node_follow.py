"""The robot node driven by an operator: follow grasps, simulated live, the watchdog and refusals."""

from __future__ import annotations

import re
import time

import numpy as np
import pytest
from support.node_rig import (
    drain,
    drive,
    killed_console_stops_the_fingers,
    running_node,
    step_for,
    wait_prepared,
)

from teleop.operator import WATCHDOG_S


@pytest.fixture
def rig():
    with running_node() as rig:
        yield rig


@pytest.mark.slow
def test_a_follow_grasp_is_simulated_live_force_capped_and_released(rig):
    node, operator, listener, scene = rig
    wait_prepared(node)
    cap = scene.settings.gripper.target_force_n
    # Close to 0 over 1 s (the stress ball stalls at the maximum force), hold, then release.
    drive(node, operator, lambda t: max(0.0, 0.08 * (1.0 - t)), 1.3)
    operator.send("command", t_capture_s=time.monotonic(), action="release", grasp_id="g-follow", params={})
    deadline = time.monotonic() + 5.0
    while node.busy:
        assert time.monotonic() < deadline, "the released grasp did not end"
        node.step(timeout_s=0.002)
    got = drain(listener)
    ours = [m for m in got if m.body.get("grasp_id") == "g-follow"]
    events = [m for m in ours if m.type == "grasp_event"]
    assert [m.body["event"] for m in events] == ["start", "end"]
    assert events[0].body["object_name"] == scene.objects[0].name
    data = [m for m in ours if m.type in ("frame", "force", "width")]
    assert {m.type for m in data} == {"frame", "force", "width"}
    assert {m.topic for m in data if m.type == "frame"} == {"frame/left", "frame/right"}
    assert events[0].t_capture_s <= min(m.t_capture_s for m in data)
    forces = np.concatenate([m.body["value_n"] for m in data if m.type == "force"])
    assert 0.9 * cap < forces.max() <= 1.05 * cap  # squeezed to the cap, never beyond (gain error, noise)
    widths = np.concatenate([m.body["value_m"] for m in data if m.type == "width"])
    assert widths.min() < 0.05  # closed on the ball
    assert widths[-1] > 0.07  # opened again
    notices = [m.body for m in got if m.type == "robot_notice"]
    assert [n["event"] for n in notices] == ["force_limit"]
    modes = [m.body["mode"] for m in got if m.type == "robot_state"]
    assert "following" in modes and "releasing" in modes and modes[-1] == "idle"


def test_enable_released_stops_the_fingers(rig):
    node, operator, listener, _ = rig
    wait_prepared(node)
    drive(node, operator, lambda t: 0.08 - 0.05 * t, 0.3)
    drive(node, operator, lambda t: 0.0, 0.2, enable=False)  # targets without enable do not count
    held = node.gripper.read_width()[1]
    drive(node, operator, lambda t: 0.0, 0.3, enable=False)
    assert node.gripper.read_width()[1] == pytest.approx(held, abs=2e-4)
    assert held < 0.075 and node.busy  # it had moved; the grasp goes on
    states = [m.body for m in drain(listener) if m.type == "robot_state"]
    assert states[-1]["enable"] is False and states[-1]["mode"] == "following"


def test_enable_released_stops_fingers_still_on_their_way(rig):
    node, operator, _, _ = rig
    wait_prepared(node)
    drive(node, operator, lambda t: 0.03, 0.04)  # 50 mm ahead of the open fingers: on their way for 0.5 s
    drive(node, operator, lambda t: 0.03, 0.5, enable=False)
    # Stopped about 4 mm in (0.35 s of the node's delay to spare), not carried on to the old target.
    assert node.gripper.read_width()[1] > 0.045


def test_the_watchdog_stops_fingers_still_on_their_way(rig):
    node, operator, _, _ = rig
    wait_prepared(node)
    drive(node, operator, lambda t: 0.0, 0.04)  # closing on the object, then the operator falls silent
    step_for(node, 0.35)
    assert not node.busy and node._follower.stopped
    stopped_at = node.gripper.read_width()[1]
    step_for(node, 0.5)
    assert node.gripper.read_width()[1] == pytest.approx(stopped_at, abs=5e-4)  # not closing on to the target


def shifted_clock(node, monkeypatch) -> list[float]:
    """The node's clock ahead of the wall clock by the returned list's one item, which the test
    moves on: a node stalled, or slow, without waiting for it."""
    ahead = [0.0]
    clock = node.clock
    monkeypatch.setattr(node, "clock", lambda: clock() + ahead[0])
    return ahead


def test_follows_that_came_while_the_node_published_a_backlog_count_before_the_watchdog(rig, monkeypatch):
    node, operator, listener, _ = rig
    wait_prepared(node)
    drive(node, operator, lambda t: 0.07, 0.3)
    ahead = shifted_clock(node, monkeypatch)
    publish = node._publish

    def slow(kind, item):
        if kind != "backlog":
            publish(kind, item)
            return
        ahead[0] += 0.4 * WATCHDOG_S  # the node busy publishing what its devices captured ...
        operator.send("follow", t_capture_s=time.monotonic(), grasp_id="g-follow", target_width_m=0.07, enable=True)
        time.sleep(0.01)  # ... while the operator's follows keep coming (on their way)

    monkeypatch.setattr(node, "_publish", slow)
    for _ in range(5):  # twice the watchdog's time in all: neither the operator's silence nor a stall
        node._captured.put(("backlog", None))
    node.step(timeout_s=0.002)
    assert node.busy
    drive(node, operator, lambda t: 0.07, 0.1)
    assert not [m for m in drain(listener) if m.type == "robot_notice"]


def test_a_node_that_stalled_stops_the_fingers_and_refuses_the_follows_that_queued_meanwhile(rig, monkeypatch):
    node, operator, listener, _ = rig
    wait_prepared(node)
    drive(node, operator, lambda t: 0.07, 0.3)
    while listener.recv(timeout_s=0) is not None:  # not drain's wait: the node not stepping would stall
        pass
    ahead = shifted_clock(node, monkeypatch)
    # The node stopped (SIGSTOP, a starved CPU) for a little over a watchdog while the operator kept closing.
    for width in np.linspace(0.065, 0.03, 10):
        operator.send("follow", t_capture_s=time.monotonic(), grasp_id="g-follow", target_width_m=width, enable=True)
    time.sleep(0.05)  # the follows on their way
    ahead[0] += 1.2 * WATCHDOG_S
    step_for(node, 0.1)
    assert not node.busy and node._follower.stopped
    assert node.gripper.read_width()[1] > 0.069  # not driven toward the backlog's 65 .. 30 mm
    said = [m.body for m in drain(listener) if m.type == "robot_notice"]
    assert said[0]["event"] == "watchdog" and said[0]["grasp_id"] == "g-follow"
    stalled = re.fullmatch(r"the robot node itself stalled for ([\d.]+) s \(watchdog 0.2 s\): the fingers stopped",
                           said[0]["reason"])
    assert stalled and float(stalled[1]) >= 1.2 * WATCHDOG_S
    assert {(n["event"], n["grasp_id"]) for n in said[1:]} == {("refused", "g-follow")}
    assert "grasp 'g-follow' has ended" in said[1]["reason"]


def test_a_slow_gripper_stop_in_a_command_is_no_stall_of_the_node(rig, monkeypatch):
    # Letting go of the enable stops the fingers; a stop that takes longer than the watchdog is the
    # gripper's time, not the node's: the follow grasp is paused, not ended.
    node, operator, listener, _ = rig
    wait_prepared(node)
    drive(node, operator, lambda t: 0.07, 0.3)
    while listener.recv(timeout_s=0) is not None:  # not drain's wait: the node not stepping would stall
        pass
    ahead = shifted_clock(node, monkeypatch)
    stop = node.gripper.stop

    def slow_stop():  # the console's let-go follows keep coming while it blocks
        ahead[0] += 1.5 * WATCHDOG_S
        for _ in range(3):
            operator.send("follow", t_capture_s=time.monotonic(), grasp_id="g-follow", target_width_m=0.07,
                          enable=False)
        time.sleep(0.05)
        stop()

    monkeypatch.setattr(node.gripper, "stop", slow_stop)
    drive(node, operator, lambda t: 0.07, 0.2, enable=False)  # let go, and the console keeps saying so
    said = [m.body for m in drain(listener) if m.type == "robot_notice"]
    assert node.busy and not any(n["event"] == "watchdog" for n in said), said


def test_killing_the_console_stops_the_simulated_gripper_within_250_ms(rig):
    node, operator, listener, _ = rig
    wait_prepared(node)
    # Closing at 40 mm/s: still in the air (the stress ball is 63 mm wide) when the console dies.
    killed_console_stops_the_fingers(node, operator, listener, lambda t: 0.08 - 0.04 * (t + 0.1), still_m=1e-4)


@pytest.mark.slow
def test_commands_that_cannot_be_carried_out_are_refused_on_the_bus(rig):
    node, operator, listener, scene = rig
    wait_prepared(node)
    maximum = scene.settings.gripper.target_force_n
    operator.send("command", t_capture_s=0.0, action="start_grasp", grasp_id="g-typo", params={"hold_s": 1e9})
    operator.send("command", t_capture_s=0.0, action="start_grasp", grasp_id="g-hard", params={"target_force_n": 500.0})
    drive(node, operator, lambda t: 0.5, 0.05, grasp_id="g-wide")  # wider than the gripper opens
    drive(node, operator, lambda t: 0.07, 0.1, grasp_id="g-follow")
    operator.send("command", t_capture_s=0.0, action="start_grasp", grasp_id="g-during", params={})
    drive(node, operator, lambda t: 0.07, 0.1, grasp_id="g-other")
    refusals = [m.body for m in drain(listener) if m.type == "robot_notice"]
    assert [(r["action"], r["grasp_id"]) for r in refusals] == [("start_grasp", "g-typo"),
        ("start_grasp", "g-hard"), ("follow", "g-wide"), ("start_grasp", "g-during"), ("follow", "g-other")]
    assert all(r["event"] == "refused" for r in refusals)
    assert "start_grasp params hold_s: expected only object_index, target_force_n" in refusals[0]["reason"]
    refusals = refusals[1:]
    assert f"{maximum}" in refusals[0]["reason"] and "open to" in refusals[1]["reason"]
    assert "in progress" in refusals[2]["reason"] and "g-follow" in refusals[3]["reason"]
    # After the grasp: its id is spent, and a commanded grasp takes no follows.
    operator.send("command", t_capture_s=0.0, action="release", grasp_id="g-follow", params={})
    drive(node, operator, lambda t: 0.07, 0.6, grasp_id=None, enable=False)
    assert not node.busy
    drive(node, operator, lambda t: 0.07, 0.05, grasp_id="g-follow")
    operator.send("command", t_capture_s=0.0, action="start_grasp", grasp_id="g-script", params={})
    step_for(node, 0.05)
    drive(node, operator, lambda t: 0.07, 0.05, grasp_id=None)
    reasons = [m.body["reason"] for m in drain(listener) if m.type == "robot_notice"]
    assert any("has ended" in r for r in reasons) and any("commanded grasp" in r for r in reasons)
    assert node.stats.bad_commands >= len(refusals) + 2  # repeated follows refused, their notices not repeated


@pytest.mark.slow
def test_a_release_opens_fingers_the_watchdog_left_closed_and_the_next_grasp_takes_the_next_object(rig):
    node, operator, listener, scene = rig
    wait_prepared(node)
    # Squeeze the stress ball to the force limit, then go silent: the watchdog ends the grasp with
    # the fingers closed on it.
    drive(node, operator, lambda t: max(0.0, 0.08 * (1.0 - 1.5 * t)), 1.0, grasp_id="g-first")
    step_for(node, 0.4)
    assert not node.busy and node.gripper.read_width()[1] < 0.06
    # A release without a grasp opens them (as the operator's console sends it); the ball leaves.
    operator.send("command", t_capture_s=time.monotonic(), action="release", grasp_id=None, params={})
    deadline = time.monotonic() + 5.0
    while node.gripper.read_width()[1] < 0.075:
        assert time.monotonic() < deadline, "the fingers did not open"
        step_for(node, 0.1)
    # The operator has the fingers back: the node is no longer in the watchdog's stop.
    assert [m.body["mode"] for m in drain(listener) if m.type == "robot_state"][-1] == "idle"
    # The next follow grasp takes the scene's next object, prepared once it is asked for.
    starts = _drive_until_started(node, operator, listener, "g-second")
    assert starts["g-second"] == scene.objects[1].name != scene.objects[0].name


def _drive_until_started(node, operator, listener, grasp_id: str) -> dict[str, str]:
    """Follow with the fingers open until ``grasp_id`` starts (its object prepared first); the objects of
    the grasps that started meanwhile, by grasp id."""
    deadline, starts = time.monotonic() + 30.0, {}
    while grasp_id not in starts:
        assert time.monotonic() < deadline, f"grasp {grasp_id} did not start"
        drive(node, operator, lambda t: 0.08, 0.3, grasp_id=grasp_id)
        # What came so far, not drain's wait: the node not stepping that long would have stalled.
        while (m := listener.recv(timeout_s=0)) is not None:
            if m.type == "grasp_event" and m.body["event"] == "start":
                starts[m.body["grasp_id"]] = m.body["object_name"]
    return starts


@pytest.mark.slow
def test_grasping_again_what_the_watchdog_left_between_the_fingers_takes_no_new_object(rig):
    node, operator, listener, scene = rig
    wait_prepared(node)
    drive(node, operator, lambda t: max(0.0, 0.08 * (1.0 - 1.5 * t)), 1.0, grasp_id="g-first")
    step_for(node, 0.4)  # the watchdog: the fingers stay closed on the stress ball
    drive(node, operator, lambda t: 0.0, 0.3, grasp_id="g-again")
    operator.send("command", t_capture_s=time.monotonic(), action="release", grasp_id="g-again", params={})
    starts = _drive_until_started(node, operator, listener, "g-next")
    # The scene's objects in turn: the one grasped again took no turn of its own.
    assert [starts[g] for g in ("g-first", "g-again", "g-next")] == [scene.objects[0].name] * 2 + [scene.objects[1].name]


@pytest.mark.slow
def test_a_commanded_grasp_leaves_the_fingers_open_for_the_next_objects_follow_grasp(rig):
    node, operator, listener, scene = rig
    operator.send("command", t_capture_s=time.monotonic(), action="start_grasp", grasp_id="g-script", params={})
    deadline = time.monotonic() + 30.0
    while node.busy or node.stats.grasps < 1:
        assert time.monotonic() < deadline, "the commanded grasp did not end"
        node.step(timeout_s=0.002)
    step_for(node, 1.0)
    # The replay let go where its record ends; as a hardware release, the fingers then open fully.
    assert node.gripper.read_width()[1] == pytest.approx(scene.settings.gripper.max_width_m, abs=1e-3)
    assert node._next_live[0] == 1  # the next grasp's object prepared ahead, not the one the commanded grasp skipped
    wait_prepared(node)
    drain(listener)
    drive(node, operator, lambda t: scene.settings.gripper.max_width_m, 0.4, grasp_id="g-next")
    forces = np.concatenate([m.body["value_n"] for m in drain(listener) if m.type == "force"])
    assert forces.size and forces.max() < 1.0  # the next object sits between open fingers, untouched
