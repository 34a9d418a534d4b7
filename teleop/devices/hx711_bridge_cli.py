"""``teleop hx711-bridge``: serve HX711 load-cell readings as framed TCP (:mod:`teleop.devices.hx711_bridge`).

The source is a simulated cell (``--fake``) or an Arduino-style serial HX711 bridge
(``--serial PORT``, pyserial), calibrated and paced by the settings' ``[load_cell]``.
"""

from __future__ import annotations

import argparse
import json
import sys
import threading
import time

from teleop.devices.hx711_bridge import FakeHx711, Hx711Bridge, SerialCounts
from teleop.settings import default_settings_path, load_settings


def add_arguments(parser: argparse.ArgumentParser) -> None:
    source = parser.add_mutually_exclusive_group(required=True)
    source.add_argument("--fake", action="store_true", help="serve a simulated load cell (constant --force-n plus noise)")
    source.add_argument("--serial", metavar="PORT", help="serve an Arduino-style serial HX711 bridge on this port")
    parser.add_argument("--host", default="0.0.0.0", help="address to listen on")
    parser.add_argument("--port", type=int, default=5601, help="TCP port to listen on (0: any free port)")
    parser.add_argument(
        "--settings", default=str(default_settings_path()), help="settings TOML: [load_cell] calibration, rate and baud"
    )
    parser.add_argument("--baud", type=int, default=None, help="serial baud rate (default: [load_cell] baud of the settings)")
    parser.add_argument("--force-n", type=float, default=0.0, help="--fake: force the simulated cell feels, N")
    parser.add_argument("--noise-counts", type=float, default=0.0, help="--fake: reading noise (std), counts")
    parser.add_argument("--duration-s", type=float, default=None, help="stop after this many seconds (default: run until Ctrl+C)")
    parser.add_argument("--json", action="store_true", help="on exit, print a JSON summary as the last stdout line")


def run(args: argparse.Namespace) -> int:
    cell = load_settings(args.settings).load_cell
    if args.fake:
        source = FakeHx711(
            counts_per_n=cell.counts_per_n,
            tare_counts=cell.tare_counts,
            rate_hz=cell.sample_rate_hz,
            force_n=args.force_n,
            noise_counts=args.noise_counts,
        )
    else:
        source = SerialCounts(args.serial, args.baud or cell.baud)
    started = time.monotonic()
    try:
        with Hx711Bridge(source, host=args.host, port=args.port) as bridge:
            print(f"hx711-bridge: serving on {bridge.address}", flush=True)
            if args.duration_s is None:
                threading.Event().wait()  # until Ctrl+C
            else:
                time.sleep(args.duration_s)
    finally:
        if isinstance(source, SerialCounts):
            source.close()
    if args.json:
        summary = {"address": bridge.address, "readings": bridge.sent, "seconds": round(time.monotonic() - started, 3)}
        print(json.dumps(summary))
    sys.stdout.flush()
    return 0
