"""``teleop settings``: check a settings file, every package's tables included, and print it resolved.

The base reads its own tables; the estimator's and the display's are built and checked by their
packages (``estimator.settings``, ``haptics.settings``), so the full check lives here, above them.
"""

from __future__ import annotations

import argparse
import json
import sys

from estimator.settings import estimator_settings
from haptics.settings import display_settings, display_warnings, operator_settings
from teleop.bus.security import check_endpoints
from teleop.clikit import help_literal
from teleop.errors import BusSecurityError, SettingsError
from teleop.settings import (
    BusSettings,
    Settings,
    default_settings_path,
    load_settings,
    missing_calibrations,
    settings_to_mapping,
)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.description = (
        "Check a settings file (every table: the rig's, [estimator], [display] and the optional [operator]) "
        "and print what it "
        "resolves to as JSON: defaults filled in, paths made absolute against the file's folder, the "
        "display's rigid end set to the sensor's resolution limit where the file leaves it 0."
    )
    parser.add_argument("path", nargs="?", default=None, metavar="FILE",
                        help=f"settings TOML file (default: {help_literal(default_settings_path())})")
    # Every other command names its settings file so.
    parser.add_argument("--settings", metavar="FILE", default=None, help="the same as FILE")


def run(args: argparse.Namespace) -> int:
    if args.path is not None and args.settings is not None:
        raise SettingsError(f"FILE {args.path} and --settings {args.settings}: name the settings file once")
    path = args.settings or args.path
    settings = load_settings(path)
    resolved = (settings.with_section(estimator_settings(settings)).with_section(display_settings(settings))
                .with_section(operator_settings(settings)))
    print(json.dumps(settings_to_mapping(resolved), indent=2))
    # Valid settings, but a session would lack a file, a process would refuse its endpoint, or the display
    # could not show what it should.
    for warning in (*missing_calibrations(settings, path), *_bus_key_warnings(settings), *display_warnings(settings)):
        print(f"teleop settings: warning: {warning}", file=sys.stderr)
    return 0


def _bus_key_warnings(settings: Settings) -> list[str]:
    """An endpoint other hosts reach without ``keys_dir``: each process refuses it as it starts (not
    the file: a command line may give loopback endpoints instead)."""
    if settings.bus.keys_dir:
        return []
    try:
        check_endpoints([getattr(settings.bus, name) for name in BusSettings.ENDPOINTS], None)
    except BusSecurityError as exc:
        return [f"[bus] {exc}"]
    return []
