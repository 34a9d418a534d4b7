"""The operator's loop (:mod:`haptics.operator_loop`) on a fake link, device and clock: the follows' pace,
what the dead-man's let-go names, when a paused follow grasp still counts as running, and what ``next``
and ``quit`` leave behind (cases the other operator-loop tests leave open)."""

from __future__ import annotations

import threading

import pytest
from support.operator_fakes import Clock, FakeDevice, FakeLink, Reading, loop_rig, press

from haptics.operator_link import OperatorView, Peer
from haptics.operator_loop import NEXT_WAIT_S, RECONNECT_S, RELEASE_FOLLOWS, OperatorLoop
from teleop.bus.messages import EstimateBody, RobotNoticeBody, RobotStateBody
from teleop.operator import FOLLOW_RATE_HZ
from teleop.settings import load_settings

PERIOD_S = 1.0 / FOLLOW_RATE_HZ
ROBOT_UP = (Peer("robot node", "robot", True, 0.1),)


def _steps(clock: Clock, loop: OperatorLoop, seconds: float, tick_s: float = 0.001) -> None:
    for _ in range(round(seconds / tick_s)):
        loop.step()
        clock.t += tick_s


def _follows(link: FakeLink, since: int = 0) -> list[dict]:
    return [body for _, kind, body in link.sent[since:] if kind == "follow"]


def _driving(grip: float = 0.5) -> tuple[Clock, FakeLink, FakeDevice, OperatorLoop, str]:
    """The enable held for 0.1 s with the robot node heard: the follow grasp's id."""
    clock, link, device, loop = loop_rig(grip=grip)
    link.view = OperatorView(t_s=clock(), peers=ROBOT_UP)
    device.enable = True
    _steps(clock, loop, 0.1)
    return clock, link, device, loop, link.sent[-1][2]["grasp_id"]


def _estimate(grasp_id: str, *, provisional: bool) -> EstimateBody:
    return EstimateBody(grasp_id=grasp_id, method="series", E_pa=5e4, interval_pa=[2e4, 1e5], state="ok", reason="",
                        provisional=provisional, latency_s=0.01)


def _paused(clock: Clock, loop: OperatorLoop, device: FakeDevice) -> None:
    """Let go of the enable for long enough that the let-go follows are spent."""
    device.enable = False
    _steps(clock, loop, 0.2)


@pytest.mark.parametrize("kwargs", [{"force_n": 0.0}, {"follow_rate_hz": 0.0}])
def test_a_zero_grasp_force_or_follow_rate_is_refused(kwargs):
    clock = Clock()
    with pytest.raises(ValueError):
        OperatorLoop(FakeLink(clock), FakeDevice(clock), load_settings(), clock=clock, **kwargs)


def test_the_first_follow_goes_out_on_the_step_that_reads_the_enable_held():
    clock, link, device, loop = loop_rig(grip=0.5)
    device.enable = True
    loop.step()
    assert link.sent == [(clock(), "follow", {"target_width_m": pytest.approx(0.04), "enable": True,
                                              "grasp_id": loop.status.grasp_id})]


def test_follows_after_a_stall_start_again_from_now_without_a_burst():
    clock, link, device, loop, _ = _driving()
    clock.t += 1.0  # the loop was stalled for a second
    sent = len(link.sent)
    for _ in range(10):
        loop.step()
    assert len(_follows(link, sent)) == 1


def test_the_follow_rate_holds_when_the_steps_do_not_divide_its_period():
    clock, link, device, loop, _ = _driving()
    sent = len(link.sent)
    _steps(clock, loop, 2.0, tick_s=0.007)
    assert len(_follows(link, sent)) >= 2 * FOLLOW_RATE_HZ - 2


def _polls_take_their_time(clock: Clock, link: FakeLink) -> None:
    """The link's poll waits its whole timeout on the fake clock, and a little work besides."""
    def poll(timeout_s: float = 0.0) -> int:
        clock.t += timeout_s + 0.0003
        return 0

    link.poll = poll


