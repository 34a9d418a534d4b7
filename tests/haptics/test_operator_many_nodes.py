"""More than one robot node subscribed to the operator's commands (a second node on another
``bus.robot_pub``): the link counts only robot nodes and refuses to drive, the loop suspends a held
enable and says why, the console shows it."""

from __future__ import annotations

import dataclasses
import time

import pytest
from support.operator_fakes import NOBODY, Clock, loop_rig

from estimator.service import COMMAND_TOPICS as ESTIMATOR_COMMAND_TOPICS
from haptics.console import _peer_line
from haptics.operator_link import OperatorLink, OperatorView, Peer
from haptics.operator_loop import OperatorLoop
from teleop.bus.pubsub import Subscriber
from teleop.errors import BusError
from teleop.node import COMMAND_TOPICS
from teleop.settings import load_settings


def _until(predicate, what: str, timeout_s: float = 5.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not predicate():
        assert time.monotonic() < deadline, what
        time.sleep(0.01)


def test_the_link_counts_robot_nodes_only_and_refuses_to_drive_more_than_one():
    bus = dataclasses.replace(load_settings().bus, command="tcp://127.0.0.1:*")
    with OperatorLink.from_settings(bus) as link:
        endpoint = link.publisher.endpoint
        with (
            Subscriber(endpoint, COMMAND_TOPICS) as node,
            Subscriber(endpoint, ("",)),  # the session recorder
            Subscriber(endpoint, ESTIMATOR_COMMAND_TOPICS),  # the estimator service
        ):
            _until(lambda: link.robot_subscribed() and link.publisher.subscriptions("")
                   and link.publisher.subscriptions("load_model"), "the subscriptions never arrived")
            link.start_grasp(target_force_n=10.0, grasp_id="g1")
            with Subscriber(endpoint, COMMAND_TOPICS):  # a second node, on another robot_pub
                _until(lambda: link.publisher.subscriptions("follow") == 2, "the second node never subscribed")
                with pytest.raises(BusError, match="2 robot nodes subscribe to the commands: stop all but one"):
                    link.start_grasp(target_force_n=10.0, grasp_id="g2")
                with pytest.raises(BusError, match="2 robot nodes subscribe"):
                    link.follow(0.05, enable=True, grasp_id="g2")
                link.follow(0.05, enable=False, grasp_id="g1")  # what stops the fingers still goes
                link.release("g1")
                assert link.robot_nodes() == 2
            _until(lambda: link.robot_nodes() == 1, "the second node's subscription never ended")
            with Subscriber(endpoint, ("",)), Subscriber(endpoint, ESTIMATOR_COMMAND_TOPICS):  # more of each
                _until(lambda: link.publisher.subscriptions("") == link.publisher.subscriptions("load_model") == 2,
                       "the second recorder or estimator never subscribed")
                assert link.robot_nodes() == 1  # the recorders and the estimators are no robot nodes
            link.start_grasp(target_force_n=10.0, grasp_id="g3")
            got = [node.recv(timeout_s=2.0) for _ in range(4)]
            assert [(m.type, m.body["grasp_id"]) for m in got] == [
                ("command", "g1"), ("follow", "g1"), ("command", "g1"), ("command", "g3")]


def _view(clock: Clock, nodes: int) -> OperatorView:
    return OperatorView(t_s=clock(), peers=(Peer("robot node", "robot", True, 0.1, True, nodes),))


def _run(clock: Clock, loop: OperatorLoop, seconds: float) -> None:
    end = clock.t + seconds
    while clock.t < end - 1e-9:
        loop.step()
        clock.t += 0.001


def test_a_second_robot_node_suspends_a_held_enable_until_it_is_gone_and_the_enable_held_anew():
    clock, link, device, loop = loop_rig()
    link.view = _view(clock, 1)
    device.enable, device.grip = True, 0.5
    _run(clock, loop, 0.1)
    assert loop.status.mode == "follow"
    link.view = _view(clock, 2)
    _run(clock, loop, 0.1)
    sent = len(link.sent)
    _run(clock, loop, 0.2)
    assert not any(body.get("enable") for _, _, body in link.sent[sent:])
    assert "suspended" in loop.status.mode and "more than one robot node hears the console" in loop.status.log
    assert loop.status.problem.startswith("driving refused: 2 robot nodes subscribe to the commands")
    device.enable = False  # let go and held again while the second node still runs: still refused
    _run(clock, loop, 0.05)
    device.enable = True
    _run(clock, loop, 0.05)
    assert "suspended" in loop.status.mode
    assert any("enable held while more than one robot node subscribes" in line for line in loop.status.log)
    link.view = _view(clock, 1)  # the second one went: the held enable does not drive by itself
    sent = len(link.sent)
    _run(clock, loop, 0.2)
    assert not any(body.get("enable") for _, _, body in link.sent[sent:])
    assert loop.status.problem == "" and "no more than one robot node subscribes to the commands now" in loop.status.log
    device.enable = False
    _run(clock, loop, 0.05)
    device.enable = True
    _run(clock, loop, 0.05)
    assert loop.status.mode == "follow" and link.sent[-1][2]["enable"]


def test_the_console_shows_more_than_one_robot_node():
    line = _peer_line(Peer("robot node", "robot", True, 0.1, True, 3))
    assert line.startswith("MANY") and "3 robot nodes subscribe" in line
    assert _peer_line(Peer("robot node", "robot", True, 0.1, True, 1)).startswith("UP")


def test_a_device_waiting_for_the_robot_node_says_so_again_when_a_second_node_is_seen():
    # The headless simulated operator: its one status line said only "waiting", though the node was heard.
    clock, link, device, loop = loop_rig()
    device.waits_for_robot = True
    link.view = OperatorView(t_s=clock(), peers=NOBODY)  # no node heard yet
    _run(clock, loop, 0.05)
    link.view = _view(clock, 2)  # heard, and a second one: waits on, now for that one to go
    _run(clock, loop, 0.05)
    waits = [line for line in loop.status.log if "waiting for the robot node" in line]
    assert len(waits) == 2 and not waits[0].endswith("alone") and waits[1].endswith("heard alone"), waits
