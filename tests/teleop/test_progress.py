"""teleop.progress.progress_bar: live on a terminal, sparing in a log."""

from __future__ import annotations

import io
import sys
import time

import pytest

from teleop.progress import progress_bar


class _Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def _draws(stream: io.StringIO, *, enabled: bool = True) -> int:
    for _ in progress_bar(range(40), enabled=enabled, desc="work"):
        time.sleep(0.01)  # 0.4 s: several of a terminal's redraw intervals
    return stream.getvalue().count("work")


@pytest.mark.parametrize("enabled", [True, False])
def test_a_log_gets_the_bar_at_its_start_and_end_only(monkeypatch, enabled):
    stream = io.StringIO()
    monkeypatch.setattr(sys, "stderr", stream)
    draws = _draws(stream, enabled=enabled)
    assert draws == (2 if enabled else 0)
    assert not enabled or "40/40" in stream.getvalue()


def test_a_terminal_sees_the_bar_move(monkeypatch):
    stream = _Terminal()
    monkeypatch.setattr(sys, "stderr", stream)
    assert _draws(stream) >= 3
