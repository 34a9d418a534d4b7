"""The operator console (:mod:`haptics.console`): driven by textual's pilot against a fake link."""

from __future__ import annotations

import asyncio
import dataclasses
import json
import logging
import threading
import time

import pytest
from support.operator_fakes import NOBODY, ConsoleLink, until

from haptics import console
from haptics.console import OperatorConsole, estimate_line, squeeze_hint
from haptics.inputs import OperatorInput
from haptics.inputs.keyboard import KeyboardInput
from haptics.mapping import EstimateUpdate
from haptics.operator_link import OperatorView, Peer
from haptics.operator_loop import OperatorLoop
from haptics.operator_status import LoopStatus
from teleop.bus.messages import DisplayBody, EstimateBody, RobotNoticeBody, RobotStateBody
from teleop.settings import load_settings

ESTIMATE = EstimateBody(grasp_id="g", method="hybrid", E_pa=3.6e6, interval_pa=[2.0e6, 6.0e6], state="ok",
                        reason="loading phase 0.12-0.41 s (the first squeeze)", provisional=False, latency_s=0.01)
DISPLAY = DisplayBody(grasp_id="g", phase="active", stiffness=0.87, uncertainty_decades=0.3, rigid=False,
                      unknown=False, provisional=False, E_pa=3.6e6, level=55, level_max=63)


class Still:
    """An input device nobody touches."""

    waits_for_robot = False

    def read(self, *, timeout_s):
        return OperatorInput(t_s=time.monotonic(), grip=0.0, enable=False)

    def feel(self, **_):
        pass


def unrun_console() -> OperatorConsole:
    """A console that is not run, for :meth:`OperatorConsole.render_status`."""
    return OperatorConsole(OperatorLoop(ConsoleLink(), Still(), load_settings(), force_n=10.0), input_name="gamepad")


def test_estimates_and_moduli_read_as_people_write_them():
    assert estimate_line(None) == "no estimate yet"
    assert estimate_line(ESTIMATE) == "E = 3.6 MPa  interval [2 MPa, 6 MPa]  ok  final"
    bound = dataclasses.replace(ESTIMATE, state="lower_bound", E_pa=6.75e6, interval_pa=[6.75e6, None], provisional=True)
    assert estimate_line(bound) == "E >= 6.75 MPa  interval [6.75 MPa, -]  lower_bound  provisional"
    steel = dataclasses.replace(ESTIMATE, E_pa=2e11, interval_pa=[9.9996e8, 1e12])  # the model's cap: 1 TPa
    assert estimate_line(steel) == "E = 200 GPa  interval [1 GPa, 1 TPa]  ok  final"
    none = dataclasses.replace(ESTIMATE, state="insufficient_data", E_pa=None, interval_pa=[None, None])
    assert estimate_line(none) == "no modulus (insufficient data)  final"


def test_a_bound_without_a_modulus_reads_as_the_bound_the_display_renders():
    bound = dataclasses.replace(ESTIMATE, state="lower_bound", E_pa=None, interval_pa=[1e6, None])
    assert estimate_line(bound) == "E >= 1 MPa  interval [1 MPa, -]  lower_bound  final"
    update = EstimateUpdate.from_estimate(bound, 0.0)
    assert update.value_pa == 1e6  # what the renderer maps
    upper = dataclasses.replace(ESTIMATE, state="upper_bound", E_pa=None, interval_pa=[None, 2e4])
    assert estimate_line(upper) == "E <= 20 kPa  interval [-, 20 kPa]  upper_bound  final"


