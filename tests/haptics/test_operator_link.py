"""The operator's loop (:mod:`haptics.operator_loop`) against a fake link and fake devices (the link itself on
loopback: test_operator_link_bus.py)."""

from __future__ import annotations

import dataclasses
import math
import threading

import numpy as np
import pytest
from support.operator_fakes import Clock, FakeDevice, FakeLink

from haptics.errors import HapticsError
from haptics.operator_link import OperatorView, Peer
from haptics.operator_loop import NEXT_WAIT_S, RECONNECT_S, RELEASE_FOLLOWS, OperatorLoop
from teleop.bus.messages import DisplayBody, EstimateBody, RobotNoticeBody, RobotStateBody
from teleop.errors import BusError, MessageRejected
from teleop.labels import ObjectLabel
from teleop.operator import FOLLOW_RATE_HZ
from teleop.settings import load_settings


@pytest.fixture
def rig():
    clock = Clock()
    link, device = FakeLink(clock), FakeDevice(clock)
    loop = OperatorLoop(link, device, load_settings(), force_n=12.0, clock=clock)
    loop.step()  # the operator sits down, the enable let go: the loop drives only an enable read let go first
    return clock, link, device, loop


def run_for(clock: Clock, loop: OperatorLoop, seconds: float, tick_s: float = 0.001) -> None:
    end = clock.t + seconds
    while clock.t < end - 1e-9:
        loop.step()
        clock.t += tick_s


def test_follow_goes_out_at_the_rate_while_enable_is_held(rig):
    clock, link, device, loop = rig
    device.grip, device.enable = 0.25, True
    run_for(clock, loop, 1.0)
    follows = [(t, body) for t, kind, body in link.sent if kind == "follow"]
    assert abs(len(follows) - FOLLOW_RATE_HZ) <= 1
    gaps = np.diff([t for t, _ in follows])
    assert gaps.max() <= 1.0 / FOLLOW_RATE_HZ + 0.0011 and gaps.min() >= 1.0 / FOLLOW_RATE_HZ - 0.0011
    assert all(b["enable"] and b["target_width_m"] == pytest.approx(0.08 * 0.75) for _, b in follows)
    assert len({b["grasp_id"] for _, b in follows}) == 1 and follows[0][1]["grasp_id"].startswith("op-")
    assert loop.status.mode == "follow" and loop.status.enable
    # The grip moves the target within one period.
    device.grip = 1.0
    run_for(clock, loop, 0.03)
    assert link.sent[-1][2]["target_width_m"] == 0.0


def test_no_follow_without_enable_and_a_few_disabled_ones_when_let_go(rig):
    clock, link, device, loop = rig
    device.grip = 0.8
    run_for(clock, loop, 0.5)
    assert link.sent == [] and loop.status.mode == "idle"
    device.enable = True
    run_for(clock, loop, 0.2)
    held = len(link.sent)
    device.enable = False
    run_for(clock, loop, 0.5)
    after = [b for _, _, b in link.sent[held:]]
    assert len(after) == RELEASE_FOLLOWS and not any(b["enable"] for b in after)
    assert {b["grasp_id"] for b in after} == {link.sent[0][2]["grasp_id"]}
    assert not loop.status.enable


