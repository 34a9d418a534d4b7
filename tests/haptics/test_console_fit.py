"""The operator console on an 80x24 terminal, a dead estimator, the watchdog and the keyboard's toggle,
and on a tall terminal (textual's pilot against a fake link)."""

from __future__ import annotations

import asyncio
import time

import pytest
from support.operator_fakes import ConsoleLink, until

from haptics.console import OperatorConsole
from haptics.inputs.keyboard import KeyboardInput
from haptics.operator_link import OperatorView, Peer
from haptics.operator_loop import OperatorLoop
from teleop.bus.messages import EstimateBody, RobotNoticeBody, RobotStateBody
from teleop.errors import BusError
from teleop.settings import load_settings

ALIVE = (Peer("robot node", "robot", True, 0.1), Peer("estimator", "estimator", False, 4.0),
         Peer("display", "renderer", True, 0.1))
REASON = ("loading phase 0.12-0.41 s of the monotone envelope from contact to the peak, back-offs and pauses "
          "skipped, frames sampled by approach rather than time; the hybrid's CNN and the analytical fits agree")


def loading_view(peers: tuple[Peer, ...], reason: str) -> OperatorView:
    """Grasp op-1 loading, with a provisional hybrid estimate that gives ``reason``."""
    return OperatorView(
        t_s=time.monotonic(), peers=peers, grasp_id="op-1", phase="loading",
        estimate=EstimateBody(grasp_id="op-1", method="hybrid", E_pa=1.3e5, interval_pa=[6.5e4, 2.6e5],
                              state="ok", reason=reason, provisional=True, latency_s=0.01),
        estimates=3)


@pytest.mark.slow
def test_at_80x24_the_estimate_notices_and_keys_fit_and_the_toggle_tells_the_truth():
    link = ConsoleLink(ALIVE)

    async def session() -> None:
        with KeyboardInput(grip_step=0.25) as keyboard:
            loop = OperatorLoop(link, keyboard, load_settings(), force_n=10.0)
            app = OperatorConsole(loop, input_name="keyboard", keyboard=keyboard)
            async with app.run_test(size=(80, 24)) as pilot:
                await pilot.press("up", "up", "e")
                await until(lambda: link.follows_sent >= 5, pilot)
                grasp_id = link.sent[-1][1]["grasp_id"]
                watchdog = RobotNoticeBody(event="watchdog", action="follow", grasp_id=grasp_id,
                                           reason="no follow command for 0.210 s (watchdog 0.2 s): the fingers stopped")
                refusal = RobotNoticeBody(event="refused", action="follow", grasp_id=grasp_id,
                                          reason=f"grasp '{grasp_id}' has ended: name a new grasp to start one")
                now = time.monotonic()
                link.view = OperatorView(
                    t_s=now, peers=ALIVE, grasp_id=grasp_id, phase="ended", object_name="silicone_ball",
                    robot=RobotStateBody(mode="stopped", enable=False), force_n=0.0, width_m=0.03,
                    estimate=EstimateBody(grasp_id=grasp_id, method="hybrid", E_pa=1.3e5, interval_pa=[6.5e4, 2.6e5],
                                          state="ok", reason=REASON, provisional=True, latency_s=0.01),
                    estimates=40, notice=refusal, notice_t_s=now, ended_by=watchdog, ended_by_t_s=now - 0.1)
                # The robot ended the grasp: the toggle is let go with it, and the screen says so.
                await until(lambda: "enable off" in app.texts["input"], pilot)
                await pilot.pause(0.2)
                assert "suspended" not in app.texts["input"]
                # A dead estimator is named where its estimate is.
                assert "the estimator is down: not current" in app.texts["estimate"]
                # Everything fits the screen: the notices (the watchdog whole) and the keys.
                screen = app.screen.region
                for name in ("estimate", "notice", "keys"):
                    widget = app.query_one(f"#{name}")
                    assert screen.contains_region(widget.region), (name, widget.region)
                # ... and the text in them: every line of the operator's panel (the grasp force +/- sets),
                # the keys within 80 columns.
                panel = app.query_one("#input")
                assert len(app.drawn["input"].splitlines()) <= panel.content_size.height, app.drawn["input"]
                assert "grasp force 10 N" in app.drawn["input"]
                assert all(len(line) <= 78 for line in app.query_one("#keys").render().plain.splitlines())
                notices = " ".join(app.drawn["notice"].split())
                assert "watchdog" in notices and "the fingers stopped" in notices
                # ... the refusal after it begun, cut to the panel's rows where they end, saying so
                assert "robot refused follow" in notices and notices.endswith("\u2026")
                assert len(app.drawn["notice"].splitlines()) <= app.query_one("#notice").content_size.height
                assert len(app.drawn["estimate"].splitlines()) <= 4 and app.drawn["estimate"].endswith("\u2026")
                # One e drives again, under a new grasp.
                sent = len(link.sent)
                await pilot.press("e")
                await until(lambda: any(b["enable"] for k, b in link.sent[sent:] if k == "follow"), pilot)
                await until(lambda: "enable HELD" in app.texts["input"], pilot)
                assert link.sent[-1][1]["grasp_id"] not in (grasp_id, None)
                await pilot.press("q")
                await until(lambda: app.exit_status is not None, pilot)

    asyncio.run(session())