def test_a_final_answer_too_wide_to_place_asks_for_a_firmer_squeeze():
    assert squeeze_hint(ESTIMATE) is None  # 0.48 decade: placed on the display's scale
    one_decade = dataclasses.replace(ESTIMATE, E_pa=3e6, interval_pa=[1e6, 1e7])
    assert squeeze_hint(one_decade) is None  # a hint only for an interval wider than one decade
    assert squeeze_hint(dataclasses.replace(one_decade, interval_pa=[1e6, 1.1e7])) is not None
    wide = dataclasses.replace(ESTIMATE, E_pa=3e4, interval_pa=[5e3, 2e5])
    assert squeeze_hint(wide) == "wide interval (1.6 decades): a firmer squeeze reads surer"
    assert squeeze_hint(dataclasses.replace(wide, provisional=True)) is None  # still squeezing
    assert squeeze_hint(dataclasses.replace(wide, state="lower_bound", interval_pa=[5e3, None])) is None
    assert squeeze_hint(None) is None
    # A grasp that stopped short of the maximum force is told how much firmer it may go; one that
    # reached it is not asked for what it cannot do.
    assert squeeze_hint(wide, peak_force_n=12.4, max_force_n=30.0) == (
        "wide interval (1.6 decades) after a 12 N squeeze: a firmer one (up to 30 N) reads surer")
    assert squeeze_hint(wide, peak_force_n=29.0, max_force_n=30.0) is None
    assert squeeze_hint(wide, peak_force_n=27.0, max_force_n=30.0) is None  # 90 % of it is the full squeeze
    assert squeeze_hint(wide, peak_force_n=26.9, max_force_n=30.0) is not None


def test_a_panel_is_cut_only_when_its_lines_outnumber_the_rows_and_a_cut_line_keeps_the_width():
    assert console._fit("robot: no notice\nlast: -", 40, 2) == "robot: no notice\nlast: -"
    fitted = console._fit("\n".join(["x" * 30, "y" * 30, "z" * 30]), 10, 2).splitlines()
    # The ellipsis takes the last column: a wider line would wrap in the panel, pushing a line off it.
    assert fitted == ["x" * 10, "x" * 9 + "\u2026"]


def _line(texts: dict[str, str], panel: str, start: str) -> str:
    return next(line for line in texts[panel].splitlines() if line.startswith(start))


def test_the_force_bar_is_a_share_of_the_gripper_maximum_and_never_overflows():
    app = unrun_console()
    max_force = app.loop.settings.gripper.target_force_n

    def bar(force_n: float) -> str:
        return _line(app.render_status(LoopStatus(view=OperatorView(t_s=0.0, force_n=force_n))), "grasp", "force")

    assert bar(max_force / 2).startswith("force  [" + "#" * 8 + "-" * 8 + "]")
    assert bar(max_force * 1.5).startswith("force  [" + "#" * 16 + "]")
    assert bar(-2.0).startswith("force  [" + "-" * 16 + "]")  # a sensor's offset at rest


def test_the_notice_that_ended_the_grasp_is_not_shown_twice():
    notice = RobotNoticeBody(event="watchdog", action="follow", grasp_id="g1",
                             reason="no follow command for 0.210 s (watchdog 0.2 s): the fingers stopped")
    view = OperatorView(t_s=10.0, grasp_id="g1", notice=notice, notice_t_s=9.0, ended_by=notice, ended_by_t_s=9.0)
    assert unrun_console().render_status(LoopStatus(view=view))["notice"].count("the fingers stopped") == 1


def test_a_fading_display_reads_as_fading_not_as_a_modulus():
    # The service still sends the E_pa its falling stiffness maps to: no modulus stands for the level.
    fading = dataclasses.replace(DISPLAY, phase="fading", stiffness=0.4, E_pa=1.2e5, level=25)
    texts = unrun_console().render_status(LoopStatus(view=OperatorView(t_s=0.0, grasp_id="g", display=fading)))
    assert texts["display"].splitlines()[0] == "fading to free (the grasp ended)  level 25/63"