def test_buttons_become_commands(rig):
    clock, link, device, loop = rig
    device.buttons = {"grasp"}
    loop.step()
    assert link.sent[-1][1:] == ("start_grasp", {"target_force_n": 12.0, "grasp_id": loop.status.grasp_id})
    grasp_id = loop.status.grasp_id
    assert loop.status.mode == "discrete"
    for button in ("stop", "release"):
        device.buttons = {button}
        loop.step()
        assert link.sent[-1][1:] == (button, {"grasp_id": grasp_id})
    # next: releases a grasp still under way; once the robot has ended it, clears the view and forgets
    # the grasp. Meanwhile the device's buttons are read and not taken (but quit): none acts seconds later.
    link.view = OperatorView(t_s=clock(), grasp_id=grasp_id, phase="loaded")
    device.buttons = {"next"}
    loop.step()
    assert link.kinds()[-1] == "release" and link.cleared == 0 and loop.status.grasp_id == grasp_id
    device.buttons = {"grasp"}
    loop.step()
    assert link.kinds()[-1] == "release" and device.buttons == set()
    assert loop.status.last_action == "grasp pressed while the last grasp ends: not taken, press again"
    link.view = OperatorView(t_s=clock(), grasp_id=grasp_id, phase="ended")
    assert loop.step().view.phase == "ended"  # shown over once, then cleared
    loop.step()
    assert link.cleared == 1 and loop.status.grasp_id is None
    device.buttons = set()
    loop.press("grasp")  # from another thread, as the console's keys do
    loop.step()
    assert link.kinds()[-1] == "start_grasp" and loop.status.grasp_id != grasp_id
    device.buttons = {"quit"}
    assert loop.run(duration_s=5.0).quit


def test_a_command_while_the_robot_node_is_not_heard_says_that_nothing_moves(rig):
    clock, link, device, loop = rig
    for alive in (False, True):
        link.view = OperatorView(t_s=clock(), peers=(Peer("robot node", "robot", alive, None if not alive else 0.1),))
        device.buttons = {"grasp"}
        loop.step()
        assert link.kinds()[-1] == "start_grasp"  # the link sent it: its subscription is open
        assert ("robot node is not heard" in loop.status.log[-1]) == (not alive)


def test_a_grasp_the_link_refused_to_send_is_not_waited_on(rig, monkeypatch):
    clock, link, device, loop = rig

    def refused(**kwargs):
        raise BusError("the robot node has not subscribed to tcp://127.0.0.1:5 yet (it is down, or still "
                       "connecting): a start_grasp now would reach no one")

    monkeypatch.setattr(link, "start_grasp", refused)
    device.buttons = {"grasp"}
    loop.step()
    assert loop.status.log[-1].startswith("not sent (bus): the robot node has not subscribed")
    device.buttons = {"next"}  # no grasp in progress: the next object is not refused
    loop.step()
    assert "next object: ready" in loop.status.log[-1]


def test_a_grasp_the_robot_refused_to_start_is_forgotten(rig):
    clock, link, device, loop = rig
    grasp_id = hold_and_let_go(clock, loop, device, link)  # a follow grasp the robot runs
    link.view = OperatorView(t_s=clock(), grasp_id=grasp_id, phase="loading")
    device.buttons = {"grasp"}
    loop.step()
    refused = link.sent[-1][2]["grasp_id"]
    assert link.kinds()[-1] == "start_grasp" and loop.status.mode == "discrete"
    link.view = dataclasses.replace(link.view, notice=RobotNoticeBody(
        event="refused", action="start_grasp", grasp_id=refused, reason=f"grasp {grasp_id!r} is still in progress"),
        refused_starts=(refused,))
    loop.step()
    assert loop.status.mode != "discrete" and loop.status.grasp_id == grasp_id
    device.buttons = {"release"}
    loop.step()
    assert link.sent[-1][1:] == ("release", {"grasp_id": grasp_id})  # the grasp there is, not the refused one
    link.view = dataclasses.replace(link.view, phase="ended")
    loop.step()
    assert loop.status.mode == "idle" and loop.status.grasp_id is None