def test_a_long_reason_leaves_the_operator_and_notices_on_a_100x32_screen():
    idle = (Peer("robot node", "robot", True, 0.1), Peer("estimator", "estimator", True, 0.1),
            Peer("display", "renderer", True, 0.1))
    link = ConsoleLink(idle)

    async def session() -> None:
        with KeyboardInput() as keyboard:
            app = OperatorConsole(OperatorLoop(link, keyboard, load_settings()), input_name="keyboard",
                                  keyboard=keyboard)
            async with app.run_test(size=(100, 32)) as pilot:
                link.view = loading_view(idle, " ".join([REASON] * 4))
                await until(lambda: "reason" in app.texts.get("estimate", ""), pilot)
                await pilot.pause(0.2)
                screen = app.screen.region
                for name in ("input", "notice", "keys"):
                    assert screen.contains_region(app.query_one(f"#{name}").region), name
                await pilot.press("q")
                await until(lambda: app.exit_status is not None, pilot)

    asyncio.run(session())


def test_a_tall_terminal_shows_the_whole_estimate():
    link = ConsoleLink(ALIVE)
    reason = "; ".join(f"reason part {n} of a long explanation" for n in range(8))

    async def session() -> str:
        with KeyboardInput() as keyboard:
            app = OperatorConsole(OperatorLoop(link, keyboard, load_settings()), input_name="keyboard",
                                  keyboard=keyboard)
            async with app.run_test(size=(100, 60)) as pilot:
                link.view = loading_view(ALIVE, reason)
                await until(lambda: "reason part 7" in app.texts.get("estimate", ""), pilot)
                await pilot.pause(0.2)
                drawn = app.drawn["estimate"]
                await pilot.press("q")
                await until(lambda: app.exit_status is not None, pilot)
        return drawn

    drawn = asyncio.run(session())  # on a terminal of 50 rows or more, the panel is not cut to 4 lines
    assert "\u2026" not in drawn and "reason part 7" in drawn.replace("\n", " ")


class DeafLink(ConsoleLink):
    """A link whose commands cannot be sent (the robot node went away)."""

    def start_grasp(self, *, target_force_n, grasp_id=None):
        raise BusError("no robot node subscribes to the commands: a start_grasp now would reach no one")


def test_at_80x24_the_notices_show_the_current_problem_first_and_say_where_they_are_cut():
    link = DeafLink(ALIVE)

    async def session() -> None:
        with KeyboardInput() as keyboard:
            app = OperatorConsole(OperatorLoop(link, keyboard, load_settings(), force_n=10.0), input_name="keyboard",
                                  keyboard=keyboard)
            async with app.run_test(size=(80, 24)) as pilot:
                now = time.monotonic()
                refusal = RobotNoticeBody(event="refused", action="follow", grasp_id="op-1", reason=" ".join(
                    ["grasp 'op-1' has ended: name a new grasp to start one"] * 3))
                watchdog = RobotNoticeBody(event="watchdog", action="follow", grasp_id="op-1",
                                           reason="no follow command for 0.610 s (watchdog 0.2 s): the fingers stopped")
                link.view = OperatorView(t_s=now, peers=ALIVE, grasp_id="op-1", phase="ended", notice=refusal,
                                         notice_t_s=now - 5.0, ended_by=watchdog, ended_by_t_s=now - 5.1)
                await pilot.press("e", "e", "g")
                await until(lambda: "problem:" in app.texts.get("notice", ""), pilot)
                await pilot.pause(0.2)
                panel = app.query_one("#notice")
                drawn = app.drawn["notice"].splitlines()
                # What is wrong now leads, the old refusal gives way, and the cut says so.
                assert drawn[0].startswith("problem: not sent (bus)"), drawn
                assert len(drawn) <= panel.content_size.height and drawn[-1].endswith("\u2026"), drawn
                # The operator's actions newest first: the failed grasp before the enable's toggles.
                last = next(line for line in app.texts["notice"].splitlines() if line.startswith("last: "))
                assert last.index("a start_grasp now would reach no one") < last.index("enable")
                await pilot.press("q")
                await until(lambda: app.exit_status is not None, pilot)

    asyncio.run(session())