def test_a_session_with_the_keyboard_in_the_console():
    settings = load_settings()
    link = ConsoleLink()

    async def session() -> OperatorConsole:
        with KeyboardInput(grip_step=0.25) as keyboard:
            loop = OperatorLoop(link, keyboard, settings, force_n=10.0)
            app = OperatorConsole(loop, input_name="keyboard", keyboard=keyboard)
            async with app.run_test(size=(120, 40)) as pilot:
                await until(lambda: "DOWN  robot node" in app.texts.get("alive", ""), pilot)
                assert "no estimate yet" in app.texts["estimate"] and "up/k squeeze" in str(
                    app.query_one("#keys").render())
                # Nothing running but the console: it says why no estimate and no rendering will come.
                assert "the estimator is down" in app.texts["estimate"]
                assert "the renderer is down" in app.texts["display"]
                # a discrete grasp at the chosen force, raised by one newton with "+", lowered by one with "-"
                await pilot.press("plus", "plus", "minus", "g")
                await until(lambda: "start_grasp" in link.kinds(), pilot)
                assert link.sent[-1][1]["target_force_n"] == 11.0
                grasp_id = link.sent[-1][1]["grasp_id"]
                peers = (Peer("robot node", "robot", True, 0.1), Peer("estimator", "estimator", True, 0.2),
                         Peer("display", "renderer", False, 4.0))
                link.view = OperatorView(t_s=time.monotonic(), peers=peers, grasp_id=grasp_id, phase="loaded",
                                         object_name="rubber_duck", force_n=11.0, width_m=0.0312,
                                         robot=RobotStateBody(mode="holding", grasp_id=grasp_id, enable=False),
                                         estimate=dataclasses.replace(ESTIMATE, grasp_id=grasp_id), estimates=7,
                                         display=DISPLAY,
                                         notice=RobotNoticeBody(event="refused", action="follow", grasp_id=grasp_id,
                                                                reason="a discrete grasp is under way"),
                                         notice_t_s=time.monotonic())
                await until(lambda: "E = 3.6 MPa" in app.texts["estimate"], pilot)
                texts = app.texts
                assert "UP    robot node" in texts["alive"] and "DOWN  display" in texts["alive"]
                assert "is down" not in texts["estimate"]  # an estimate came
                # A rendering came too, but the renderer is down since: its last report is not current.
                assert "the renderer is down: its last report below is not current" in texts["display"]
                assert "rubber_duck" in texts["grasp"] and "31.2 mm" in texts["grasp"] and "11.0 N" in texts["grasp"]
                assert "loading phase 0.12-0.41 s" in texts["estimate"] and "7 estimate(s)" in texts["estimate"]
                assert "stiffness 0.87 of range" in texts["display"] and "level 55/63" in texts["display"]
                # uncertainty_decades is the interval's whole width: not a +/- (which would read twice as wide)
                assert "interval 0.30 decades wide" in texts["display"] and "+/-" not in texts["display"]
                assert "refused" in texts["notice"] and "a discrete grasp is under way" in texts["notice"]
                assert "mode discrete" in texts["input"]
                await pilot.press("r")
                await until(lambda: link.kinds()[-1] == "release", pilot)
                assert link.sent[-1][1]["grasp_id"] == grasp_id
                # leader-follower: squeeze two steps, hold the enable: follows at the grip's width
                link.view = dataclasses.replace(link.view, phase="ended")
                await pilot.press("up", "up", "e")
                await until(lambda: link.follows_sent >= 10, pilot)
                follow = link.sent[-1][1]
                assert follow["enable"] and follow["target_width_m"] == pytest.approx(0.04)
                assert "enable HELD" in app.texts["input"] and "mode follow" in app.texts["input"]
                await pilot.press("e")  # let go
                await until(lambda: link.sent[-1][1].get("enable") is False, pilot)
                await pilot.press("n", "q")
                await until(lambda: app.exit_status is not None, pilot)
        return app

    app = asyncio.run(session())
    assert app.exit_status.quit and "clear" in link.kinds()
    assert app._thread is not None and not app._thread.is_alive()


def test_other_inputs_still_take_the_buttons_and_q_or_ctrl_c_quits():
    settings = load_settings()
    link = ConsoleLink()

    async def session() -> OperatorConsole:
        loop = OperatorLoop(link, Still(), settings)
        app = OperatorConsole(loop, input_name="gamepad")
        async with app.run_test(size=(100, 30)) as pilot:
            await pilot.press("g", "s")
            await until(lambda: link.kinds() == ["start_grasp", "stop"], pilot)
            assert "gamepad input drives grip and enable" in str(app.query_one("#keys").render())
            await pilot.press("q")
            await until(lambda: app.exit_status is not None, pilot)
        return app

    assert asyncio.run(session()).exit_status.quit

    async def interrupted() -> OperatorConsole:
        app = OperatorConsole(OperatorLoop(ConsoleLink(), Still(), settings), input_name="gamepad")
        async with app.run_test(size=(80, 24)) as pilot:
            await pilot.press("ctrl+c")
            await until(lambda: app.exit_status is not None, pilot)
        return app

    assert asyncio.run(interrupted()).exit_status.quit