def test_an_unplugged_device_pauses_the_follow_grasp_and_is_opened_again(rig):
    clock, link, device, loop = rig
    device.grip, device.enable = 0.5, True
    run_for(clock, loop, 0.2)
    grasp_id = link.sent[-1][2]["grasp_id"]
    link.view = OperatorView(t_s=clock(), grasp_id=grasp_id, phase="loading")  # the robot runs it
    device.plugged = device.connected = False
    sent = len(link.sent)
    run_for(clock, loop, 2.5)
    paused = [b for _, kind, b in link.sent[sent:] if kind == "follow"]
    # The enable reads released: follows go on at the rate without it (no watchdog), the grip kept.
    assert len(paused) > 2 * RELEASE_FOLLOWS and not any(b["enable"] for b in paused)
    assert [b["target_width_m"] for b in paused] == pytest.approx([0.04] * len(paused))
    assert {b["grasp_id"] for b in paused} == {grasp_id}
    assert device.connects == 3  # at 0, 1 and 2 s: every RECONNECT_S
    assert "unplugged" in loop.status.problem and f"every {RECONNECT_S:g} s" in loop.status.problem
    assert not any("feel()" in line for line in loop.status.log)  # not fed back while disconnected
    device.grip, device.plugged = 1.0, True  # the hand squeezed on while it was unplugged
    sent = len(link.sent)
    run_for(clock, loop, RECONNECT_S)
    assert device.connected and "input device connected again" in loop.status.log and loop.status.problem == ""
    # Held all along: that is no fresh press. Follows go on without the enable, the grasp paused.
    back = [b for _, kind, b in link.sent[sent:] if kind == "follow"]
    assert back and not any(b["enable"] for b in back) and {b["grasp_id"] for b in back} == {grasp_id}
    assert loop.status.suspended and loop.status.held
    device.enable = False
    run_for(clock, loop, 0.05)
    device.enable = True  # let go and held again: it drives on, where the grip is now
    run_for(clock, loop, 0.05)
    assert link.sent[-1][2] == {"target_width_m": 0.0, "enable": True, "grasp_id": grasp_id}


def test_a_simulated_person_waits_for_the_robot_node_before_squeezing(rig):
    clock, link, device, loop = rig
    device.waits_for_robot, device.grip, device.enable = True, 0.5, True
    for alive in (False, True):
        link.view = OperatorView(t_s=clock(), peers=(Peer("robot node", "robot", alive, None if not alive else 0.1),))
        run_for(clock, loop, 0.1)
        assert (link.kinds().count("follow") > 0) == alive
        assert ("waiting for the robot node" in loop.status.log[0]) and len(loop.status.log) == 1 + alive


def hold_and_let_go(clock: Clock, loop: OperatorLoop, device: FakeDevice, link: FakeLink) -> str:
    """Hold the enable for 0.1 s, then let it go for 0.1 s; the follow grasp's id."""
    device.enable = True
    run_for(clock, loop, 0.1)
    grasp_id = link.sent[-1][2]["grasp_id"]
    device.enable = False
    run_for(clock, loop, 0.1)
    return grasp_id


def test_next_leaves_a_grasp_the_robot_already_releases_without_a_second_release(rig):
    clock, link, device, loop = rig
    grasp_id = hold_and_let_go(clock, loop, device, link)
    # The operator let go and the robot opens the fingers; "next" comes before the robot ends the grasp.
    link.view = OperatorView(t_s=clock(), grasp_id=grasp_id, phase="loading",
                             robot=RobotStateBody(mode="releasing", grasp_id=grasp_id, target_width_m=None,
                                                  enable=False))
    device.buttons = {"next"}
    sent = len(link.sent)
    run_for(clock, loop, 0.5)
    assert "release" not in link.kinds()[sent:] and link.cleared == 0
    # The robot never says it ended (say it died): the view is cleared after NEXT_WAIT_S all the same.
    run_for(clock, loop, NEXT_WAIT_S, tick_s=0.01)
    assert link.cleared == 1 and loop.status.last_action == "next object: ready"


def test_next_suspends_a_held_enable_until_it_is_let_go_and_held_again(rig):
    # The next object is not under the fingers yet: the hand still on the enable must not grasp it.
    clock, link, device, loop = rig
    device.enable, device.grip = True, 0.5
    run_for(clock, loop, 0.1)
    assert link.sent[-1][1] == "follow" and link.sent[-1][2]["enable"]
    loop.press("next")  # the view shows no grasp yet: next clears at once
    run_for(clock, loop, 0.05)
    sent = len(link.sent)
    run_for(clock, loop, 0.5)
    assert not any(b["enable"] for _, kind, b in link.sent[sent:] if kind == "follow")
    assert loop.status.suspended and loop.status.held
    _hold_again(clock, device, loop)
    assert link.sent[-1][2]["enable"]


