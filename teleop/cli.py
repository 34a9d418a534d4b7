"""``teleop``: the robot side: simulation, capture, the bus, sessions."""

from __future__ import annotations

from collections.abc import Sequence

from teleop.clikit import Command, run_cli

COMMANDS = {
    "settings": Command("teleop.settings_cli", "check a settings TOML file and print it resolved"),
    "import-dataset": Command("teleop.dataset", "import the published dataset (raw grasps or preprocessed samples)"),
    "catalogue": Command("teleop.catalogue", "list an object catalogue (project TOML or published CSV table)"),
    "hx711-bridge": Command("teleop.devices.hx711_bridge", "serve HX711 load-cell readings as framed TCP (run where the cell is)"),
    "simulate-presses": Command("teleop.sim.presses", "render simulated ball presses for calibrating the estimator (taxim dataPack layout)"),
}


def main(argv: Sequence[str] | None = None) -> int:
    return run_cli("teleop", __doc__, COMMANDS, argv)
