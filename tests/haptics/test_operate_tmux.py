"""``haptics operate`` in a real terminal: a whole session in tmux against the live system on
simulated hardware (send-keys in, capture-pane out)."""

from __future__ import annotations

import os
import re
import shlex
import shutil
import subprocess
import sys
import textwrap
import time
import uuid
from pathlib import Path

import pytest

from teleop.settings import default_settings_path, load_settings
from teleop.system.live_system import LiveSystem, simulated_calibration

ESTIMATE = re.compile(r"E (=|>=|<=) [0-9.]+ [kMG]?Pa")
COMMAND_REBIND_S = 0.3  # the demo's command publisher is closed: its port is free again after this


class Tmux:
    """A private tmux server (its own socket name), so the test never touches a user's sessions."""

    def __init__(self):
        self.socket = f"operate-test-{uuid.uuid4().hex[:8]}"

    def __call__(self, *args: str) -> str:
        done = subprocess.run(["tmux", "-L", self.socket, *args], capture_output=True, text=True, timeout=10)
        if done.returncode != 0:
            raise AssertionError(f"tmux {' '.join(args)}: {done.stderr.strip()}")
        return done.stdout

    def pane(self) -> str:
        return self("capture-pane", "-p", "-t", "operate")

    def wait_for(self, predicate, what: str, timeout_s: float, system: LiveSystem) -> str:
        deadline = time.monotonic() + timeout_s
        while True:
            text = self.pane()
            if predicate(text):
                return text
            system.check()
            if time.monotonic() > deadline:
                raise AssertionError(f"no {what} within {timeout_s:g} s; the pane:\n{text}")
            time.sleep(0.2)

    def kill(self) -> None:
        subprocess.run(["tmux", "-L", self.socket, "kill-server"], capture_output=True, timeout=10)


@pytest.fixture
def tmux():
    if shutil.which("tmux") is None:
        message = "tmux is not installed: the console's terminal session cannot be tested"
        if os.environ.get("CI", "").lower() == "true":
            pytest.fail(f"{message} (CI=true: install tmux)")
        pytest.skip(message)
    server = Tmux()
    yield server
    server.kill()


def _one_object_scene(tmp_path: Path) -> Path:
    path = tmp_path / "scene.toml"
    path.write_text(textwrap.dedent("""
        description = "one quick grasp"
        objects = ["steel_ball_bearing"]
        seed = 5
    """))
    return path


def _operate_command(system: LiveSystem, *options: str) -> str:
    ep = system.endpoints
    argv = [sys.executable, "-c", "import sys; from haptics.cli import main; sys.exit(main())", "operate",
            "--settings", str(default_settings_path()), "--robot-pub", ep["robot_pub"],
            "--estimate-pub", ep["estimate_pub"], "--command", ep["command"], "--display-pub", ep["display_pub"],
            *options]
    # COLUMNS and LINES (pytest's) would override the pane's size for textual. The pane outlives
    # the console, so that the test reads how it ended.
    return f"env -u COLUMNS -u LINES {shlex.join(argv)}; echo operate-exit-$?; sleep 60"


@pytest.fixture
def live(tmp_path):
    """The live system on simulated hardware (one steel ball: a quick grasp), its command endpoint
    left to the console: the console is the operator and binds it."""
    calibration = simulated_calibration(load_settings(), tmp_path, n_presses=12)
    system = LiveSystem(default_settings_path(), str(_one_object_scene(tmp_path)), tmp_path / "run", calibration,
                        record=False)
    system.start()
    try:
        system.commands.close()
        system.commands = None
        time.sleep(COMMAND_REBIND_S)
        yield system
    finally:
        system.stop()


def _start_console(tmux: Tmux, system: LiveSystem, *options: str) -> None:
    tmux("new-session", "-d", "-s", "operate", "-x", "120", "-y", "40", _operate_command(system, *options))
    tmux.wait_for(lambda t: re.search(r"UP\s+robot node", t) and re.search(r"UP\s+estimator", t)
                  and re.search(r"UP\s+display", t), "live system shown alive", 30, system)  # UP: it hears us


def _quit_cleanly(tmux: Tmux, system: LiveSystem) -> None:
    tmux("send-keys", "-t", "operate", "q")
    pane = tmux.wait_for(lambda t: "operate-exit-" in t, "the console's exit", 15, system)
    assert "operate-exit-0" in pane and "command message(s) sent" in pane, pane
    assert "Traceback" not in pane, pane


@pytest.mark.slow
def test_a_whole_session_in_tmux(tmux, live):
    """A discrete grasp: g, the estimate appears (to the final one), r, q."""
    _start_console(tmux, live, "--input", "keyboard", "--force", "20")
    tmux("send-keys", "-t", "operate", "g")
    pane = tmux.wait_for(lambda t: ESTIMATE.search(t) and "final" in t, "final estimate", 60, live)
    assert "steel_ball_bearing" in pane and "grasp op-" in pane
    tmux("send-keys", "-t", "operate", "r")
    tmux.wait_for(lambda t: re.search(r"\d+ follow, 2 command", t) and "release" in t, "the release sent", 10, live)
    _quit_cleanly(tmux, live)


def _node_follows() -> bool:
    from teleop.node import COMMAND_TOPICS

    return "follow" in COMMAND_TOPICS


@pytest.mark.slow
@pytest.mark.skipif(not _node_follows(), reason="the robot node does not take follow commands yet")
def test_a_follow_session_in_tmux(tmux, live):
    """Leader-follower from the keys: squeeze the grip, hold the enable, the fingers follow and the
    estimate appears; r releases (and lets the enable go), q quits."""
    _start_console(tmux, live, "--input", "keyboard")
    tmux("send-keys", "-t", "operate", *["k"] * 16)  # grip 0.8: a 16 mm target, past the 25 mm ball
    tmux.wait_for(lambda t: "0.80 -> 16.0 mm" in t, "the grip squeezed", 10, live)
    tmux("send-keys", "-t", "operate", "e")
    pane = tmux.wait_for(lambda t: "robot  following" in t and ESTIMATE.search(t), "an estimate while following",
                         60, live)
    assert "enable HELD" in pane and "mode follow" in pane and "steel_ball_bearing" in pane
    tmux("send-keys", "-t", "operate", "r")
    tmux.wait_for(lambda t: "phase  ended" in t and "enable off" in t, "the grasp ended", 20, live)
    _quit_cleanly(tmux, live)
