"""Real input backends (fake hardware underneath) driving the operator's loop: what the hand did
while the device was not heard never drives; the enable must be read let go and held again."""

from __future__ import annotations

import pytest
from support.operator_fakes import Clock, FakeLink

from haptics.errors import ProtocolError
from haptics.inputs.display import DisplayInput
from haptics.inputs.gamepad import GamepadInput
from haptics.inputs.sim import SimulatedInput
from haptics.operator_link import OperatorView
from haptics.operator_loop import RECONNECT_S, OperatorLoop
from teleop.settings import load_settings

TRIGGER_FULL = 255
TRIGGER_FIFTH = 51  # grip 0.2: the fingers' target 0.064 m of 0.08 m


def _run(clock: Clock, loop: OperatorLoop, seconds: float, each=None) -> None:
    end = clock.t + seconds
    while clock.t < end - 1e-9:
        if each is not None:
            each()
        loop.step()
        clock.t += 0.001


def _enabled(link: FakeLink, since: int) -> list[dict]:
    return [body for _, kind, body in link.sent[since:] if kind == "follow" and body["enable"]]


def _driving_pad(make_pad) -> tuple[Clock, FakeLink, object, OperatorLoop, str]:
    clock = Clock()
    link, pad = FakeLink(clock), make_pad()
    loop = OperatorLoop(link, GamepadInput(device=pad).connect(), load_settings(), clock=clock)
    loop.step()  # the enable read let go
    pad.key("BTN_TR", 1)
    pad.move("ABS_RZ", TRIGGER_FIFTH)
    _run(clock, loop, 0.1)
    grasp_id = link.sent[-1][2]["grasp_id"]
    assert link.sent[-1][2]["enable"] and link.sent[-1][2]["target_width_m"] == pytest.approx(0.064)
    link.view = OperatorView(t_s=clock(), grasp_id=grasp_id, phase="loading")  # the robot runs it
    return clock, link, pad, loop, grasp_id


def test_a_gamepad_plugged_back_with_the_trigger_pulled_meanwhile_drives_only_once_the_enable_is_held_anew(make_pad):
    clock, link, pad, loop, grasp_id = _driving_pad(make_pad)
    pad.unplugged = True
    _run(clock, loop, 0.5)
    pad.move("ABS_RZ", TRIGGER_FULL, report=False)  # the hand squeezes on while it is unplugged
    pad.unplugged = False
    sent = len(link.sent)
    _run(clock, loop, 1.2)  # opened again within RECONNECT_S, the shoulder button held all along
    assert "input device connected again" in loop.status.log
    follows = [body for _, kind, body in link.sent[sent:] if kind == "follow"]
    assert follows and not any(body["enable"] for body in follows)  # paused, not squeezed shut
    assert {body["grasp_id"] for body in follows} == {grasp_id}
    assert loop.status.suspended and loop.status.held and not loop.status.enable
    assert loop.status.mode.startswith("follow suspended")
    pad.key("BTN_TR", 0)
    _run(clock, loop, 0.05)
    assert not _enabled(link, sent)
    pad.key("BTN_TR", 1)  # held anew: now it drives, where the grip is
    _run(clock, loop, 0.05)
    assert _enabled(link, sent)[0] == {"target_width_m": 0.0, "enable": True, "grasp_id": grasp_id}


def test_while_a_gamepad_is_unplugged_the_status_says_so_and_names_it_not_feel(make_pad):
    clock, link, pad, loop, _ = _driving_pad(make_pad)
    pad.unplugged = True
    _run(clock, loop, 2.5)
    problem = loop.status.problem
    assert "went away" in problem and f"trying again every {RECONNECT_S:g} s" in problem
    assert "GamepadInput" in problem
    assert not any("feel()" in line for line in loop.status.log)


def test_an_enable_held_when_the_loop_starts_drives_only_once_let_go_and_held_again(make_pad):
    clock = Clock()
    link, pad = FakeLink(clock), make_pad()
    pad.key("BTN_TR", 1, report=False)
    pad.move("ABS_RZ", TRIGGER_FULL, report=False)  # held and squeezed before the console starts
    loop = OperatorLoop(link, GamepadInput(device=pad).connect(), load_settings(), clock=clock)
    _run(clock, loop, 0.3)
    assert not _enabled(link, 0)
    assert loop.status.suspended and loop.status.held and not loop.status.enable
    pad.key("BTN_TR", 0)
    _run(clock, loop, 0.05)
    assert not _enabled(link, 0) and not loop.status.suspended
    pad.key("BTN_TR", 1)
    _run(clock, loop, 0.05)
    assert _enabled(link, 0)[0]["target_width_m"] == 0.0