def test_run_wakes_for_a_follow_when_it_is_due_not_at_its_next_idle_tick():
    clock, link, device, loop = loop_rig(grip=0.5)
    _polls_take_their_time(clock, link)
    device.enable = True
    loop.run(duration_s=1.0)
    times = [t for t, kind, body in link.sent if kind == "follow" and body["enable"]]
    late = [t - (times[0] + i * PERIOD_S) for i, t in enumerate(times)]
    assert len(times) >= FOLLOW_RATE_HZ - 1 and min(late) >= -1e-9 and max(late) <= 0.001


def test_release_pressed_while_the_enable_is_held_suspends_it_until_held_anew():
    clock, link, device, loop, _ = _driving()
    loop.press("release")
    _steps(clock, loop, 0.3)
    released = link.kinds().index("release")  # after the step's follow: the grip and enable go first
    assert not any(b["enable"] for b in _follows(link, released))
    assert loop.status.suspended and loop.status.held


def test_the_reading_that_opens_the_device_again_is_not_the_let_go_that_rearms_the_enable():
    clock, link, device, loop, _ = _driving()
    device.plugged = device.connected = False
    _steps(clock, loop, 0.1)  # failed, and the first reopening failed too
    device.plugged, device.enable = True, False
    clock.t += RECONNECT_S
    loop.step()  # opened again: it reads the enable let go
    assert "input device connected again" in loop.status.log
    device.enable = True
    sent = len(link.sent)
    _steps(clock, loop, 0.1)
    assert not any(b["enable"] for b in _follows(link, sent)) and loop.status.suspended


def test_quitting_while_paused_in_a_follow_grasp_the_robot_runs_lets_go_then_releases():
    clock, link, device, loop, grasp_id = _driving()
    link.view = OperatorView(t_s=clock(), peers=ROBOT_UP, grasp_id=grasp_id, phase="loaded",
                             robot=RobotStateBody(mode="following", grasp_id=grasp_id, target_width_m=0.04,
                                                  enable=False))
    _paused(clock, loop, device)
    sent = len(link.sent)
    loop.finish()
    assert [(kind, body) for _, kind, body in link.sent[sent:]] == [
        ("follow", {"target_width_m": pytest.approx(0.04), "enable": False, "grasp_id": grasp_id}),
        ("release", {"grasp_id": grasp_id})]


@pytest.mark.parametrize("held_as", ["robot-stopped-in-it", "shown-loaded"])
def test_a_follow_grasp_the_robot_holds_keeps_getting_paused_follows(held_as):
    # Stopped, or loaded (its state not heard): the robot still runs it, and its watchdog must
    # only end it when the console dies.
    clock, link, device, loop, grasp_id = _driving()
    if held_as == "shown-loaded":
        link.view = OperatorView(t_s=clock(), peers=ROBOT_UP, grasp_id=grasp_id, phase="loaded")
    else:
        link.view = OperatorView(t_s=clock(), peers=ROBOT_UP, robot=RobotStateBody(
            mode="stopped", grasp_id=grasp_id, target_width_m=0.04, enable=False))
    _paused(clock, loop, device)
    sent = len(link.sent)
    _steps(clock, loop, 0.5)
    paused = _follows(link, sent)
    assert len(paused) >= 0.5 * FOLLOW_RATE_HZ - 1 and {b["grasp_id"] for b in paused} == {grasp_id}
    assert not any(b["enable"] for b in paused) and loop.status.mode == "follow (paused)"


def test_quitting_at_once_after_the_robot_node_went_down_lets_go_naming_the_grasp_lost():
    clock, link, device, loop, lost = _driving()
    link.view = OperatorView(t_s=clock(), peers=(Peer("robot node", "robot", False, 2.0),))
    loop.step()
    assert loop.status.grasp_id is None
    sent = len(link.sent)
    loop.finish()
    assert _follows(link, sent) == [{"target_width_m": pytest.approx(0.04), "enable": False, "grasp_id": lost}]