def test_next_waits_for_the_final_estimate_that_follows_an_operator_grasps_end(rig):
    clock, link, device, loop = rig
    grasp_id = hold_and_let_go(clock, loop, device, link)
    alive = (Peer("estimator", "estimator", True, 0.1),)

    def estimate(provisional: bool) -> EstimateBody:
        return EstimateBody(grasp_id=grasp_id, method="auto", E_pa=3e4, interval_pa=[1.5e4, 6e4], state="ok",
                            reason="", provisional=provisional, latency_s=0.002)

    # The robot ended the grasp; its final estimate comes after, from the estimator.
    link.view = OperatorView(t_s=clock(), peers=alive, grasp_id=grasp_id, phase="ended", estimate=estimate(True))
    device.buttons = {"next"}
    run_for(clock, loop, 0.5)
    assert link.cleared == 0 and "final estimate" in loop.status.last_action
    assert "release" not in link.kinds()  # ended: nothing to release
    link.view = dataclasses.replace(link.view, estimate=estimate(False))
    assert not loop.step().view.estimate.provisional and link.cleared == 0  # the final shown once
    loop.step()
    assert link.cleared == 1 and loop.status.last_action == "next object: ready"
    # With no estimator alive, no final is awaited.
    grasp_id = hold_and_let_go(clock, loop, device, link)
    link.view = OperatorView(t_s=clock(), peers=(dataclasses.replace(alive[0], alive=False),), grasp_id=grasp_id,
                             phase="ended")
    device.buttons = {"next"}
    loop.step()
    assert link.cleared == 2


def test_a_label_names_the_current_grasp_then_the_last_one(rig):
    from teleop.labels import modulus_label, shore_label

    clock, link, device, loop = rig
    assert loop.status.label_grasp_id is None
    device.buttons = {"grasp"}
    loop.step()
    grasp_id = loop.status.grasp_id
    assert loop.status.label_grasp_id == grasp_id
    loop.label(grasp_id, shore_label("gel pad", 40, "A"))  # from another thread, as the console does
    assert link.kinds()[-1] == "start_grasp"  # sent on the next step, from the loop's thread
    loop.step()
    assert link.sent[-1][1:] == ("label", shore_label("gel pad", 40, "A").body(grasp_id))
    assert loop.status.labels[grasp_id].object_name == "gel pad" and "label " + grasp_id in loop.status.last_action
    link.view = OperatorView(t_s=clock(), grasp_id=grasp_id, phase="ended")
    loop.step()
    device.buttons = {"next"}
    loop.step()
    assert loop.status.grasp_id is None and loop.status.label_grasp_id == grasp_id  # the last grasp still
    loop.label(grasp_id, modulus_label("gel pad", 2e6))
    loop.step()
    assert link.sent[-1][2]["source"] == "datasheet" and loop.status.labels[grasp_id].modulus_pa == 2e6
    with pytest.raises(ValueError, match="needs the id"):
        loop.label("", modulus_label("x", 1.0))


def test_a_follow_grasp_gets_a_new_id_after_the_robot_ended_it(rig):
    clock, link, device, loop = rig
    first = hold_and_let_go(clock, loop, device, link)
    link.view = OperatorView(t_s=clock(), grasp_id=first, phase="loading")
    device.enable = True
    run_for(clock, loop, 0.1)
    assert link.sent[-1][2]["grasp_id"] == first  # paused and resumed: the same grasp
    device.enable = False
    run_for(clock, loop, 0.1)
    link.view = OperatorView(t_s=clock(), grasp_id=first, phase="ended")
    run_for(clock, loop, 0.01)
    device.enable = True
    run_for(clock, loop, 0.1)
    assert link.sent[-1][2]["grasp_id"] not in (first, None)


