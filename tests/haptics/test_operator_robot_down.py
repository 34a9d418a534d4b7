"""The operator's loop with its enable turned on while the robot node is down or not subscribed, and the
bus problem that leaves behind (against a fake link and device; the node lost mid-grasp:
test_operator_restart.py and test_operator_link.py)."""

from __future__ import annotations

import pytest
from support.operator_fakes import (
    Clock,
    loop_rig,
)

from haptics.operator_link import OperatorView, Peer
from haptics.operator_loop import OperatorLoop
from teleop.errors import BusError

NOT_SUBSCRIBED = "the robot node has not subscribed to tcp://127.0.0.1:5 yet (it is down, or still connecting)"


def _run(clock: Clock, loop: OperatorLoop, seconds: float) -> None:
    end = clock.t + seconds
    while clock.t < end - 1e-9:
        loop.step()
        clock.t += 0.001


def _node(clock: Clock, alive: bool, subscribed: bool | None, seen_ago_s: float | None = 0.1) -> OperatorView:
    return OperatorView(t_s=clock(), peers=(Peer("robot node", "robot", alive, seen_ago_s, subscribed),))


@pytest.mark.parametrize("alive, subscribed, seen_ago_s", [(False, None, None), (False, None, 4.0),
                                                           (True, False, 0.1)],
                         ids=["never heard", "heard dead", "heard, not subscribed"])
def test_an_enable_held_while_the_robot_node_is_down_never_drives_it_when_it_comes_up(alive, subscribed,
                                                                                      seen_ago_s):
    # The keyboard's e and a squeeze while the node is down: when it starts, nothing moves it until the
    # enable has been let go and held again.
    clock, link, device, loop = loop_rig()
    link.view = _node(clock, alive, subscribed, seen_ago_s)
    device.enable, device.grip = True, 0.9
    _run(clock, loop, 0.2)
    assert "suspended" in loop.status.mode and loop.status.grasp_id is None
    assert any("enable held while the robot node is down or not subscribed" in line for line in loop.status.log)
    link.view = _node(clock, True, True)  # the node is heard, its subscription open
    _run(clock, loop, 0.5)
    assert not any(body["enable"] for _, kind, body in link.sent if kind == "follow")
    assert "suspended" in loop.status.mode
    device.enable = False
    _run(clock, loop, 0.05)
    device.enable = True
    _run(clock, loop, 0.05)
    assert loop.status.mode == "follow" and link.sent[-1][2]["enable"] and link.sent[-1][2]["grasp_id"]


def test_a_bus_problem_goes_once_the_robot_node_is_subscribed_again():
    clock, link, device, loop = loop_rig()
    link.view = _node(clock, False, False, 4.0)

    def refused(**kwargs):
        raise BusError(NOT_SUBSCRIBED)

    link.start_grasp = refused
    loop.press("grasp")
    loop.step()
    assert loop.status.problem.startswith("not sent (bus): the robot node has not subscribed")
    clock.t += 1.0
    loop.step()
    assert loop.status.problem  # still so
    link.view = _node(clock, True, True)  # started again: nothing sent since
    loop.step()
    assert loop.status.problem == "" and loop.status.log[-1].startswith("not sent (bus)")  # the log keeps it


def test_a_held_enable_is_suspended_when_the_robot_node_stops_hearing_the_console():
    # Killed: its subscription goes at once, its liveness only after three heartbeats. Started again
    # meanwhile, it must not take the held enable's follows.
    clock, link, device, loop = loop_rig()
    link.view = _node(clock, True, True)
    device.enable, device.grip = True, 0.5
    _run(clock, loop, 0.1)
    assert loop.status.mode == "follow"
    link.view = _node(clock, True, False)
    _run(clock, loop, 0.1)
    assert "suspended" in loop.status.mode and "the robot node no longer hears the console" in loop.status.log
    link.view = _node(clock, True, True)
    sent = len(link.sent)
    _run(clock, loop, 0.3)
    assert not any(body["enable"] for _, _, body in link.sent[sent:])