def test_the_let_go_follows_name_the_grasp_lost_when_the_restarted_node_then_goes_down():
    clock, link, device, loop, lost = _driving()
    link.view = OperatorView(t_s=clock(), peers=ROBOT_UP, robot_restarts=1)  # restarted at once
    loop.step()
    clock.t += PERIOD_S
    link.view = OperatorView(t_s=clock(), peers=(Peer("robot node", "robot", False, 2.0),), robot_restarts=1)
    sent = len(link.sent)
    _steps(clock, loop, 0.2)
    let_go = _follows(link, sent)
    assert len(let_go) == RELEASE_FOLLOWS and {b["grasp_id"] for b in let_go} == {lost}


def test_the_let_go_follows_of_a_later_grasp_do_not_name_one_lost_before_it():
    clock, link, device, loop, lost = _driving()
    link.view = OperatorView(t_s=clock(), peers=(Peer("robot node", "robot", False, 2.0),))
    _steps(clock, loop, 0.1)
    link.view = OperatorView(t_s=clock(), peers=ROBOT_UP)  # back
    _paused(clock, loop, device)
    device.enable = True
    _steps(clock, loop, 0.1)
    later = link.sent[-1][2]["grasp_id"]
    assert later not in (lost, None)
    link.view = OperatorView(t_s=clock(), peers=ROBOT_UP, grasp_id=later, phase="ended")  # the robot ended it
    loop.step()  # the step's follow, then the end heard
    sent = len(link.sent)
    _steps(clock, loop, 0.2)
    assert {b["grasp_id"] for b in _follows(link, sent)} == {None}


def test_next_on_a_follow_grasp_not_shown_makes_the_next_hold_a_new_grasp():
    clock, link, device, loop, grasp_id = _driving()
    _paused(clock, loop, device)
    press(loop, clock, "next")
    assert link.cleared == 1
    device.enable = True
    _steps(clock, loop, 0.1)
    assert link.sent[-1][2]["enable"] and link.sent[-1][2]["grasp_id"] not in (grasp_id, None)


def test_next_waiting_for_a_discrete_grasp_that_never_ends_forgets_it_when_it_gives_up():
    clock, link, device, loop = loop_rig(grip=0.5)
    grasp_id = press(loop, clock, "grasp")
    link.view = OperatorView(t_s=clock(), peers=ROBOT_UP, grasp_id=grasp_id, phase="loaded",
                             robot=RobotStateBody(mode="holding", grasp_id=grasp_id, enable=False))
    press(loop, clock, "next")
    _steps(clock, loop, NEXT_WAIT_S + 0.1, tick_s=0.01)
    assert link.cleared == 1 and loop.status.grasp_id is None and loop.status.mode == "idle"
    press(loop, clock, "next")
    assert not loop.status.last_action.startswith("next refused")


def test_next_clears_at_once_when_the_view_moves_on_to_another_grasp():
    clock, link, device, loop, grasp_id = _driving()
    _paused(clock, loop, device)
    link.view = OperatorView(t_s=clock(), peers=ROBOT_UP, grasp_id=grasp_id, phase="loaded")
    press(loop, clock, "next")
    assert link.cleared == 0 and "release" in link.kinds()
    link.view = OperatorView(t_s=clock(), peers=ROBOT_UP, grasp_id="op-other", phase="loading")
    loop.step()
    assert link.cleared == 1 and loop.status.last_action == "next object: ready"


def test_next_giving_up_on_a_final_with_the_estimator_alive_does_not_say_it_is_down():
    clock, link, device, loop, grasp_id = _driving()
    _paused(clock, loop, device)
    link.view = OperatorView(t_s=clock(), peers=(*ROBOT_UP, Peer("estimator", "estimator", True, 0.1)),
                             grasp_id=grasp_id, phase="ended", estimate=_estimate(grasp_id, provisional=True))
    press(loop, clock, "next")
    _steps(clock, loop, NEXT_WAIT_S + 0.1, tick_s=0.01)
    assert link.cleared == 1 and loop.status.last_action == "next object: ready"


def test_quit_on_the_device_acts_while_next_waits_for_the_last_grasp():
    clock, link, device, loop, grasp_id = _driving()
    _paused(clock, loop, device)
    link.view = OperatorView(t_s=clock(), peers=ROBOT_UP, grasp_id=grasp_id, phase="loaded")
    press(loop, clock, "next")
    device.buttons = {"quit"}
    loop.step()
    assert loop.quit and link.cleared == 0


