"""The console's safety keys (s, r, e, q) reach the robot whatever has the focus, and ctrl+p opens no
command palette over the status (textual's pilot against a fake link)."""

from __future__ import annotations

import asyncio

import pytest
from support.operator_fakes import ConsoleLink, until
from textual.screen import ModalScreen
from textual.widgets import Input

from haptics.console import OperatorConsole
from haptics.inputs.keyboard import KeyboardInput
from haptics.operator_link import Peer
from haptics.operator_loop import OperatorLoop
from teleop.settings import load_settings

ALIVE = (Peer("robot node", "robot", True, 0.1), Peer("estimator", "estimator", True, 0.1),
         Peer("display", "renderer", True, 0.1))


class SearchBox(ModalScreen):
    """An overlay with a focused line that would take letters as typing."""

    AUTO_FOCUS = "#search"

    def compose(self):
        yield Input(id="search")


def test_ctrl_p_opens_no_palette_and_s_e_q_still_stop_and_quit_over_a_focused_line():
    link = ConsoleLink(ALIVE)

    async def session() -> OperatorConsole:
        with KeyboardInput(grip_step=0.25) as keyboard:
            app = OperatorConsole(OperatorLoop(link, keyboard, load_settings(), force_n=10.0),
                                  input_name="keyboard", keyboard=keyboard)
            async with app.run_test(size=(80, 24)) as pilot:
                await pilot.press("e", "up", "up")
                await until(lambda: any(body["enable"] for kind, body in link.sent if kind == "follow"), pilot)
                await pilot.press("ctrl+p")  # squeezing: no search box comes over the status
                await pilot.pause(0.1)
                assert len(app.screen_stack) == 1 and app.focused is None
                await pilot.press("s")
                await until(lambda: "stop" in link.kinds(), pilot)
                assert not keyboard.read(timeout_s=0).enable
                # Even with an overlay's line focused, the keys are the console's: e drives again, s stops.
                await app.push_screen(SearchBox())
                await until(lambda: isinstance(app.focused, Input), pilot)
                await pilot.press("e")
                await until(lambda: keyboard.read(timeout_s=0).enable, pilot)
                await pilot.press("s")
                await until(lambda: link.kinds().count("stop") == 2, pilot)
                assert app.screen.query_one("#search", Input).value == ""
                await pilot.press("q")
                await until(lambda: app.exit_status is not None, pilot)
        return app

    app = asyncio.run(session())
    assert app.exit_status.quit


@pytest.mark.slow
def test_the_label_line_still_takes_the_safety_keys_as_letters():
    link = ConsoleLink(ALIVE)

    async def session() -> None:
        with KeyboardInput() as keyboard:
            loop = OperatorLoop(link, keyboard, load_settings(), force_n=10.0)
            app = OperatorConsole(loop, input_name="keyboard", keyboard=keyboard)
            async with app.run_test(size=(80, 24)) as pilot:
                await pilot.press("g")
                await until(lambda: loop.status.label_grasp_id is not None, pilot)
                await pilot.press("l", *"rose quartz")
                line = app.query_one("#label", Input)
                await until(lambda: line.value == "rose quartz", pilot)
                assert app.labelling is not None and link.kinds() == ["start_grasp"]
                assert not keyboard.read(timeout_s=0).enable
                await pilot.press("escape", "q")
                await until(lambda: app.exit_status is not None, pilot)

    asyncio.run(session())
