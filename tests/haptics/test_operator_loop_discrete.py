"""The operator's loop with a discrete grasp in progress on quit and next, and next with the estimator
down (against a fake link and device; the rest of the loop: test_operator_link.py)."""

from __future__ import annotations

import dataclasses
import math
from datetime import datetime

import pytest
from support.operator_fakes import (
    Clock,
    FakeLink,
    loop_rig,
    press,
)

from haptics.operator_link import OperatorView, Peer
from haptics.operator_loop import OperatorLoop
from teleop.bus.messages import RobotNoticeBody, RobotStateBody

ESTIMATOR_DOWN = (Peer("robot node", "robot", True, 0.1), Peer("estimator", "estimator", False, 4.0))


def _discrete_grasp_loaded(robot_mode: str) -> tuple[Clock, FakeLink, OperatorLoop, str]:
    """A discrete grasp pressed and shown loaded, the robot in ``robot_mode``."""
    clock, link, _, loop = loop_rig(grip=0.5)
    press(loop, clock, "grasp")
    grasp_id = loop.status.grasp_id
    link.view = OperatorView(t_s=clock(), grasp_id=grasp_id, phase="loaded",
                             robot=RobotStateBody(mode=robot_mode, grasp_id=grasp_id, enable=False))
    return clock, link, loop, grasp_id


def test_quit_releases_a_discrete_grasp_in_progress():
    clock, link, loop, grasp_id = _discrete_grasp_loaded("holding")
    loop.step()
    press(loop, clock, "quit")
    loop.finish()
    assert link.sent[-1][1:] == ("release", {"grasp_id": grasp_id})
    assert loop.status.last_action == f"release {grasp_id}: the console quits" and loop.status.grasp_id is None


def test_quit_sends_no_second_release_for_a_discrete_grasp_the_robot_already_releases():
    clock, link, loop, _ = _discrete_grasp_loaded("releasing")
    press(loop, clock, "quit")
    loop.finish()
    assert "release" not in link.kinds()


def test_next_during_a_discrete_grasp_not_shown_yet_is_refused_and_clears_nothing():
    clock, link, device, loop = loop_rig(grip=0.5)
    press(loop, clock, "grasp")
    grasp_id = loop.status.grasp_id
    # The robot is still preparing it: the view shows nothing yet (or the last grasp, over).
    for view in (OperatorView(t_s=clock()), OperatorView(t_s=clock(), grasp_id="op-old", phase="ended")):
        link.view = view
        sent = len(link.sent)
        press(loop, clock, "next")
        assert link.cleared == 0 and link.sent[sent:] == []
        assert loop.status.grasp_id == grasp_id and loop.status.mode == "discrete"
        assert loop.status.last_action.startswith(f"next refused: grasp {grasp_id} is in progress")
        assert "release it (r)" in loop.status.last_action
    # Shown, next releases it and waits for its end (test_operator_link.py); once it has ended, clears the view.
    link.view = OperatorView(t_s=clock(), grasp_id=grasp_id, phase="ended")
    loop.step()
    press(loop, clock, "next")
    assert link.cleared == 1 and loop.status.grasp_id is None


def test_next_with_the_estimator_down_does_not_wait_for_a_final_and_says_so():
    clock, link, device, loop = loop_rig(grip=0.5)
    device.enable = True
    for _ in range(30):
        loop.step()
        clock.t += 0.002
    grasp_id = loop.status.grasp_id
    device.enable = False
    link.view = OperatorView(t_s=clock(), peers=ESTIMATOR_DOWN, grasp_id=grasp_id, phase="loading")
    loop.step()
    press(loop, clock, "next")
    assert "release" in link.kinds() and link.cleared == 0
    assert "final estimate is in" not in loop.status.last_action
    assert "the estimator is down: no final estimate will come" in loop.status.last_action
    # The robot ends the grasp: shown ended once, then cleared (no final awaited), and the keys are taken again.
    link.view = OperatorView(t_s=clock(), peers=ESTIMATOR_DOWN, grasp_id=grasp_id, phase="ended")
    assert loop.step().view.phase == "ended" and link.cleared == 0
    loop.step()
    assert link.cleared == 1
    assert loop.status.last_action == (f"next object: ready ({grasp_id}'s final estimate did not come: "
                                       "the estimator is down)")
    device.buttons = {"grasp"}
    loop.step()
    assert link.kinds()[-1] == "start_grasp"


