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
