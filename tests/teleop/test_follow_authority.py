"""Who drives a follow grasp: only follows and releases naming the grasp in progress count (a
refused follow changes nothing, the watchdog included), anyone's stop wins, and a stop, release or
let-go enable while the grasp prepares keeps the fingers from closing when it would go live."""

from __future__ import annotations

import time
from collections.abc import Callable
from concurrent.futures import Future

import pytest
from support.node_rig import drain, running_node, step_for, wait_prepared

from teleop.bus.wire import make_message
from teleop.errors import DeviceError, SimulationError
from teleop.operator import WATCHDOG_S


@pytest.fixture
def rig():
    with running_node() as (node, _, listener, _scene):
        yield node, listener


def follow(node, grasp_id: str | None, width_m: float, *, enable: bool = True) -> None:
    node.handle_command(make_message("follow", t_capture_s=time.monotonic(), grasp_id=grasp_id,
                                     target_width_m=width_m, enable=enable))


def command(node, action: str, grasp_id: str | None) -> None:
    node.handle_command(make_message("command", t_capture_s=time.monotonic(), action=action, grasp_id=grasp_id,
                                     params={}))


def go_live(node, grasp_id: str, width_m: float) -> None:
    """Start follow grasp ``grasp_id`` on the object prepared at connect, and step until it is live."""
    wait_prepared(node)
    follow(node, grasp_id, width_m)
    while node._grasp.phase == "preparing":
        node.step(timeout_s=0.002)
    assert node._grasp.phase == "following"


def preparing(node, grasp_id: str) -> tuple[Callable[[], None], float]:
    """Start follow grasp ``grasp_id`` (enabled, closing) and keep it preparing until the returned
    function is called (the object ready); and the fingers' open width (m)."""
    wait_prepared(node)
    number, prepared = node._next_live
    pending: Future = Future()
    node._follower.next_live = (number, pending)
    open_m = node.gripper.read_width()[1]
    follow(node, grasp_id, 0.0)
    return lambda: pending.set_result(prepared.result()), open_m


def notices(listener) -> list[dict]:
    return [m.body for m in drain(listener) if m.type == "robot_notice"]



def stale_follows_start_nothing(node, grasp_id: str, open_m: float) -> None:
    """Follows naming ``grasp_id``, which ended, the enable held: refused, and the fingers stay open."""
    for _ in range(5):
        follow(node, grasp_id, 0.0)
        step_for(node, 0.01)
    assert not node.busy and node.gripper.read_width()[1] == pytest.approx(open_m, abs=1e-4)

def test_follows_of_another_grasp_neither_feed_the_watchdog_nor_set_the_enable(rig):
    node, listener = rig
    go_live(node, "A1", 0.07)
    fed = node._follower.last_follow_s
    follow(node, "B1", 0.07, enable=False)
    assert node._follower.last_follow_s == fed and node._follower.enable is True
    # A goes silent while B keeps sending enabled follows: the watchdog still ends A's grasp.
    give_up = time.monotonic() + 3 * WATCHDOG_S
    while node.busy and time.monotonic() < give_up:
        follow(node, "B1", 0.0)
        step_for(node, 0.02)
    assert not node.busy
    got = notices(listener)
    assert ("refused", "B1") in [(n["event"], n["grasp_id"]) for n in got]
    assert "grasp 'A1' is in progress, not 'B1'" in [n["reason"] for n in got]
    assert [n["grasp_id"] for n in got if n["event"] == "watchdog"] == ["A1"]


def test_a_follow_refused_during_a_commanded_grasp_leaves_the_enable(rig):
    node, _ = rig
    command(node, "start_grasp", "S1")
    follow(node, "S1", 0.07)
    assert node._follower.enable is False and node._follower.last_follow_s == -float("inf")


def test_a_follow_naming_no_grasp_does_not_steer_the_grasp_in_progress(rig):
    node, listener = rig
    go_live(node, "A1", 0.07)
    fed = node._follower.last_follow_s
    follow(node, None, 0.005)
    assert node._grasp.target_width_m == 0.07 and node._follower.last_follow_s == fed
    assert [(n["grasp_id"], n["reason"]) for n in notices(listener)] == [
        ("A1", "grasp 'A1' is in progress: a follow must name it")]


def test_a_release_naming_another_grasp_is_refused_and_anyones_stop_wins(rig):
    node, listener = rig
    go_live(node, "X1", 0.07)
    command(node, "release", "Z9")
    assert node._grasp.phase == "following"
    assert [(n["action"], n["reason"]) for n in notices(listener)] == [
        ("release", "grasp 'X1' is in progress, not 'Z9'")]
    command(node, "stop", "Z9")
    assert node._grasp.phase == "stopped"
    command(node, "release", None)  # naming no grasp: the one in progress
    assert node._grasp.phase == "releasing"


def test_a_stop_while_the_grasp_prepares_keeps_it_from_going_live(rig):
    node, listener = rig
    ready, open_m = preparing(node, "G2")
    command(node, "stop", "G2")
    ready()
    for _ in range(5):  # follows go on: ignored, as after a stop while following
        follow(node, "G2", 0.0)
        step_for(node, 0.01)
    assert node._grasp.phase == "stopped" and node._mode() == "stopped"
    assert node.gripper.read_width()[1] == pytest.approx(open_m, abs=1e-4)
    command(node, "release", "G2")
    assert not node.busy and node._mode() == "idle"
    got = drain(listener)
    assert not [m for m in got if m.type == "grasp_event"]  # it never went live: no start, no end
    assert [(n["action"], n["reason"]) for n in (m.body for m in got if m.type == "robot_notice")] == [
        ("release", "follow grasp 'G2' had not started: cancelled, the fingers have nothing to open")]
    assert node._next_live[0] == node._count == 0  # its object untaken: the next grasp's


