"""A ``start_grasp`` the robot refused is not left tracked as in progress: not when another notice
follows its refusal within one poll (the keyboard merges same-tick presses: ``g s``), nor when its
refusal never arrives (the link's view, then the loop against a fake link)."""

from __future__ import annotations

import dataclasses

from support.operator_fakes import (
    Clock,
    FakeLink,
    QueuedSubscriber,
    SubscribedPublisher,
    loop_rig,
    press,
)

from haptics.operator_link import OperatorLink, OperatorView
from haptics.operator_loop import OperatorLoop
from teleop.bus.messages import RobotNoticeBody, RobotStateBody
from teleop.bus.wire import make_message


def _notice(seq: int, action: str, grasp_id: str):
    message = make_message("robot_notice", t_capture_s=0.0, event="refused", action=action, grasp_id=grasp_id,
                           reason="grasp 'op-1' is still in progress")
    return dataclasses.replace(message, source="robot", topic="robot_notice", seq=seq)


def _link() -> tuple[OperatorLink, QueuedSubscriber]:
    clock = Clock()
    subscriber = QueuedSubscriber(clock)
    return OperatorLink(publisher=SubscribedPublisher(), subscriber=subscriber, clock=clock), subscriber


def test_the_link_keeps_every_refused_start_of_a_poll_not_only_the_newest_notice():
    link, subscriber = _link()
    subscriber.queue += [_notice(0, "start_grasp", "op-2"), _notice(1, "stop", "op-2")]
    link.poll()
    assert link.view.notice.action == "stop" and link.view.refused_starts == ("op-2",)
    subscriber.queue += [_notice(n, "start_grasp", f"op-{n}") for n in range(2, 60)]
    link.poll()
    assert len(link.view.refused_starts) == 32 and link.view.refused_starts[-1] == "op-59"  # bounded


def test_the_link_keeps_every_refused_follow_of_a_poll_apart_from_the_refused_starts():
    link, subscriber = _link()
    subscriber.queue += [_notice(0, "follow", "op-3"), _notice(1, "stop", "op-3")]
    link.poll()
    assert link.view.notice.action == "stop" and link.view.refused_follows == ("op-3",)
    assert link.view.refused_starts == ()


def _running(clock: Clock, link: FakeLink, loop: OperatorLoop) -> str:
    """A discrete grasp pressed and shown held by the robot."""
    running = press(loop, clock, "grasp")
    link.view = OperatorView(t_s=clock(), grasp_id=running, phase="loaded",
                             robot=RobotStateBody(mode="holding", grasp_id=running, enable=False))
    loop.step()
    return running


def _ended(clock: Clock, link: FakeLink, running: str, **view) -> None:
    link.view = dataclasses.replace(link.view, t_s=clock(), phase="ended",
                                    robot=RobotStateBody(mode="idle", enable=False), **view)


def test_a_start_refused_then_another_notice_in_the_same_poll_is_forgotten():
    clock, link, _, loop = loop_rig()
    running = _running(clock, link, loop)
    loop.press("grasp")
    loop.press("stop")  # g s in one tick: both refused, the stop's notice last
    loop.step()
    refused = next(body["grasp_id"] for _, kind, body in reversed(link.sent) if kind == "start_grasp")
    link.view = dataclasses.replace(link.view, notice=RobotNoticeBody(
        event="refused", action="stop", grasp_id=running, reason="a simulated discrete grasp ..."),
        refused_starts=(refused,))
    loop.step()
    assert loop.status.grasp_id == running
    _ended(clock, link, running, estimate=None)
    loop.step()
    assert loop.status.mode == "idle" and loop.status.grasp_id is None
    press(loop, clock, "next")
    assert link.cleared == 1 and "next refused" not in loop.status.last_action


def test_a_start_whose_refusal_never_came_goes_once_the_robot_has_moved_on():
    clock, link, _, loop = loop_rig()
    running = _running(clock, link, loop)
    lost = press(loop, clock, "grasp")  # refused, its notice lost
    assert loop.status.grasp_id == lost
    clock.t += 0.5
    loop.step()  # the robot's state still names the running one: too soon to tell
    assert loop.status.grasp_id == lost
    _ended(clock, link, running)
    clock.t += 2.0
    loop.step()
    assert loop.status.mode == "idle" and loop.status.grasp_id is None
    press(loop, clock, "next")
    assert link.cleared == 1


def test_a_grasp_the_robot_prepares_stays_tracked():
    # Named in the robot's state before any grasp event (the simulation takes a while): in progress.
    clock, link, _, loop = loop_rig()
    preparing = press(loop, clock, "grasp")
    link.view = OperatorView(t_s=clock(), robot=RobotStateBody(mode="grasping", grasp_id=preparing, enable=False))
    clock.t += 5.0
    loop.step()
    assert loop.status.grasp_id == preparing and loop.status.mode == "discrete"
