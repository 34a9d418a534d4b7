"""``teleop``: the robot side: simulation, capture, the bus, sessions."""

from __future__ import annotations

from collections.abc import Sequence

from teleop.clikit import Command, run_cli

COMMANDS = {
    "settings": Command("teleop.settings_cli", "check a settings TOML file and print it resolved"),
    "import-dataset": Command("teleop.dataset", "import the published dataset (raw grasps or preprocessed samples)"),
    "catalogue": Command("teleop.catalogue", "list an object catalogue (project TOML or published CSV table)"),
}


def main(argv: Sequence[str] | None = None) -> int:
    return run_cli("teleop", __doc__, COMMANDS, argv)
