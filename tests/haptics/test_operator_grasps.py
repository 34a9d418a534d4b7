"""What the operator's loop knows of grasps from the robot's side (:mod:`haptics.operator_grasps`): which
grasp the robot releases, the grasp a release names while a second one waits for the robot's answer, and
the grasp the status shows meanwhile (against a fake link and device on a fake clock)."""

from __future__ import annotations

from support.operator_fakes import Clock, FakeLink, loop_rig, press

from haptics.operator_grasps import releasing, running
from haptics.operator_link import OperatorView
from haptics.operator_loop import OperatorLoop
from teleop.bus.messages import RobotStateBody


def _run(clock: Clock, loop: OperatorLoop, seconds: float, tick_s: float = 0.001) -> None:
    end = clock.t + seconds
    while clock.t < end - 1e-9:
        loop.step()
        clock.t += tick_s


def _held_by_the_robot() -> tuple[Clock, FakeLink, OperatorLoop, str]:
    """A discrete grasp pressed, shown loaded and held by the robot."""
    clock, link, _, loop = loop_rig()
    press(loop, clock, "grasp")
    held = link.sent[-1][2]["grasp_id"]
    link.view = OperatorView(t_s=clock(), grasp_id=held, phase="loaded",
                             robot=RobotStateBody(mode="holding", grasp_id=held, enable=False))
    loop.step()
    return clock, link, loop, held


def _released(link: FakeLink, since: int = 0) -> list[str | None]:
    return [body["grasp_id"] for _, kind, body in link.sent[since:] if kind == "release"]


def test_releasing_is_about_the_grasp_named():
    robot = RobotStateBody(mode="releasing", grasp_id="op-1", target_width_m=None, enable=False)
    assert releasing(robot, "op-1")
    assert not releasing(robot, "op-2")
    assert not releasing(None, "op-1")
    assert not releasing(RobotStateBody(mode="holding", grasp_id="op-1", enable=False), "op-1")


def test_the_grasp_running_is_the_one_the_robots_state_names_else_the_one_shown_under_way():
    holding = RobotStateBody(mode="holding", grasp_id="op-1", enable=False)
    idle = RobotStateBody(mode="idle", enable=False)
    assert running(OperatorView(t_s=0.0, robot=holding)) == "op-1"  # taken, its start not shown yet
    assert running(OperatorView(t_s=0.0, grasp_id="op-2", phase="loaded", robot=holding)) == "op-1"
    for phase in ("loading", "loaded"):
        assert running(OperatorView(t_s=0.0, grasp_id="op-2", phase=phase)) == "op-2"
        assert running(OperatorView(t_s=0.0, grasp_id="op-2", phase=phase, robot=idle)) == "op-2"
    assert running(OperatorView(t_s=0.0, grasp_id="op-2", phase="ended", robot=idle)) is None
    assert running(OperatorView(t_s=0.0)) is None


def test_quit_releases_the_follow_grasp_even_while_the_robot_releases_another_one():
    clock, link, device, loop = loop_rig(grip=0.5)
    device.enable = True
    _run(clock, loop, 0.1)
    grasp_id = link.sent[-1][2]["grasp_id"]
    # The robot's state names another grasp it opens the fingers of (not ours): ours must still be released.
    link.view = OperatorView(t_s=clock(), grasp_id=grasp_id, phase="loading",
                             robot=RobotStateBody(mode="releasing", grasp_id="op-other", target_width_m=None,
                                                  enable=False))
    sent = len(link.sent)
    loop.finish()
    assert grasp_id in _released(link, sent)


def test_the_status_names_the_grasp_pressed_last_until_the_robot_answers():
    # The view shows the grasp the robot runs; the status, what the operator commanded last.
    clock, link, loop, held = _held_by_the_robot()
    press(loop, clock, "grasp")
    pending = link.sent[-1][2]["grasp_id"]  # as sent: not read back from the status under test
    assert pending != held
    assert loop.status.grasp_id == pending and loop.status.mode == "discrete"


def test_a_release_pressed_with_a_second_grasp_names_the_grasp_the_robot_runs():
    # g r read in one tick: the robot refuses a release naming the second grasp ("grasp A is in
    # progress, not B"), which would leave the first one's fingers closed.
    clock, link, loop, held = _held_by_the_robot()
    loop.press("grasp")
    loop.press("release")
    loop.step()
    pending = next(body["grasp_id"] for _, kind, body in link.sent if kind == "start_grasp" and body["grasp_id"] != held)
    assert _released(link) == [held]
    assert loop.status.last_action == f"release {held}" and loop.status.grasp_id == pending


def test_a_release_names_the_grasp_the_robots_state_names_before_its_start_is_shown():
    clock, link, _, loop = loop_rig()
    taken = press(loop, clock, "grasp")
    link.view = OperatorView(t_s=clock(), robot=RobotStateBody(mode="grasping", grasp_id=taken, enable=False))
    loop.step()
    press(loop, clock, "grasp")
    press(loop, clock, "release")
    assert _released(link) == [taken]


def test_a_release_or_stop_never_names_another_operators_grasp_the_robot_runs():
    """The node opens only the grasp a release names: another operator's grasp, shown or only in the
    robot's state, is not named while this console has a grasp of its own."""
    other = "op-other-001"
    for view in (OperatorView(t_s=0.0, grasp_id=other, phase="loaded",
                              robot=RobotStateBody(mode="holding", grasp_id=other, enable=False)),
                 OperatorView(t_s=0.0, robot=RobotStateBody(mode="following", grasp_id=other, enable=True))):
        clock, link, _, loop = loop_rig()
        link.view = view
        loop.step()
        mine = press(loop, clock, "grasp")
        for button in ("stop", "release"):
            loop.press(button)
            loop.step()
        named = [body.get("grasp_id") for _, action, body in link.sent if action in ("stop", "release")]
        assert named and other not in named and mine in named, (named, mine)