def _refuse_start(link: FakeLink, clock: Clock, grasp_id: str, running: str) -> None:
    link.view = dataclasses.replace(link.view, notice=RobotNoticeBody(
        event="refused", action="start_grasp", grasp_id=grasp_id, reason=f"grasp {running!r} is still in progress"),
        notice_t_s=clock(), refused_starts=(*link.view.refused_starts, grasp_id))


def test_a_second_grasp_the_robot_refuses_leaves_the_running_one_tracked_and_quit_releases_it():
    clock, link, loop, running = _discrete_grasp_loaded("holding")
    loop.step()
    press(loop, clock, "grasp")
    refused = link.sent[-1][2]["grasp_id"]
    assert link.kinds()[-1] == "start_grasp" and refused != running
    _refuse_start(link, clock, refused, running)
    loop.step()
    assert loop.status.mode == "discrete" and loop.status.grasp_id == running
    press(loop, clock, "quit")
    loop.finish()
    assert link.sent[-1][1:] == ("release", {"grasp_id": running})
    assert loop.status.last_action == f"release {running}: the console quits" and loop.status.mode == "idle"


def test_quit_before_the_robot_answers_a_second_grasp_releases_the_running_one_too():
    clock, link, loop, running = _discrete_grasp_loaded("holding")
    loop.step()
    press(loop, clock, "grasp")
    pending = link.sent[-1][2]["grasp_id"]
    press(loop, clock, "quit")
    loop.finish()
    assert [body["grasp_id"] for _, kind, body in link.sent if kind == "release"] == [running, pending]


def test_a_grasp_the_robot_starts_after_another_leaves_only_it_to_release():
    clock, link, loop, first = _discrete_grasp_loaded("holding")
    loop.step()
    press(loop, clock, "grasp")  # the first one's end went unseen: the robot starts the second
    second = link.sent[-1][2]["grasp_id"]
    link.view = OperatorView(t_s=clock(), grasp_id=second, phase="loading",
                             robot=RobotStateBody(mode="grasping", grasp_id=second, enable=False))
    loop.step()
    _refuse_start(link, clock, "op-other", second)  # a refusal of another grasp changes nothing
    loop.step()
    press(loop, clock, "quit")
    loop.finish()
    assert [body["grasp_id"] for _, kind, body in link.sent if kind == "release"] == [second]


def test_a_discrete_grasp_is_forgotten_when_the_robot_node_goes_down():
    # As a follow grasp is (test_operator_link.py): a node started again does not run it, so quit must
    # not release it by name (nor next wait on it).
    clock, link, loop, grasp_id = _discrete_grasp_loaded("holding")
    link.view = dataclasses.replace(link.view, peers=(Peer("robot node", "robot", True, 0.1),))
    loop.step()
    assert loop.status.grasp_id == grasp_id and loop.status.mode == "discrete"
    link.view = dataclasses.replace(link.view, peers=(Peer("robot node", "robot", False, 4.0),))
    loop.step()
    assert f"the robot node is down: grasp {grasp_id} is lost" in loop.status.log
    assert loop.status.grasp_id is None and loop.status.mode == "idle"
    loop.finish()
    assert "release" not in link.kinds()


def test_set_force_keeps_the_discrete_force_between_one_newton_and_the_settings_maximum():
    # The console's +/- keys step it: held down, they must not run past either end.
    clock, link, _, loop = loop_rig()
    limit = loop.settings.gripper.target_force_n
    assert loop.set_force(limit + 5.0) == loop.force_n == limit
    press(loop, clock, "grasp")
    assert link.sent[-1][1:] == ("start_grasp", {"target_force_n": limit, "grasp_id": loop.status.grasp_id})
    assert loop.set_force(-3.0) == loop.force_n == min(1.0, limit)


@pytest.mark.parametrize("force_n", [math.nan, math.inf])
def test_set_force_refuses_a_force_that_is_not_finite_and_keeps_the_one_set(force_n):
    _, _, _, loop = loop_rig()
    before = loop.force_n
    with pytest.raises(ValueError, match=r"force_n = (nan|inf): expected a finite force"):
        loop.set_force(force_n)
    assert loop.force_n == before


def test_a_grasp_id_names_the_day_so_a_console_started_at_the_same_time_tomorrow_is_not_refused():
    clock, _, _, loop = loop_rig(grip=0.5)
    before = datetime.now()
    press(loop, clock, "grasp")
    after = datetime.now()
    stamp = loop.status.grasp_id.split("-")[1]
    assert stamp in {before.strftime("%m%d"), after.strftime("%m%d")}
