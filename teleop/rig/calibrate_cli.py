"""``teleop calibrate {load-cell,gripper,camera}``: measure a rig's constants and write them into its settings.

Each calibration reads the devices the settings file configures, fits its constants, refuses a
fit that is not good enough (with the reason), writes what it measured into that same file
(comments and layout kept) and prints what changed. Only the chosen calibration's module is
imported.
"""

from __future__ import annotations

import argparse
import importlib

__all__ = ["TARGETS", "add_arguments", "run"]

#: Calibration name -> (module with ``add_arguments(parser)`` and ``run(args)``, what it measures).
TARGETS = {
    "load-cell": ("teleop.rig.load_cell_calibration",
                  "tare and counts per newton of the HX711 cell from known masses"),
    "gripper": ("teleop.rig.gripper_calibration",
                "the fingers' stiffness, squeezing a rigid reference object at several forces"),
    "camera": ("teleop.rig.camera_calibration",
               "a Wedge's mirror corners from a no-contact frame, and the camera's latency from a tap"),
}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.description = __doc__.split("\n\n", 1)[1] + "\n" + "\n".join(f"  {name:10s} {text}" for name, (_, text) in TARGETS.items())
    parser.set_defaults(_formatter=parser.formatter_class)
    parser.formatter_class = argparse.RawDescriptionHelpFormatter
    parser.add_argument("target", choices=sorted(TARGETS), help="what to calibrate")
    parser.add_argument("options", nargs=argparse.REMAINDER, metavar="...",
                        help="options of that calibration: see `teleop calibrate TARGET --help`")


def run(args: argparse.Namespace) -> int:
    module_name, text = TARGETS[args.target]
    module = importlib.import_module(module_name)
    parser = argparse.ArgumentParser(prog=f"teleop calibrate {args.target}", description=text,
                                     formatter_class=args._formatter)
    module.add_arguments(parser)
    return int(module.run(parser.parse_args(args.options)) or 0)
