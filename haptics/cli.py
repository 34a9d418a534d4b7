"""``haptics``: the operator's softness display: mapping, HID protocol, devices."""

from __future__ import annotations

from collections.abc import Sequence

from teleop.clikit import Command, run_cli

COMMANDS: dict[str, Command] = {}


def main(argv: Sequence[str] | None = None) -> int:
    return run_cli("haptics", __doc__, COMMANDS, argv)