def test_q_quits_a_console_whose_loop_stopped():
    class BrokenLink(ConsoleLink):
        def poll(self, timeout_s: float = 0.0) -> int:
            raise RuntimeError("the link broke")

    async def session() -> OperatorConsole:
        app = OperatorConsole(OperatorLoop(BrokenLink(), Still(), load_settings()), input_name="gamepad")
        async with app.run_test(size=(100, 30)) as pilot:
            await until(lambda: "(q quits)" in app.texts.get("notice", ""), pilot)
            await pilot.press("q")
            await until(lambda: app.exit_status is not None, pilot)
        return app

    assert asyncio.run(session()).exit_status is not None


def test_a_warning_logged_while_the_screen_runs_shows_in_the_notices():
    from haptics.operate_cli import _HeldLog

    refused = "CURVE handshake with tcp://127.0.0.2:6650 refused (the server does not authorise this client's key)"

    async def session() -> OperatorConsole:
        with KeyboardInput() as keyboard:
            app = OperatorConsole(OperatorLoop(ConsoleLink(), keyboard, load_settings()), input_name="keyboard",
                                  keyboard=keyboard)
            held = _HeldLog(app)
            async with app.run_test(size=(120, 40)) as pilot:
                held.handle(logging.LogRecord("teleop.bus.handshakes", logging.INFO, "", 0, "heard", (), None))
                # the handshake watcher logs from its own thread
                threading.Thread(target=held.handle, args=(logging.LogRecord(
                    "teleop.bus.handshakes", logging.WARNING, "", 0, "%s", (refused,), None),)).start()
                await until(lambda: refused in app.texts.get("notice", ""), pilot)
                assert "heard" not in app.texts["notice"]  # info stays in the held log alone
                await pilot.press("q")
                await until(lambda: app.exit_status is not None, pilot)
        assert [r.getMessage() for r in held.records] == ["heard", refused]  # still printed after the quit
        return app

    assert asyncio.run(session()).exit_status.quit


# --------------------------------------------------------------------------- the command


def _endpoints() -> list[str]:
    from teleop.system.live_system import free_ports

    names = ("--robot-pub", "--estimate-pub", "--command", "--display-pub")
    return [a for name, port in zip(names, free_ports(4), strict=True) for a in (name, f"tcp://127.0.0.1:{port}")]


def test_operate_headless_with_the_simulated_operator(capsys):
    from haptics.cli import main

    assert main(["operate", "--headless", "--input", "sim", "--duration-s", "0.6", "--json", *_endpoints()]) == 0
    out = capsys.readouterr().out.strip().splitlines()
    result = json.loads(out[-1])
    # nobody listening: the simulated operator waits for the robot node and says so
    assert result["input"] == "sim" and result["follows_sent"] == 0 and result["problem"] is None
    assert "waiting for the robot node" in out[0]


def test_operate_refuses_a_force_beyond_the_maximum_a_missing_terminal_and_headless_keys(capsys):
    from haptics.cli import main

    assert main(["operate", "--headless", "--force", "80", *_endpoints()]) == 2
    assert "--force 80: expected a force in (0, 30] N" in capsys.readouterr().err
    assert main(["operate", "--input", "keyboard", *_endpoints()]) == 2  # pytest's stdin is no terminal
    assert "needs a terminal" in capsys.readouterr().err
    assert main(["operate", "--headless", *_endpoints()]) == 2  # the settings' input: the keyboard
    assert "--input keyboard reads the console's own keys" in capsys.readouterr().err


# --------------------------------------------------------------------------- labels


class LabellingLink(ConsoleLink):
    def label(self, grasp_id, object_name, *, modulus_pa=None, source, detail=""):
        self._command("label", grasp_id=grasp_id, object_name=object_name, modulus_pa=modulus_pa, source=source,
                      detail=detail)


