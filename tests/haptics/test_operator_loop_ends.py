"""The operator's loop when the robot ends its follow grasp, and what it says of the enable
(against a fake link and device; the rest of the loop: test_operator_link.py)."""

from __future__ import annotations

from support.operator_fakes import (
    Clock,
    loop_rig,
)

from haptics.operator_link import OperatorView
from haptics.operator_loop import NEXT_WAIT_S, OperatorLoop
from teleop.bus.messages import RobotNoticeBody


def _run(clock: Clock, loop: OperatorLoop, seconds: float) -> None:
    end = clock.t + seconds
    while clock.t < end - 1e-9:
        loop.step()
        clock.t += 0.001


def test_the_watchdogs_notice_ends_the_follow_grasp_it_names():
    # The watchdog ended the grasp before its start was announced (the node was preparing the
    # object): no grasp_event end comes, only the notice. The console must not go on driving it.
    clock, link, device, loop = loop_rig(grip=0.5)
    device.enable = True
    _run(clock, loop, 0.1)
    grasp_id = link.sent[-1][2]["grasp_id"]
    watchdog = RobotNoticeBody(event="watchdog", action="follow", grasp_id=grasp_id,
                               reason="no follow command for 0.210 s (watchdog 0.2 s): the fingers stopped")
    link.view = OperatorView(t_s=clock(), notice=watchdog, notice_t_s=clock(), ended_by=watchdog,
                             ended_by_t_s=clock())
    _run(clock, loop, 0.05)
    sent = len(link.sent)
    _run(clock, loop, 0.5)
    assert link.sent[sent:] == [] and loop.status.grasp_id is None
    assert loop.status.suspended and loop.status.held and not loop.status.enable
    device.enable = False  # let go (the console turns a keyboard's toggle off) and hold again: a new grasp
    _run(clock, loop, 0.05)
    assert not loop.status.suspended and not loop.status.held
    device.enable = True
    _run(clock, loop, 0.05)
    kind, body = link.sent[-1][1:]
    assert kind == "follow" and body["enable"] and body["grasp_id"] not in (grasp_id, None)


def test_an_enable_held_while_the_last_grasp_ends_shows_and_drives_once_it_is_over():
    # After next, the loop waits up to NEXT_WAIT_S for the grasp left to end. The device is read
    # meanwhile: the status shows the enable and grip as they are (the keys do not pile up unseen),
    # and the enable drives once that grasp is over, not before.
    clock, link, device, loop = loop_rig(grip=0.5)
    link.view = OperatorView(t_s=clock(), grasp_id="g-left", phase="loading")  # it never ends: say its node died
    device.buttons = {"next"}
    _run(clock, loop, 0.05)
    device.enable, device.grip = True, 0.8  # the operator takes the next object at once
    _run(clock, loop, 1.0)
    assert loop.status.held and loop.status.grip == 0.8 and link.cleared == 0
    assert loop.status.last_action == "enable held: the next grasp starts once the last one has ended"
    assert not [body for _, kind, body in link.sent if kind == "follow" and body["enable"]]
    _run(clock, loop, NEXT_WAIT_S)
    assert link.cleared == 1 and [body for _, kind, body in link.sent if kind == "follow" and body["enable"]]


def _held_anew_drives_a_new_grasp(clock: Clock, loop: OperatorLoop, device, link, ended: str) -> dict:
    """Let go of the enable and hold it again: the follow it sends names a new grasp, not ``ended``."""
    device.enable = False
    _run(clock, loop, 0.05)
    device.enable = True
    _run(clock, loop, 0.05)
    kind, body = link.sent[-1][1:]
    assert kind == "follow" and body["enable"] and body["grasp_id"] not in (ended, None)
    return body


def _held_follow(clock: Clock, loop: OperatorLoop, device, link) -> str:
    device.enable = True
    _run(clock, loop, 0.1)
    return link.sent[-1][2]["grasp_id"]


def test_a_follow_refused_for_a_grasp_the_robot_does_not_run_ends_it_on_the_console():
    # The watchdog ended the grasp while it was prepared and its notice was lost (a slow joiner, a
    # dropped message): the robot refuses each follow naming it. A device notice came after the
    # refusal in the same poll. The console must not drive that id for good: held anew, a new grasp.
    clock, link, device, loop = loop_rig(grip=0.5)
    grasp_id = _held_follow(clock, loop, device, link)
    device_notice = RobotNoticeBody(event="device", action="load_cell", grasp_id=None, reason="read again")
    link.view = OperatorView(t_s=clock(), notice=device_notice, notice_t_s=clock(), refused_follows=(grasp_id,))
    _run(clock, loop, 0.05)
    sent = len(link.sent)
    _run(clock, loop, 0.5)
    assert link.sent[sent:] == [] and loop.status.grasp_id is None and loop.status.suspended
    assert f"follow {grasp_id} refused by the robot" in loop.status.log
    body = _held_anew_drives_a_new_grasp(clock, loop, device, link, grasp_id)
    again = body["grasp_id"]  # refused too (this time the refusal is the newest notice): it says why
    refusal = RobotNoticeBody(event="refused", action="follow", grasp_id=again,
                              reason=f"grasp {again!r} has ended: name a new grasp to start one")
    link.view = OperatorView(t_s=clock(), notice=refusal, notice_t_s=clock(), refused_follows=(grasp_id, again))
    _run(clock, loop, 0.05)
    assert f"follow {again} refused by the robot: {refusal.reason}" in loop.status.log


def test_a_refused_follow_of_the_grasp_the_robot_runs_keeps_it():
    # With hardware, a silent load cell refuses closing follows during the grasp: it goes on.
    clock, link, device, loop = loop_rig(grip=0.5)
    grasp_id = _held_follow(clock, loop, device, link)
    silent = RobotNoticeBody(event="refused", action="follow", grasp_id=grasp_id,
                             reason="the load cell has sent no force for over 0.1 s: ...")
    link.view = OperatorView(t_s=clock(), grasp_id=grasp_id, phase="loading", notice=silent, notice_t_s=clock(),
                             refused_follows=(grasp_id,))
    sent = len(link.sent)
    _run(clock, loop, 0.1)
    follows = [body for _, kind, body in link.sent[sent:] if kind == "follow"]
    assert follows and all(b["enable"] and b["grasp_id"] == grasp_id for b in follows)
    assert loop.status.grasp_id == grasp_id and not loop.status.suspended


def test_a_follow_grasp_released_while_the_robot_prepared_it_is_forgotten():
    # No start came (the robot prepares the object), so no end will: the robot cancels it and never
    # starts it again. Let go and held again, the enable starts a new grasp at once.
    clock, link, device, loop = loop_rig(grip=0.5)
    grasp_id = _held_follow(clock, loop, device, link)
    device.buttons = {"release"}
    _run(clock, loop, 0.05)
    device.buttons = set()
    assert ("release", {"grasp_id": grasp_id}) in [(kind, body) for _, kind, body in link.sent]
    _held_anew_drives_a_new_grasp(clock, loop, device, link, grasp_id)
