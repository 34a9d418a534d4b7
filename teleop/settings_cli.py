"""``teleop settings``: validate a settings file and print what it resolves to."""

from __future__ import annotations

import argparse
import json

from teleop.settings import default_settings_path, load_settings, settings_to_mapping


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("path", nargs="?", default=str(default_settings_path()), help="settings TOML file")


def run(args: argparse.Namespace) -> int:
    settings = load_settings(args.path)
    print(json.dumps(settings_to_mapping(settings), indent=2))
    return 0
