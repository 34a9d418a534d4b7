"""``haptics try``: map one modulus to a display command and write it to a display."""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import sys

from haptics.devices import BACKENDS, make_display
from haptics.errors import HapticsError
from haptics.mapping import (
    ESTIMATE_STATES,
    EstimateUpdate,
    just_noticeable_steps,
    map_estimate,
    to_command,
)
from haptics.settings import display_settings
from teleop.settings import load_settings
from teleop.units import format_pa


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--e-pa", type=float, default=None,
                        help="Young's modulus in Pa (for a bound state: the bound); "
                             "not needed with --state insufficient_data")
    parser.add_argument("--low-pa", type=float, default=None,
                        help="lower end of the uncertainty interval in Pa (default: open)")
    parser.add_argument("--high-pa", type=float, default=None,
                        help="upper end of the uncertainty interval in Pa (default: open)")
    parser.add_argument("--state", choices=ESTIMATE_STATES, default="ok", help="estimate state")
    parser.add_argument("--backend", choices=sorted(BACKENDS), default=None,
                        help="display backend (default: [display] backend of the settings)")
    parser.add_argument("--settings", default=None,
                        help="settings TOML with the [display] section; its rigid end is the "
                             "estimating sensor's resolution limit unless [display] e_rigid_pa "
                             "sets it (default: the shipped configs/settings.toml)")
    parser.add_argument("--timeout-s", type=float, default=0.2,
                        help="how long to wait for the display's status report, in seconds")
    parser.add_argument("--json", action="store_true",
                        help="print one JSON object (mapping, report, status) on stdout, the text on stderr; "
                             "E_pa is the modulus rendered (for a bound state without --e-pa, its bound), null for "
                             "insufficient_data; display_fraction is the fraction of the "
                             "display's range rendered (0 free, 1 rigid)")


def run(args: argparse.Namespace) -> int:
    # Checked before the display is touched: a bad option must not leave a command written.
    if args.e_pa is None and args.state == "ok":
        raise HapticsError("--e-pa: expected Young's modulus in Pa (only --state insufficient_data needs none)")
    if args.e_pa is not None and not (math.isfinite(args.e_pa) and args.e_pa > 0):
        raise HapticsError(f"--e-pa {args.e_pa}: expected Young's modulus in Pa, a finite number > 0")
    if not (math.isfinite(args.timeout_s) and args.timeout_s >= 0):
        raise HapticsError(f"--timeout-s {args.timeout_s}: expected a finite number of seconds >= 0")
    # The full settings resolve [display] e_rigid_pa = 0 to the sensor's resolution limit.
    settings = display_settings(load_settings(args.settings))
    if args.backend is not None:
        settings = dataclasses.replace(settings, backend=args.backend)
    update = EstimateUpdate(
        e_pa=args.e_pa, interval_pa=(args.low_pa, args.high_pa), state=args.state,
        reason="haptics try",
    )
    percept = map_estimate(update, e_soft_pa=settings.e_soft_pa, e_rigid_pa=settings.e_rigid_pa)
    with make_display(settings) as display:
        command = to_command(percept, level_max=display.info.level_max)
        report = display.write_command(command)
        status = display.read_status(timeout_s=args.timeout_s)
        where = str(display)
    flags = [name for name in ("rigid", "unknown", "provisional") if getattr(command, name)]
    steps = just_noticeable_steps(settings.e_soft_pa, settings.e_rigid_pa)
    out = sys.stderr if args.json else sys.stdout  # with --json, stdout is the JSON alone
    modulus = "no modulus" if update.value_pa is None else f"E {format_pa(update.value_pa)}"
    print(f"{modulus} ({args.state}) -> {percept.stiffness:.3f} of the range "
          f"{format_pa(settings.e_soft_pa)}..{format_pa(settings.e_rigid_pa)} ({steps:.0f} just-noticeable steps), "
          f"level {command.level}/{display.info.level_max}, uncertainty "
          f"{percept.uncertainty_decades:.2f} decades, flags: {', '.join(flags) or 'none'}", file=out)
    if percept.unknown and args.state != "insufficient_data":
        print("unknown: the interval spans the display's whole range, so it places the object nowhere", file=out)
    print(f"wrote to {where}: {report.hex(' ')}", file=out)
    if status is None:
        print(f"no status report within {args.timeout_s} s", file=out)
    else:
        print(f"display status: {status.state}, level {status.level}, faults "
              f"{', '.join(sorted(status.faults)) or 'none'}, sequence echo {status.sequence}", file=out)
    if args.json:
        print(json.dumps({
            "backend": settings.backend, "display": where, "state": args.state,
            # As estimate and the renderer say it: the modulus rendered (for a bound state without
            # --e-pa, the bound of --low-pa / --high-pa); a refusal carries none.
            "E_pa": update.value_pa,
            "e_soft_pa": settings.e_soft_pa, "e_rigid_pa": settings.e_rigid_pa, "just_noticeable_steps": steps,
            "display_fraction": percept.stiffness, "uncertainty_decades": percept.uncertainty_decades,
            "level": command.level, "level_max": display.info.level_max,
            "command": dataclasses.asdict(command), "report_hex": report.hex(),
            "status": None if status is None else {**dataclasses.asdict(status),
                                                   "faults": sorted(status.faults)},
        }, allow_nan=False))
    return 0