def test_the_robot_state_goes_back_to_the_device(rig):
    clock, link, device, loop = rig
    loop.step()
    assert device.felt[-1] == (0.0, 0.08, None)  # nothing heard yet: open, no force, nothing rendered
    display = DisplayBody(phase="active", stiffness=0.4, uncertainty_decades=0.2, rigid=False, unknown=False,
                          provisional=False, E_pa=1e6)
    link.view = OperatorView(t_s=clock(), force_n=3.5, width_m=0.03, display=display)
    loop.step()
    assert device.felt[-1] == (3.5, 0.03, 0.4)
    link.view = dataclasses.replace(link.view, display=dataclasses.replace(display, rigid=True, stiffness=1.0))
    loop.step()
    assert device.felt[-1][2] == 1.0


def test_force_beyond_the_settings_maximum_is_refused():
    clock = Clock()
    with pytest.raises(ValueError, match=r"maximum grasp force"):
        OperatorLoop(FakeLink(clock), FakeDevice(clock), load_settings(), force_n=500.0)
    with pytest.raises(ValueError, match=r"button"):
        OperatorLoop(FakeLink(clock), FakeDevice(clock), load_settings()).press("launch")


@pytest.mark.parametrize("duration_s", [math.nan, math.inf, -1.0, "1"])
def test_a_bad_duration_is_refused_before_the_loop_runs(rig, duration_s):
    _, link, _, loop = rig
    with pytest.raises(HapticsError, match=r"duration_s = .*: expected a finite number of seconds >= 0"):
        loop.run(duration_s=duration_s)
    assert link.sent == []


def test_a_failed_send_is_shown_and_the_loop_goes_on(rig):
    from teleop.errors import BusTimeoutError

    clock, link, device, loop = rig

    def refuse(**_):
        raise BusTimeoutError("no room for 'command'")

    link.start_grasp = refuse
    device.buttons = {"grasp"}
    loop.step()
    assert "no room" in loop.status.problem and loop.status.mode == "idle"
    device.buttons = {"stop"}
    loop.step()
    assert link.kinds() == ["stop"]


def test_a_problem_that_no_longer_holds_is_cleared_and_the_log_keeps_it(rig, monkeypatch):
    clock, link, device, loop = rig
    not_subscribed = BusError("the robot node has not subscribed to tcp://127.0.0.1:5 yet (it is down, or still "
                              "connecting): a follow now would reach no one")

    def refused(*args, **kwargs):
        raise not_subscribed

    def bad_poll(timeout_s=0.0):
        raise BusError("bad message")

    for send in ("start_grasp", "follow"):
        monkeypatch.setattr(link, send, refused)
    device.buttons, device.enable = {"grasp"}, True
    run_for(clock, loop, 0.1)
    assert loop.status.problem.startswith("not sent (bus): the robot node has not subscribed") and link.sent == []
    monkeypatch.undo()  # the robot node comes up: the follows reach it
    run_for(clock, loop, 0.1)
    assert link.kinds()[-1] == "follow" and loop.status.problem == ""
    assert f"not sent (bus): {not_subscribed}" in loop.status.log
    monkeypatch.setattr(link, "poll", bad_poll)
    loop.step()
    assert loop.status.problem == "bus: bad message"
    monkeypatch.undo()
    loop.step()
    assert loop.status.problem == "" and "bus: bad message" in loop.status.log


def test_the_loop_runs_in_a_thread_and_stops(rig):
    clock, link, device, loop = rig
    real = OperatorLoop(link, device, load_settings())
    stop = threading.Event()
    thread = threading.Thread(target=real.run, args=(stop,))
    thread.start()
    real.press("quit")
    thread.join(timeout=2.0)
    assert not thread.is_alive() and real.status.quit


def test_after_a_stop_or_the_grasps_end_the_enable_must_be_held_anew(rig):
    clock, link, device, loop = rig
    device.enable, device.grip = True, 0.5
    run_for(clock, loop, 0.1)
    grasp_id = link.sent[-1][2]["grasp_id"]
    device.buttons = {"stop"}
    run_for(clock, loop, 0.2)
    stop = link.kinds().index("stop")
    assert "suspended" in loop.status.mode and not loop.status.enable
    assert [b["enable"] for _, _, b in link.sent[stop + 1:]] == [False] * RELEASE_FOLLOWS
    device.enable = False
    run_for(clock, loop, 0.05)
    device.enable = True
    run_for(clock, loop, 0.1)
    assert link.sent[-1][2] == {"target_width_m": 0.04, "enable": True, "grasp_id": grasp_id}
    # the robot ends the grasp (its watchdog, say) while the enable is still held: nothing more
    link.view = OperatorView(t_s=clock(), grasp_id=grasp_id, phase="ended")
    run_for(clock, loop, 0.2)
    sent = len(link.sent)
    run_for(clock, loop, 0.3)
    assert len(link.sent) == sent
    _hold_again(clock, device, loop)
    assert link.sent[-1][2]["enable"] and link.sent[-1][2]["grasp_id"] not in (grasp_id, None)


