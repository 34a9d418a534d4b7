"""``teleop``: the robot side: simulation, capture, the bus, sessions."""

from __future__ import annotations

import sys
from typing import TYPE_CHECKING

from teleop.cli_start import start

if TYPE_CHECKING:
    from collections.abc import Sequence

    from teleop.clikit import Command

# Nothing else is imported here: the console script imports this module before main() runs, and a
# Ctrl-C meanwhile would end in a traceback. teleop.clikit is imported by start(), under its guard.


def commands() -> dict[str, Command]:
    """The ``teleop`` subcommands, by name (each one's module imported only when it runs)."""
    from teleop.clikit import Command

    return {
        "settings": Command("teleop.system.settings_cli", "check a settings TOML file (every table) and print it resolved"),
        "import-dataset": Command("teleop.system.dataset", "import the published dataset (raw grasps or preprocessed samples)"),
        "catalogue": Command("teleop.catalogue_cli", "list an object catalogue (project TOML or published CSV table)"),
        "hx711-bridge": Command("teleop.devices.hx711_bridge_cli", "serve HX711 load-cell readings as framed TCP (run where the cell is)"),
        "keys": Command("teleop.bus.keys_cli", "create, authorise, list and revoke the bus's CURVE keys"),
        "simulate": Command("teleop.sim.simulate_cli", "simulate labelled grasp records of catalogue objects"),
        "simulate-presses": Command("teleop.sim.presses_cli", "render simulated ball presses for calibrating the estimator (taxim dataPack layout)"),
        "node": Command("teleop.node_cli", "run the robot node: devices to the bus, grasps on operator command"),
        "demo": Command("teleop.system.demo", "run the live system on simulated hardware over a scene and print the results"),
        "bench-latency": Command("teleop.system.latency", "measure the live system's latency to the display report and its estimate rate"),
        "record": Command("teleop.session.record_cli", "record every bus message of a session into an MCAP log"),
        "replay": Command("teleop.session.replay_cli", "publish a recorded session back onto the bus"),
        "label": Command("teleop.session.label_cli", "attach labels (object and modulus per grasp) to a session log from a CSV"),
        "export": Command("teleop.session.export_cli", "turn the grasps of a session log into .grasp records"),
        "report": Command("teleop.system.report", "write a web page (HTML + PNGs) of a session log's grasps: frames, depth, force, estimates, display"),
        "recover": Command("teleop.session.recover_cli", "salvage a session log cut short (killed recorder, full disk)"),
        "soak": Command("teleop.soak_cli", "soak the grasp data path on loopback: lost messages, memory growth, latency"),
        "calibrate": Command("teleop.rig.calibrate_cli", "calibrate a rig (load cell, gripper, camera) into its settings file"),
        "doctor": Command("teleop.system.doctor", "check every configured device, the bus ports and the calibration files"),
    }


def main(argv: Sequence[str] | None = None) -> int:
    return start("teleop", __doc__, commands, argv)


if __name__ == "__main__":  # `python -m teleop.cli`, as the console script runs main()
    sys.exit(main())
