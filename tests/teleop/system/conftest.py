"""One run of ``teleop demo`` on the quick scene per operator, shared by the slow tests that read it.

A run takes 10-20 s of processes on a 2-core machine; the tests only read what it printed and wrote
(each writes its own reports and exports into its own ``tmp_path``).
"""

from __future__ import annotations

import contextlib
import io
import json
from dataclasses import dataclass
from pathlib import Path

import pytest
from matplotlib.figure import Figure

import teleop.cli
import teleop.system.report_figures as figures


@dataclass(frozen=True)
class DemoRun:
    code: int
    out: list[str]
    err: str
    folder: Path

    @property
    def result(self) -> dict:
        """The ``--json`` object: all of stdout."""
        return json.loads("\n".join(self.out))

    @property
    def text(self) -> list[str]:
        """What it showed (the closing table and the session log's path): stderr under ``--json``."""
        return self.err.splitlines()


def _demo(folder: Path, *options: str) -> DemoRun:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = teleop.cli.main(["demo", "--scene", "quick", "--json", "--no-view", "--out", str(folder), *options])
    return DemoRun(code, out.getvalue().strip().splitlines(), err.getvalue(), folder)


@pytest.fixture(scope="session")
def quick_demo_script(tmp_path_factory) -> DemoRun:
    """The scripted grasps, served the shipped default model named by its path."""
    return _demo(tmp_path_factory.mktemp("demo-script"), "--operator", "script", "--model", "estimator/models/default")


@pytest.fixture(scope="session")
def quick_demo_sim(tmp_path_factory) -> DemoRun:
    """The defaults: the simulated operator, the default model. Run once more when the robot's
    watchdog stopped the fingers: the operator's thread was starved of CPU for over 200 ms by the
    rest of the suite (a grasp then ends without its squeeze), which is not what the readers test
    (the watchdog has its own tests)."""
    run = _demo(tmp_path_factory.mktemp("demo-sim"))
    if _WATCHDOG_FIRED in _read(run.folder / "node.log"):
        run = _demo(tmp_path_factory.mktemp("demo-sim-again"))
    return run


# What the node logs when its watchdog stops the fingers (teleop.follow).
_WATCHDOG_FIRED = "no follow command for"


def _read(path: Path) -> str:
    try:
        return path.read_text(errors="replace")
    except OSError:
        return ""


@pytest.fixture
def drawn(monkeypatch) -> list[Figure]:
    """The figures the report module saves, as they were when saved (none written)."""
    saved: list[Figure] = []
    monkeypatch.setattr(figures, "_save", lambda fig, path: saved.append(fig) or (1, 1))
    return saved
