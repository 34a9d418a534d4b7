"""The operator console in a terminal smaller than its layout (80x24): a line at the top keeps the
dead-man enable and the mode in sight; at 80x24 the label line shows what is typed (textual's pilot
against a fake link)."""

from __future__ import annotations

import asyncio
import re
import time

import pytest
from support.operator_fakes import ConsoleLink, until

from haptics.console import OperatorConsole
from haptics.inputs.keyboard import KeyboardInput
from haptics.operator_link import OperatorView, Peer
from haptics.operator_loop import OperatorLoop
from teleop.settings import load_settings


@pytest.mark.slow
@pytest.mark.parametrize("size", [(60, 20), (40, 12), (20, 5), (80, 24)])
def test_a_small_terminal_shows_the_enable_and_mode_on_a_line_at_the_top(size):
    link = ConsoleLink((Peer("robot node", "robot", True, 0.1, subscribed=True),))  # heard: the enable drives

    async def session() -> None:
        with KeyboardInput(grip_step=0.25) as keyboard:
            loop = OperatorLoop(link, keyboard, load_settings(), force_n=10.0)
            app = OperatorConsole(loop, input_name="keyboard", keyboard=keyboard)
            async with app.run_test(size=size) as pilot:
                await pilot.pause(0.2)
                banner = app.query_one("#small")
                if size == (80, 24):  # the layout fits: no line
                    assert not banner.display and app.small_line == ""
                    await pilot.press("q")
                    await until(lambda: app.exit_status is not None, pilot)
                    return
                await until(lambda: "enable off" in app.small_line, pilot)
                width, height = size
                assert f"terminal {width}x{height}: 80x24 needed" in app.small_line and "mode idle" in app.small_line
                assert banner.display and banner.region.y == 0 and banner.region.height >= 1
                assert app.screen.region.contains_region(banner.region)
                assert app.screen.get_widget_at(0, 0)[0] is banner  # on top: the keys' legend does not cover it
                await pilot.press("e")  # the dead-man toggled on: the line says so
                await until(lambda: "enable HELD, mode follow" in app.small_line, pilot)
                await pilot.press("e")
                await until(lambda: "enable off" in app.small_line, pilot)
                await pilot.press("q")
                await until(lambda: app.exit_status is not None, pilot)

    asyncio.run(session())


def test_a_robot_node_heard_but_not_yet_hearing_the_console_is_shown_waiting_and_fits():
    link = ConsoleLink((Peer("robot node", "robot", True, 0.1, subscribed=False),
                        Peer("estimator", "estimator", True, 0.2), Peer("display", "renderer", True, 0.3)))

    async def session() -> None:
        with KeyboardInput(grip_step=0.25) as keyboard:
            loop = OperatorLoop(link, keyboard, load_settings(), force_n=10.0)
            app = OperatorConsole(loop, input_name="keyboard", keyboard=keyboard)
            async with app.run_test(size=(80, 24)) as pilot:
                await until(lambda: "WAIT  robot node" in app.texts.get("alive", ""), pilot)
                assert "not subscribed yet" in app.texts["alive"] and "UP    estimator" in app.texts["alive"]
                panel = app.query_one("#alive")
                assert all(len(line) <= panel.content_region.width for line in app.texts["alive"].splitlines())
                await pilot.press("q")
                await until(lambda: app.exit_status is not None, pilot)

    asyncio.run(session())


@pytest.mark.slow
def test_at_80x24_the_label_line_shows_what_is_typed_and_the_suggestion():
    # Labels become retraining data: the operator must see what is typed, on a screen that does not scroll.
    from teleop.bus.messages import DisplayBody, EstimateBody
    from teleop.catalogue import load_catalogue

    link = ConsoleLink()

    async def session() -> None:
        with KeyboardInput(grip_step=0.25) as keyboard:
            loop = OperatorLoop(link, keyboard, load_settings(), force_n=10.0)
            app = OperatorConsole(loop, input_name="keyboard", keyboard=keyboard, catalogue=load_catalogue())
            async with app.run_test(size=(80, 24)) as pilot:
                await pilot.press("g")
                await until(lambda: "start_grasp" in link.kinds(), pilot)
                grasp_id = link.sent[-1][1]["grasp_id"]
                estimate = EstimateBody(grasp_id=grasp_id, method="hybrid", E_pa=3.6e6, interval_pa=[2.0e6, 6.0e6],
                                        state="ok", reason="loading phase 0.12-0.41 s of the monotone envelope "
                                        "from contact to the peak, back-offs and pauses skipped, frames sampled",
                                        provisional=False, latency_s=0.01)
                display = DisplayBody(grasp_id=grasp_id, phase="active", stiffness=0.87, uncertainty_decades=0.3,
                                      rigid=False, unknown=False, provisional=False, E_pa=3.6e6, level=55, level_max=63)
                link.view = OperatorView(t_s=time.monotonic(), peers=link.view.peers, grasp_id=grasp_id,
                                         phase="loaded", estimate=estimate, estimates=5, display=display, force_n=5.0,
                                         width_m=0.03)
                await until(lambda: loop.status.label_grasp_id == grasp_id and "3.6 MPa" in app.texts["estimate"],
                            pilot)
                await pilot.press("l", *"stress_b")
                line = app.query_one("#label")
                await until(lambda: line._suggestion == "stress_ball", pilot)
                await pilot.pause(0.2)
                screen = app.screen
                assert line.region.height == 3 and screen.region.contains_region(line.region)
                assert screen.max_scroll_y == 0  # nothing scrolled off, no scrollbar
                assert screen.get_widget_at(2, line.region.y + 1)[0] is line  # its text row, uncovered
                shown = "".join(re.findall(r">([^<>]*)</text>", app.export_screenshot()))  # the screen's text
                assert "stress_ball" in shown  # typed, then the suggestion
                await pilot.press("escape")
                await until(lambda: app.query_one("#keys").display, pilot)  # the keys' legend back
                await pilot.press("q")
                await until(lambda: app.exit_status is not None, pilot)

    asyncio.run(session())
