"""``teleop hx711-bridge``: serve HX711 load-cell readings as framed TCP (:mod:`teleop.devices.hx711_bridge`).

The source is a simulated cell (``--fake``) or an Arduino-style serial HX711 bridge
(``--serial PORT``, pyserial), calibrated and paced by the settings' ``[load_cell]``.
It serves until ``--duration-s`` passed, Ctrl-C or SIGTERM, then closes the server and (``--json``)
prints its summary; when the source fails (the serial device went away) it closes every host's
connection and exits with the error (status 2). Listening beyond loopback (the default ``0.0.0.0``,
for the host across the network) it warns on stderr: any host can connect, unauthenticated.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import sys
import time

from teleop.bus.security import host_is_loopback
from teleop.clikit import positive_number
from teleop.devices.hx711_bridge import FakeHx711, Hx711Bridge, SerialCounts
from teleop.errors import DeviceError, SettingsError
from teleop.live import StopSignals
from teleop.settings import LoadCellSettings, default_settings_path, load_settings

NOISE_COUNTS_MAX = 2**23  # beyond the HX711's range: every reading would saturate (or overflow, near 1e308)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    source = parser.add_mutually_exclusive_group(required=True)
    source.add_argument("--fake", action="store_true", help="serve a simulated load cell (constant --force-n plus noise)")
    source.add_argument("--serial", metavar="PORT", help="serve an Arduino-style serial HX711 bridge on this port")
    parser.add_argument(
        "--host", default="0.0.0.0", help="address to listen on; beyond loopback (the default included) any host on "
        "the network can connect, unauthenticated, and a warning says so: 127.0.0.1 for this machine only"
    )
    parser.add_argument("--port", type=int, default=5601, help="TCP port to listen on (0: any free port)")
    parser.add_argument(
        "--settings", default=str(default_settings_path()), help="settings TOML: [load_cell] calibration, rate and baud"
    )
    parser.add_argument("--baud", type=int, default=None, help="serial baud rate (default: [load_cell] baud of the settings)")
    parser.add_argument("--force-n", type=float, default=0.0, help="--fake: force the simulated cell feels, N")
    parser.add_argument("--noise-counts", type=float, default=0.0, help="--fake: reading noise (std), counts")
    parser.add_argument("--duration-s", type=positive_number, default=None, help="stop after this many seconds (default: run until Ctrl-C or SIGTERM)")
    parser.add_argument("--json", action="store_true", help="on exit, print a JSON summary as the last stdout line")


def _checked(args: argparse.Namespace, cell: LoadCellSettings) -> LoadCellSettings:
    """``cell`` with ``--baud`` applied; every option checked before anything is opened."""
    if not 0 <= args.port <= 65535:
        raise SettingsError(f"--port {args.port}: expected a TCP port in 0..65535 (0: any free port)")
    if not math.isfinite(args.force_n):
        raise SettingsError(f"--force-n {args.force_n}: expected a finite force in N")
    if not (math.isfinite(args.noise_counts) and 0 <= args.noise_counts <= NOISE_COUNTS_MAX):
        raise SettingsError(f"--noise-counts {args.noise_counts}: expected a number of counts >= 0 and "
                            f"<= {NOISE_COUNTS_MAX} (the HX711's whole 24-bit range)")
    if args.baud is None:
        return cell
    try:  # the settings' own bounds, so the two cannot disagree
        return dataclasses.replace(cell, baud=args.baud)
    except SettingsError as exc:
        raise SettingsError(f"--baud {args.baud}: {exc}") from None


def _warn_reachable(bridge: Hx711Bridge) -> None:
    """Say on stderr that other hosts reach ``bridge`` unauthenticated (the bus refuses such an
    endpoint without CURVE keys; the bridge has none), and how to keep it to this one."""
    print(f"teleop hx711-bridge: warning: {bridge.address} is reachable from other hosts, unencrypted and without "
          f"authentication (the bus's CURVE keys do not cover it): anyone on the network can read the load cell "
          f"or take up its connections; serve it on 127.0.0.1 only (--host 127.0.0.1) and reach it through an SSH "
          f"tunnel (ssh -L {bridge.port}:127.0.0.1:{bridge.port} THIS-HOST) unless this network is trusted",
          file=sys.stderr, flush=True)


def run(args: argparse.Namespace) -> int:
    cell = _checked(args, load_settings(args.settings).load_cell)
    if args.fake:
        source = FakeHx711(
            counts_per_n=cell.counts_per_n,
            tare_counts=cell.tare_counts,
            rate_hz=cell.sample_rate_hz,
            force_n=args.force_n,
            noise_counts=args.noise_counts,
        )
    else:
        source = SerialCounts(args.serial, cell.baud)
    started = time.monotonic()
    try:
        # Ctrl-C and SIGTERM end the wait as --duration-s does: the server is closed and the summary printed.
        # The signals are caught until the server is closed, so a second Ctrl-C cannot cut that short.
        with StopSignals() as signals, Hx711Bridge(source, host=args.host, port=args.port,
                                                   on_failure=lambda _why: signals.stop.set()) as bridge:
            # On stderr: stdout holds the --json summary alone.
            print(f"hx711-bridge: serving on {bridge.address}", file=sys.stderr, flush=True)
            if not host_is_loopback(args.host):
                _warn_reachable(bridge)
            signals.stop.wait(args.duration_s)
    finally:
        if isinstance(source, SerialCounts):
            source.close()
    if bridge.failure is not None:
        raise DeviceError(f"stopped serving {bridge.address}: {bridge.failure}")
    if args.json:
        summary = {"address": bridge.address, "readings": bridge.sent, "seconds": round(time.monotonic() - started, 3)}
        print(json.dumps(summary))
    sys.stdout.flush()
    return 0
