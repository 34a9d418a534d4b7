"""``haptics operate`` on screen: SIGTERM quits the console as ``q`` does (:mod:`haptics.operate_cli`)."""

from __future__ import annotations

import asyncio
import os
import signal
import time

import pytest

from haptics.operate_cli import _sigterm_quits
from teleop.clikit import Terminated


class _App:
    def __init__(self) -> None:
        self.quits = 0

    def action_quit_console(self) -> None:
        self.quits += 1


def test_sigterm_quits_the_running_screen_and_the_handler_is_restored():
    app, before = _App(), signal.getsignal(signal.SIGTERM)

    async def screen() -> None:
        with _sigterm_quits(app):
            os.kill(os.getpid(), signal.SIGTERM)
            for _ in range(100):  # the handler schedules the quit on this loop
                if app.quits:
                    break
                await asyncio.sleep(0)

    asyncio.run(screen())
    assert app.quits == 1
    assert signal.getsignal(signal.SIGTERM) is before


def test_sigterm_with_no_screen_running_stops_as_ctrl_c_would_saying_it_was_terminated():
    app = _App()
    with pytest.raises(Terminated) as stopped, _sigterm_quits(app):
        os.kill(os.getpid(), signal.SIGTERM)
        time.sleep(0)  # a call: the pending handler runs by then at the latest
    assert app.quits == 0
    assert isinstance(stopped.value, KeyboardInterrupt) and stopped.value.signum == signal.SIGTERM  # status 143


def test_sighup_quits_the_running_screen_as_sigterm_does():
    # A hung-up terminal (an SSH drop, tmux kill-session) mid-grasp: the loop must release the grasp, not
    # die with the fingers squeezing. In a child: on the old handling SIGHUP killed the process.
    import subprocess
    import sys
    import textwrap

    script = textwrap.dedent("""
        import asyncio, os, signal
        from haptics.operate_cli import _sigterm_quits

        class App:
            quits = 0
            def action_quit_console(self):
                App.quits += 1

        before = signal.getsignal(signal.SIGHUP)

        async def screen():
            with _sigterm_quits(App()):
                os.kill(os.getpid(), signal.SIGHUP)
                for _ in range(100):
                    if App.quits:
                        break
                    await asyncio.sleep(0)

        asyncio.run(screen())
        assert App.quits == 1 and signal.getsignal(signal.SIGHUP) is before
        print("quit")
    """)
    done = subprocess.run([sys.executable, "-c", script], timeout=60, capture_output=True, text=True)
    assert done.returncode == 0 and "quit" in done.stdout, done.stderr