def _hold_again(clock: Clock, device, loop: OperatorLoop) -> None:
    """Let go of the enable and hold it again: a new follow grasp starts."""
    device.enable = False
    run_for(clock, loop, 0.05)
    device.enable = True
    run_for(clock, loop, 0.05)


def test_follows_go_on_without_the_enable_while_the_robot_runs_the_grasp(rig):
    """A paused operator keeps the grasp: the robot's watchdog must only fire when the console dies."""
    clock, link, device, loop = rig
    device.enable, device.grip = True, 0.5
    run_for(clock, loop, 0.1)
    grasp_id = link.sent[-1][2]["grasp_id"]
    link.view = OperatorView(t_s=clock(), grasp_id=grasp_id, phase="loading",
                             robot=RobotStateBody(mode="following", grasp_id=grasp_id, target_width_m=0.04,
                                                  enable=True))
    device.enable = False
    run_for(clock, loop, 1.0)
    paused = [(t, b) for t, kind, b in link.sent if kind == "follow" and not b["enable"]]
    assert abs(len(paused) - FOLLOW_RATE_HZ) <= 1 and {b["grasp_id"] for _, b in paused} == {grasp_id}
    assert loop.status.mode == "follow (paused)"
    device.enable = True  # resumes the same grasp
    run_for(clock, loop, 0.05)
    assert link.sent[-1][2] == {"target_width_m": 0.04, "enable": True, "grasp_id": grasp_id}
    device.enable = False
    link.view = OperatorView(t_s=clock(), grasp_id=grasp_id, phase="ended",
                             robot=RobotStateBody(mode="idle", enable=False))
    run_for(clock, loop, 0.2)
    sent = len(link.sent)
    run_for(clock, loop, 0.5)
    assert len(link.sent) == sent and loop.status.mode == "idle"


def _robot(clock: Clock, alive: bool, **view) -> OperatorView:
    return OperatorView(t_s=clock(), peers=(Peer("robot node", "robot", alive, 0.1),), **view)


@pytest.mark.parametrize("waits_for_robot", [False, True])
def test_a_grasp_is_forgotten_when_the_robot_node_goes_down(rig, waits_for_robot):
    # The node killed mid-grasp and started again: the held enable must not drive the new node under
    # the old grasp's id (it would start a grasp of that id, which the estimator and renderer took as
    # the old one's).
    clock, link, device, loop = rig
    device.waits_for_robot, device.grip, device.enable = waits_for_robot, 0.5, True
    link.view = _robot(clock, True)
    run_for(clock, loop, 0.1)
    lost = link.sent[-1][2]["grasp_id"]
    link.view = _robot(clock, True, grasp_id=lost, phase="loading")
    run_for(clock, loop, 0.1)
    link.view = _robot(clock, False, grasp_id=lost, phase="loading")
    run_for(clock, loop, 0.1)
    assert f"the robot node is down: grasp {lost} is lost" in loop.status.log and link.cleared == 1
    assert loop.status.grasp_id is None and "suspended" in loop.status.mode
    link.view = _robot(clock, True)  # started again
    sent = len(link.sent)
    run_for(clock, loop, 0.3)
    assert not any(b["enable"] or b["grasp_id"] for _, kind, b in link.sent[sent:] if kind == "follow")
    _hold_again(clock, device, loop)
    assert link.sent[-1][2]["enable"] and link.sent[-1][2]["grasp_id"] not in (lost, None)