@pytest.mark.slow
def test_l_labels_the_grasp_from_the_catalogue_or_a_shore_reading():
    from teleop.catalogue import load_catalogue
    from teleop.labels import shore_to_modulus_pa

    settings = load_settings()
    link = LabellingLink()
    catalogue = load_catalogue()

    async def session() -> OperatorConsole:
        with KeyboardInput(grip_step=0.25) as keyboard:
            loop = OperatorLoop(link, keyboard, settings, force_n=10.0)
            app = OperatorConsole(loop, input_name="keyboard", keyboard=keyboard, catalogue=catalogue,
                                  catalogue_name="objects.toml")
            async with app.run_test(size=(120, 44)) as pilot:
                await until(lambda: "label  - (l names the object)" in app.texts.get("grasp", ""), pilot)
                await pilot.press("l")  # nothing grasped yet: nothing to label
                await until(lambda: "no grasp to label yet" in app.texts["notice"], pilot)
                assert app.labelling is None
                await pilot.press("g")
                await until(lambda: "start_grasp" in link.kinds(), pilot)
                grasp_id = link.sent[-1][1]["grasp_id"]
                link.view = OperatorView(t_s=time.monotonic(), peers=NOBODY, grasp_id=grasp_id, phase="loaded")
                await until(lambda: loop.status.label_grasp_id == grasp_id, pilot)
                # the note said with no grasp in view is not about this one
                await until(lambda: "no grasp to label yet" not in app.texts["notice"], pilot)
                # the catalogue's name, typed in part and completed with the suggestion; letters that are
                # keys (g grasp, r release, e enable, q quit) go to the line, not to the robot
                await pilot.press("l")
                line = app.query_one("#label")
                assert app.labelling == grasp_id and line.has_focus and grasp_id in line.border_title
                await pilot.press(*"stress_b")
                await until(lambda: line._suggestion == "stress_ball", pilot)
                await pilot.press("right", "enter")
                await until(lambda: "label" in link.kinds(), pilot)
                kind, body = link.sent[-1]
                assert body["grasp_id"] == grasp_id and body["object_name"] == "stress_ball"
                assert body["modulus_pa"] == 4.0e4 and body["source"] == "catalogue"
                assert link.kinds().count("start_grasp") == 1 and "release" not in link.kinds()
                assert not keyboard.read(timeout_s=0).enable and app.labelling is None
                await until(lambda: "stress_ball  E 40 kPa  (catalogue)" in app.texts["grasp"], pilot)
                # a Shore reading out of range stays on the line with the reason; a good one goes out
                await pilot.press("l", *"gel pad shore 00 20", "enter")
                await until(lambda: "Shore 00 20 is outside 45 to 90" in str(line.border_subtitle), pilot)
                await until(lambda: "Shore 00 20 is outside 45 to 90" in app.texts["notice"], pilot)  # whole
                assert app.labelling == grasp_id and link.kinds().count("label") == 1
                line.value = ""
                await pilot.press(*"gel pad shore 00 70", "enter")
                await until(lambda: link.kinds().count("label") == 2, pilot)
                body = link.sent[-1][1]
                assert body["source"] == "durometer" and "Shore 00 70" in body["detail"]
                assert body["modulus_pa"] == pytest.approx(shore_to_modulus_pa(70, "00"))
                await until(lambda: "gel pad  E 732 kPa  (durometer)" in app.texts["grasp"], pilot)
                # after "next" the last grasp is still the one labelled; escape closes the line unsent
                link.view = dataclasses.replace(link.view, phase="ended")  # over (no estimator): "next" need not wait
                await pilot.press("n")
                await until(lambda: "clear" in link.kinds(), pilot)
                await pilot.press("l", "x", "escape")
                assert app.labelling is None and link.kinds().count("label") == 2
                await until(lambda: f"label  {grasp_id}: gel pad  E 732 kPa" in app.texts["grasp"], pilot)
                await pilot.press("q")
                await until(lambda: app.exit_status is not None, pilot)
        return app

    app = asyncio.run(session())
    assert app.exit_status.quit and [label.object_name for label in app.exit_status.labels.values()] == ["gel pad"]
