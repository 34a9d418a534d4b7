"""What the live system waits for before it is ready: the node's and the recorder's subscriptions to
its commands (a command sent before one reaches no one)."""

from __future__ import annotations

from pathlib import Path

import pytest

from teleop.node import COMMAND_TOPICS
from teleop.settings import default_settings_path
from teleop.system.live_system import LiveSystem


class _Commands:
    """The command publisher's subscriptions, as counted (exact prefixes)."""

    def __init__(self, *prefixes: str):
        self.prefixes = prefixes

    def subscriptions(self, prefix: str) -> int:
        return self.prefixes.count(prefix)


@pytest.mark.parametrize(("record", "prefixes", "deaf"), [
    (True, (), ["the node's commands", "the recorder"]),
    (True, ("command",), ["the node's commands", "the recorder"]),  # the estimator's: not the node's
    (True, (*COMMAND_TOPICS, ""), []),
    (False, COMMAND_TOPICS, []),
])
def test_ready_once_the_node_and_the_recorder_hear_the_commands(record, prefixes, deaf, tmp_path):
    system = LiveSystem(default_settings_path(), "quick", tmp_path, Path("cal.npz"), record=record)
    system.commands = _Commands(*prefixes)
    assert system._deaf() == deaf


def test_a_recorder_that_stopped_recording_is_not_waited_for(tmp_path):
    # check() lets the session go on without it; waiting for its subscription timed the start out.
    system = LiveSystem(default_settings_path(), "quick", tmp_path, Path("cal.npz"))
    system.commands = _Commands(*COMMAND_TOPICS)
    system.recording_stopped = "No space left on device"
    assert system._deaf() == []