def test_a_release_while_the_grasp_prepares_cancels_it(rig):
    node, listener = rig
    ready, open_m = preparing(node, "H2")
    command(node, "release", "H2")
    assert not node.busy
    ready()
    step_for(node, 0.05)
    assert not node.busy and node.gripper.read_width()[1] == pytest.approx(open_m, abs=1e-4)
    got = drain(listener)
    assert not [m for m in got if m.type == "grasp_event"]
    assert "cancelled" in [m.body for m in got if m.type == "robot_notice"][0]["reason"]


def test_letting_go_of_the_enable_while_the_grasp_prepares_clears_its_target(rig):
    node, _ = rig
    ready, open_m = preparing(node, "J2")
    follow(node, "J2", 0.0, enable=False)
    assert node._grasp.target_width_m is None
    ready()
    while node._grasp.phase == "preparing":
        follow(node, "J2", 0.0, enable=False)
        node.step(timeout_s=0.002)
    for _ in range(5):  # live now: the stale target does not drive the fingers
        follow(node, "J2", 0.0, enable=False)
        step_for(node, 0.01)
    assert node._grasp.phase == "following" and node._grasp.target_width_m is None
    assert node.gripper.read_width()[1] == pytest.approx(open_m, abs=1e-4)


def test_a_grasp_the_watchdog_ended_while_it_prepared_is_not_started_again_by_its_stale_follows(rig):
    node, listener = rig
    ready, open_m = preparing(node, "W2")
    node._follower.last_follow_s -= 2 * WATCHDOG_S  # the operator silent (no wall clock waited)
    node.step(timeout_s=0.002)
    assert not node.busy
    ready()
    stale_follows_start_nothing(node, "W2", open_m)  # the console's, still in flight, the enable held
    got = drain(listener)
    assert not [m for m in got if m.type == "grasp_event"]
    said = [m.body for m in got if m.type == "robot_notice"]
    assert [(n["event"], n["grasp_id"]) for n in said] == [("watchdog", "W2"), ("refused", "W2")]
    assert "grasp 'W2' has ended: name a new grasp" in said[1]["reason"]


def test_a_grasp_the_gripper_failed_while_it_prepared_is_not_started_again_by_its_stale_follows(rig, monkeypatch):
    node, listener = rig
    ready, open_m = preparing(node, "G2")

    def link_down():
        raise DeviceError("franky: the gripper's link is down")

    monkeypatch.setattr(node.gripper, "read_width", link_down)  # going live reads the fingers' width
    ready()
    step_for(node, 0.05)
    assert not node.busy
    monkeypatch.undo()  # the link back: a follow still naming the failed grasp must not start it
    stale_follows_start_nothing(node, "G2", open_m)
    said = notices(listener)
    assert [(n["event"], n["grasp_id"]) for n in said] == [("device", "G2"), ("refused", "G2")]
    assert "grasp 'G2' has ended: name a new grasp" in said[1]["reason"]


def test_a_grasp_released_while_it_prepared_is_not_started_again_by_its_enabled_follows(rig):
    node, listener = rig
    ready, open_m = preparing(node, "R2")
    command(node, "release", "R2")
    ready()
    stale_follows_start_nothing(node, "R2", open_m)  # its console's, the enable still held
    got = drain(listener)
    assert not [m for m in got if m.type == "grasp_event"]
    said = [m.body for m in got if m.type == "robot_notice"]
    assert [(n["action"], n["grasp_id"]) for n in said] == [("release", "R2"), ("follow", "R2")]
    assert "grasp 'R2' has ended: name a new grasp" in said[1]["reason"]


def test_follows_naming_a_commanded_grasp_that_ended_do_not_start_it_again(rig, monkeypatch):
    node, listener = rig

    def cannot(*_):
        raise SimulationError("the object cannot be simulated")

    monkeypatch.setattr(node, "_simulate", cannot)  # the commanded grasp starts and ends at once
    command(node, "start_grasp", "D1")
    while node.busy:
        node.step(timeout_s=0.002)
    follow(node, "D1", 0.07)
    assert not node.busy
    got = drain(listener)
    assert [(m.body["event"], m.body["grasp_id"]) for m in got if m.type == "grasp_event"] == [
        ("start", "D1"), ("end", "D1")]
    said = [m.body for m in got if m.type == "robot_notice"]
    assert [(n["event"], n["action"], n["grasp_id"]) for n in said] == [("refused", "follow", "D1")]
    assert "grasp 'D1' has ended: name a new grasp" in said[0]["reason"]


def test_a_start_grasp_naming_a_follow_grasp_that_ended_is_refused(rig):
    node, listener = rig
    go_live(node, "grasp-0000", 0.07)  # the id a start_grasp without one would take first
    node._follower.last_follow_s -= 2 * WATCHDOG_S  # the operator silent: the watchdog ends it
    node.step(timeout_s=0.002)
    assert not node.busy
    drain(listener)
    command(node, "start_grasp", "grasp-0000")
    assert not node.busy
    said = [m.body for m in drain(listener) if m.type == "robot_notice"]
    assert [(n["event"], n["action"], n["grasp_id"]) for n in said] == [("refused", "start_grasp", "grasp-0000")]
    assert "grasp 'grasp-0000' has ended: name a new grasp" in said[0]["reason"]
    command(node, "start_grasp", None)  # nor does a grasp started without an id take the ended one's
    assert node._grasp.grasp_id == "grasp-0001"