def _driving_display(make_grip_display) -> tuple[Clock, FakeLink, object, OperatorLoop]:
    """A display input driving a follow grasp at grip 0.2, the robot running it."""
    clock = Clock()
    display = make_grip_display()
    link = FakeLink(clock)
    loop = OperatorLoop(link, DisplayInput(display, clock=clock).connect(), load_settings(), clock=clock)
    _run(clock, loop, 0.05, lambda: display.push(0.0, enable=False))
    _run(clock, loop, 0.2, lambda: display.push(0.2))
    assert link.sent[-1][2]["enable"]
    link.view = OperatorView(t_s=clock(), grasp_id=link.sent[-1][2]["grasp_id"], phase="loading")
    return clock, link, display, loop


def test_a_display_whose_grip_reports_stop_drives_again_only_once_the_enable_is_held_anew(make_grip_display):
    clock, link, display, loop = _driving_display(make_grip_display)
    _run(clock, loop, 0.3)  # no report for 0.3 s: the grip is lost (100 ms), the enable reads let go
    assert not link.sent[-1][2]["enable"]
    sent = len(link.sent)
    _run(clock, loop, 0.2, lambda: display.push(0.9))  # back, the enable bit held: no fresh press
    assert not _enabled(link, sent) and loop.status.suspended
    _run(clock, loop, 0.05, lambda: display.push(0.9, enable=False))
    _run(clock, loop, 0.05, lambda: display.push(0.9))
    assert _enabled(link, sent)[0]["target_width_m"] == pytest.approx(0.008)


def test_one_malformed_grip_report_is_no_gap_the_held_enable_drives_on(make_grip_display):
    clock, link, display, loop = _driving_display(make_grip_display)
    reports, failed = display.read_operator_reports, []

    def one_bad_report(*, timeout_s):
        if not failed:
            failed.append(True)
            raise ProtocolError("grip report: bad checksum")  # the protocol names it; the link stays
        return reports(timeout_s=timeout_s)

    display.read_operator_reports = one_bad_report
    sent = len(link.sent)
    _run(clock, loop, 0.2, lambda: display.push(0.3))  # the operator squeezes on, the enable held
    assert failed and _enabled(link, sent) and not loop.status.suspended


def test_one_malformed_grip_report_is_no_let_go_of_a_suspended_enable(make_grip_display):
    clock, link, display, loop = _driving_display(make_grip_display)
    loop.press("stop")  # suspended: the enable, held all along, drives nothing until let go
    _run(clock, loop, 0.1, lambda: display.push(0.2))
    assert loop.status.suspended
    reports, failed = display.read_operator_reports, []

    def one_bad_report(*, timeout_s):
        if not failed:
            failed.append(True)
            raise ProtocolError("grip report: bad checksum")
        return reports(timeout_s=timeout_s)

    display.read_operator_reports = one_bad_report
    sent = len(link.sent)
    _run(clock, loop, 0.2, lambda: display.push(0.3))  # the enable held throughout, never let go
    assert failed and not _enabled(link, sent) and loop.status.suspended


def test_before_its_first_grip_report_a_display_is_not_heard_so_its_first_held_report_does_not_drive(
        make_grip_display):
    clock = Clock()
    display = make_grip_display()
    link = FakeLink(clock)
    loop = OperatorLoop(link, DisplayInput(display, clock=clock).connect(), load_settings(), clock=clock)
    _run(clock, loop, 0.05)  # nothing reported yet: the enable reads released, but is not read let go
    _run(clock, loop, 0.1, lambda: display.push(0.5))
    assert not _enabled(link, 0) and loop.status.suspended


def test_the_simulated_operator_holding_the_enable_from_its_start_still_drives_the_loop(with_operator):
    # It sits down (its first read idle, the enable released), then presses the dead-man.
    clock = Clock()
    link = FakeLink(clock)
    device = SimulatedInput.from_settings(with_operator(sim_seed=2), clock=clock).connect()
    loop = OperatorLoop(link, device, load_settings(), clock=clock)
    _run(clock, loop, 0.2)
    enabled = _enabled(link, 0)
    assert enabled and link.sent[0][2] is enabled[0]  # its first follow already enabled
