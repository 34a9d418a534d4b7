"""``teleop settings``: check a settings file, every package's tables included, and print it resolved.

The base reads its own tables; the estimator's and the display's are built and checked by their
packages (``estimator.settings``, ``haptics.settings``), so the full check lives here, above them.
"""

from __future__ import annotations

import argparse
import json

from estimator.settings import estimator_settings
from haptics.settings import display_settings, operator_settings
from teleop.settings import default_settings_path, load_settings, settings_to_mapping


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.description = (
        "Check a settings file (every table: the rig's, [estimator] and [display]) and print what it "
        "resolves to as JSON: defaults filled in, paths made absolute against the file's folder, the "
        "display's rigid end set to the sensor's resolution limit where the file leaves it 0."
    )
    parser.add_argument("path", nargs="?", default=str(default_settings_path()), help="settings TOML file")


def run(args: argparse.Namespace) -> int:
    settings = load_settings(args.path)
    resolved = (settings.with_section(estimator_settings(settings)).with_section(display_settings(settings))
                .with_section(operator_settings(settings)))
    print(json.dumps(settings_to_mapping(resolved), indent=2))
    return 0
