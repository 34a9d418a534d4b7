"""``haptics operate`` on screen holds the log from before its sockets connect, so a refused handshake
(said as they connect) reaches the console's notices instead of being covered by the screen."""

from __future__ import annotations

import asyncio
import logging
import sys

from support.operator_fakes import ConsoleLink, until

from haptics.console import OperatorConsole
from haptics.inputs.keyboard import KeyboardInput
from haptics.operator_link import OperatorLink
from haptics.operator_loop import OperatorLoop
from teleop.settings import load_settings

REFUSED = "handshake on tcp://127.0.0.1:6650 failed: the peer at tcp://127.0.0.1:6650 runs CURVE and this process runs none"


def _endpoints() -> list[str]:
    from teleop.system.live_system import free_ports

    names = ("--robot-pub", "--estimate-pub", "--command", "--display-pub")
    return [a for name, port in zip(names, free_ports(4), strict=True) for a in (name, f"tcp://127.0.0.1:{port}")]


def test_a_warning_logged_as_the_link_connects_reaches_the_screen(monkeypatch, capsys):
    from haptics.cli import main

    connect = OperatorLink.from_settings

    def connect_and_refuse(bus):  # the handshake watcher says it as the sockets connect
        logging.getLogger("teleop.bus.handshakes").warning("%s", REFUSED)
        return connect(bus)

    shown: list[str] = []

    def run_screen(app, **_options):  # what the screen shows as it opens
        shown.append(app.log_note)

    monkeypatch.setattr(OperatorLink, "from_settings", staticmethod(connect_and_refuse))
    monkeypatch.setattr(OperatorConsole, "run", run_screen)
    monkeypatch.setattr(sys.stdin, "isatty", lambda: True, raising=False)
    monkeypatch.setattr(sys.stdout, "isatty", lambda: True, raising=False)
    root_handlers = logging.getLogger().handlers[:]
    assert main(["operate", "--input", "sim", "--duration-s", "0.2", *_endpoints()]) == 0
    assert shown == [f"warning: {REFUSED}"]
    assert logging.getLogger().handlers == root_handlers  # the held log is taken down again


def test_a_warning_held_before_the_screen_exists_shows_in_its_notices():
    from haptics.operate_cli import _held_log

    async def session(held) -> OperatorConsole:
        with KeyboardInput() as keyboard:
            app = OperatorConsole(OperatorLoop(ConsoleLink(), keyboard, load_settings()), input_name="keyboard",
                                  keyboard=keyboard)
            held.attach(app)
            async with app.run_test(size=(120, 40)) as pilot:
                await until(lambda: REFUSED in app.texts.get("notice", ""), pilot)
                await pilot.press("q")
                await until(lambda: app.exit_status is not None, pilot)
        return app

    with _held_log() as held:
        logging.getLogger("teleop.bus.handshakes").warning("%s", REFUSED)  # no screen yet
        assert asyncio.run(session(held)).exit_status.quit
    assert [r.getMessage() for r in held.records] == [REFUSED]  # printed after the screen closes, too