def test_a_discrete_grasp_the_robot_has_not_named_yet_is_kept_for_one_heartbeat_past_liveness():
    # A state comes with every heartbeat, and a node unheard for three of them is down: until a
    # fourth has passed, a state not naming the grasp may predate the command.
    clock, link, device, loop = loop_rig(grip=0.5)
    heartbeat_s = load_settings().bus.heartbeat_s
    grasp_id = press(loop, clock, "grasp")
    link.view = OperatorView(t_s=clock(), peers=ROBOT_UP, robot=RobotStateBody(mode="idle", enable=False))
    _steps(clock, loop, 3.5 * heartbeat_s, tick_s=0.01)
    assert loop.status.grasp_id == grasp_id
    _steps(clock, loop, 0.6 * heartbeat_s, tick_s=0.01)
    assert loop.status.grasp_id is None


def test_quitting_with_the_grip_fully_squeezed_lets_go_at_the_width_it_drove_not_fully_open():
    # A target of 0 m is a target: the last follow, as recorded with the session, must not jump to open.
    clock, link, device, loop, grasp_id = _driving(grip=1.0)
    assert link.sent[-1][2]["target_width_m"] == 0.0
    loop.finish()
    assert _follows(link)[-1] == {"target_width_m": 0.0, "enable": False, "grasp_id": grasp_id}


def test_run_stops_when_its_stop_event_is_set():
    clock, link, device, loop = loop_rig()
    _polls_take_their_time(clock, link)
    stop, statuses = threading.Event(), []
    stop.set()
    loop.run(stop, duration_s=1.0, on_status=statuses.append)  # the duration: only a guard
    assert statuses == []


def test_a_discrete_grasp_a_device_notice_ended_is_forgotten_before_its_end_is_heard():
    clock, link, device, loop = loop_rig(grip=0.5)
    grasp_id = press(loop, clock, "grasp")
    failed = RobotNoticeBody(event="device", action="gripper", grasp_id=grasp_id, reason="the grasp command failed")
    link.view = OperatorView(t_s=clock(), peers=ROBOT_UP, grasp_id=grasp_id, phase="loading", ended_by=failed,
                             robot=RobotStateBody(mode="grasping", grasp_id=grasp_id, enable=False))
    loop.step()
    assert loop.status.grasp_id is None and loop.status.mode == "idle"


def test_the_status_names_the_follow_grasp_the_enable_drives_over_a_discrete_grasp_pressed_meanwhile():
    clock, link, device, loop, grasp_id = _driving()
    press(loop, clock, "grasp")  # the robot will refuse it: a follow grasp runs
    assert loop.status.grasp_id == grasp_id and loop.status.mode == "follow"


def test_next_waits_again_for_the_grasp_after_one_it_saw_over():
    clock, link, device, loop, first = _driving()
    _paused(clock, loop, device)
    estimator = (*ROBOT_UP, Peer("estimator", "estimator", True, 0.1))
    link.view = OperatorView(t_s=clock(), peers=estimator, grasp_id=first, phase="ended",
                             estimate=_estimate(first, provisional=True))
    press(loop, clock, "next")
    link.view = OperatorView(t_s=clock(), peers=estimator, grasp_id=first, phase="ended",
                             estimate=_estimate(first, provisional=False))  # its final
    _steps(clock, loop, 0.01)
    assert link.cleared == 1
    link.view = OperatorView(t_s=clock(), peers=estimator, grasp_id="op-second", phase="loaded",
                             estimate=_estimate("op-second", provisional=True))
    press(loop, clock, "next")
    _steps(clock, loop, 0.1)
    assert link.cleared == 1 and "release" in link.kinds()


def test_the_status_shows_the_force_the_operator_squeezes_with():
    clock, link, device, loop = loop_rig()
    device.read = lambda *, timeout_s: Reading(clock(), 0.3, False, 7.5)
    loop.step()
    assert loop.status.operator_force_n == 7.5
