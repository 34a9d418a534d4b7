"""``estimator``: turn grasps into Young's modulus: calibration, perception, fits, models."""

from __future__ import annotations

from collections.abc import Sequence

from teleop.clikit import Command, run_cli

COMMANDS: dict[str, Command] = {}


def main(argv: Sequence[str] | None = None) -> int:
    return run_cli("estimator", __doc__, COMMANDS, argv)