def test_a_robot_node_never_heard_loses_nothing(rig):
    # Nothing to lose; an enable held meanwhile drives only once held anew with the node heard.
    clock, link, device, loop = rig
    link.view = _robot(clock, False)
    device.enable = True
    run_for(clock, loop, 0.1)
    assert not link.sent and "suspended" in loop.status.mode and link.cleared == 0
    link.view = _robot(clock, True)
    _hold_again(clock, device, loop)
    assert link.sent[-1][2]["enable"] and loop.status.mode == "follow" and link.cleared == 0


def test_quitting_releases_the_follow_grasp_the_robot_runs(rig):
    # Else follows stop and the robot's watchdog ends the grasp.
    clock, link, device, loop = rig
    device.enable, device.grip = True, 0.5
    run_for(clock, loop, 0.1)
    grasp_id = link.sent[-1][2]["grasp_id"]
    link.view = OperatorView(t_s=clock(), grasp_id=grasp_id, phase="loading", robot=RobotStateBody(
        mode="following", grasp_id=grasp_id, target_width_m=0.04, enable=True))
    device.buttons = {"quit"}
    loop.run()
    assert link.sent[-2:] == [(clock(), "follow", {"target_width_m": 0.04, "enable": False, "grasp_id": grasp_id}),
                              (clock(), "release", {"grasp_id": grasp_id})]
    assert loop.status.mode == "idle" and "the console quits" in loop.status.last_action


def test_quitting_while_driving_lets_go_of_a_grasp_the_robot_does_not_show_yet(rig):
    # Its robot_state not heard yet, the robot may run it all the same: the last follow must let go.
    clock, link, device, loop = rig
    device.enable, device.grip = True, 0.5
    run_for(clock, loop, 0.1)
    grasp_id = link.sent[-1][2]["grasp_id"]
    assert link.sent[-1][2]["enable"] and link.view.robot is None
    loop.finish()
    follows = [b for _, kind, b in link.sent if kind == "follow"]
    assert follows[-1] == {"target_width_m": follows[-2]["target_width_m"], "enable": False, "grasp_id": grasp_id}


def test_quitting_leaves_alone_a_grasp_the_robot_releases_or_none(rig):
    clock, link, device, loop = rig
    loop.finish()
    assert link.sent == []
    grasp_id = hold_and_let_go(clock, loop, device, link)
    link.view = OperatorView(t_s=clock(), grasp_id=grasp_id, phase="loaded", robot=RobotStateBody(
        mode="releasing", grasp_id=grasp_id, target_width_m=0.04, enable=False))
    sent = len(link.sent)
    loop.finish()
    assert "release" not in link.kinds()[sent:]


def test_a_label_refused_for_its_fields_stays_said_while_follows_go_through(rig, monkeypatch):
    # Any send that went through cleared every "not sent" problem: a follow 50 ms later hid a bad label.
    clock, link, device, loop = rig

    def rejected(*args, **kwargs):
        raise MessageRejected("too_long", "label detail is 300 characters, more than 256")

    monkeypatch.setattr(link, "label", rejected)
    loop.label("op-1", ObjectLabel("stress_ball", None, "catalogue", ""))
    device.enable = True
    run_for(clock, loop, 0.2)
    assert link.kinds()[-1] == "follow"
    assert loop.status.problem == "not sent: too_long: label detail is 300 characters, more than 256"


def test_a_device_opened_again_at_once_does_not_drive_the_enable_it_reads_held(rig):
    # A device failed (in feel, say) and is opened again on the next read: no reading was missed, but
    # the hand was not heard in between. The enable it reads held drives only once let go and held again.
    clock, link, device, loop = rig
    device.grip, device.enable = 0.5, True
    run_for(clock, loop, 0.1)
    device.connected = False
    sent = len(link.sent)
    run_for(clock, loop, 0.1)
    assert device.connects == 1 and "input device connected again" in loop.status.log
    assert not any(b["enable"] for _, kind, b in link.sent[sent:] if kind == "follow")
    assert loop.status.suspended and loop.status.held
