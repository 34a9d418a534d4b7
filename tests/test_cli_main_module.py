"""``python -m PKG.cli`` runs the command line as the console script does."""

from __future__ import annotations

import subprocess
import sys

import pytest


def _run(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", *args], capture_output=True, text=True, timeout=120, check=False)


@pytest.mark.parametrize("package", ["teleop", "estimator", "haptics"])
def test_python_m_cli_prints_help(package: str) -> None:
    done = _run(f"{package}.cli", "--help")
    assert done.returncode == 0, done.stderr
    assert done.stdout.startswith(f"usage: {package} "), done.stdout


def test_python_m_cli_runs_a_subcommand() -> None:
    done = _run("estimator.cli", "estimate", "--help")
    assert done.returncode == 0, done.stderr
    assert done.stdout.startswith("usage: estimator estimate "), done.stdout


def test_python_m_cli_exit_status_is_the_commands() -> None:
    done = _run("haptics.cli", "no-such-command")
    assert done.returncode != 0
    assert "no-such-command" in done.stderr
