"""A robot node killed and started again faster than its liveness can tell (within three heartbeats): the
link hears the restart in its messages' sequence and the loop treats it as the node going down (its grasp
forgotten, follows suspended until the enable is held anew)."""

from __future__ import annotations

import dataclasses

import numpy as np
from support.operator_fakes import (
    Clock,
    FakeDevice,
    FakeLink,
    QueuedSubscriber,
    SubscribedPublisher,
)

from haptics.operator_link import OperatorLink, OperatorView, Peer
from haptics.operator_loop import OperatorLoop
from teleop.bus.wire import make_message
from teleop.settings import load_settings


def _state(seq: int, grasp_id: str | None, mode: str = "following", topic: str = "robot_state"):
    message = make_message("robot_state", t_capture_s=0.0, mode=mode, grasp_id=grasp_id, target_width_m=0.06,
                           enable=True)
    return dataclasses.replace(message, source="robot", topic=topic, seq=seq)


def test_the_link_hears_a_robot_node_started_again_by_its_falling_sequence():
    clock = Clock()
    subscriber = QueuedSubscriber(clock)
    link = OperatorLink(publisher=SubscribedPublisher(), subscriber=subscriber, clock=clock)
    for seq in range(10):  # the first node: a robot_state with every heartbeat
        subscriber.queue.append(_state(seq, "op-1"))
        link.poll()
        clock.t += 0.5
    assert link.view.robot_restarts == 0 and link.view.robot.grasp_id == "op-1"
    width = make_message("width", t_capture_s=0.0, grasp_id=None, t_s=np.array([0.0]), value_m=np.array([0.02]))
    subscriber.queue.append(dataclasses.replace(width, source="robot", topic="width", seq=500))
    link.poll()
    # Killed and started again within a heartbeat: never seen down, but it counts from 0 again.
    clock.t += 0.3
    subscriber.queue.append(_state(0, None, mode="idle"))
    link.poll()
    assert link.view.alive("robot node") and link.view.robot_restarts == 1
    assert link.view.width_m is None and link.view.robot.mode == "idle"  # the old node's width is gone
    # The new node's other topics, and its next states, are not further restarts.
    subscriber.queue += [dataclasses.replace(width, source="robot", topic="width", seq=0), _state(1, None, "idle")]
    link.poll()
    assert link.view.robot_restarts == 1 and link.view.width_m == 0.02
    # Others' sequences are not the robot's; handle() (tests, replays) checks none.
    subscriber.queue.append(dataclasses.replace(_state(0, None), source="estimator"))
    link.poll()
    link.handle(_state(0, None))
    link.poll()
    assert link.view.robot_restarts == 1


def test_a_robot_node_restarted_after_its_first_state_is_heard_at_the_same_sequence():
    # Killed right after its first robot_state, the new node numbers from 0 again: its seq did not fall.
    clock = Clock()
    subscriber = QueuedSubscriber(clock)
    link = OperatorLink(publisher=SubscribedPublisher(), subscriber=subscriber, clock=clock)
    subscriber.queue.append(_state(0, "op-1"))
    link.poll()
    assert link.view.robot_restarts == 0
    subscriber.queue.append(_state(0, None, mode="idle"))
    link.poll()
    assert link.view.robot_restarts == 1 and link.view.robot.mode == "idle"


def _run(clock: Clock, loop: OperatorLoop, seconds: float) -> None:
    end = clock.t + seconds
    while clock.t < end - 1e-9:
        loop.step()
        clock.t += 0.001


def _robot(clock: Clock, restarts: int = 0, **view) -> OperatorView:
    return OperatorView(t_s=clock(), peers=(Peer("robot node", "robot", True, 0.1),), robot_restarts=restarts,
                        **view)


def _driving(clock: Clock) -> tuple[FakeLink, FakeDevice, OperatorLoop]:
    """A console whose enable is held half-squeezed, driving a live robot node for 0.1 s."""
    link, device = FakeLink(clock), FakeDevice(clock)
    loop = OperatorLoop(link, device, load_settings(), clock=clock)
    loop.step()  # the enable read let go once: the loop starts armed off
    device.grip, device.enable = 0.5, True
    link.view = _robot(clock)
    _run(clock, loop, 0.1)
    return link, device, loop


def test_a_robot_node_restarted_within_three_heartbeats_is_not_driven_by_the_held_enable():
    # Killed mid-grasp and started again at once: never seen down. The held enable must not drive the
    # new node, and not under the old grasp's id.
    clock = Clock()
    link, device, loop = _driving(clock)
    lost = link.sent[-1][2]["grasp_id"]
    link.view = _robot(clock, grasp_id=lost, phase="loading")
    _run(clock, loop, 0.1)
    link.view = _robot(clock, restarts=1, grasp_id=lost, phase="loading")  # the new node heard: still alive
    loop.step()
    clock.t += 0.001
    assert f"the robot node restarted: grasp {lost} is lost" in loop.status.log and link.cleared == 1
    assert loop.status.grasp_id is None and "suspended" in loop.status.mode
    link.view = _robot(clock, restarts=1)
    sent = len(link.sent)
    _run(clock, loop, 0.5)
    follows = [body for _, kind, body in link.sent[sent:] if kind == "follow"]
    # Let go under the lost grasp's id (a node that took it refuses follows naming none), then nothing.
    assert follows and not any(body["enable"] or body["grasp_id"] != lost for body in follows)
    device.enable = False
    _run(clock, loop, 0.05)
    device.enable = True
    _run(clock, loop, 0.05)
    assert link.sent[-1][2]["enable"] and link.sent[-1][2]["grasp_id"] not in (lost, None)
    assert loop.status.mode == "follow"  # one restart is handled once


def test_a_restart_heard_after_the_node_was_seen_down_is_not_lost_twice():
    # Seen down (three heartbeats), then the new node's first message shows its restart too: one loss.
    # The enable held anew while it was down drives nothing; held anew once the node is heard, it drives.
    clock = Clock()
    link, device, loop = _driving(clock)
    link.view = dataclasses.replace(_robot(clock), peers=(Peer("robot node", "robot", False, 2.0),))
    _run(clock, loop, 0.1)
    assert "suspended" in loop.status.mode
    device.enable = False
    _run(clock, loop, 0.05)
    device.enable = True
    _run(clock, loop, 0.05)
    link.view = _robot(clock, restarts=1)
    sent = len(link.sent)
    _run(clock, loop, 0.1)
    assert "suspended" in loop.status.mode and not any(body["enable"] for _, _, body in link.sent[sent:])
    assert not any("restarted" in line for line in loop.status.log)
    device.enable = False
    _run(clock, loop, 0.05)
    device.enable = True
    _run(clock, loop, 0.05)
    assert loop.status.mode == "follow" and link.sent[-1][2]["enable"] and link.sent[-1][2]["grasp_id"]
