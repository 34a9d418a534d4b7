"""``haptics serve``: render live estimates from the bus on the softness display (:mod:`haptics.service`).

``--report`` appends one JSON object per final estimate (its latency and what the display
renders for it) to a file; ``--json`` prints the service's counts on exit. ``--foxglove``
serves the display messages it publishes live to Foxglove
(:class:`~teleop.session.foxglove_live.LiveTap`).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys

from haptics.devices import BACKENDS, make_display
from haptics.renderer import HapticRenderer
from haptics.service import INPUT_TOPICS, RendererService, check_tick_s
from haptics.settings import display_settings
from teleop.bus.pubsub import Publisher, Subscriber
from teleop.clikit import positive_number
from teleop.live import JsonLines, StopSignals, add_endpoint_arguments, bus_from_args
from teleop.session.foxglove_live import LiveTap, add_foxglove_argument
from teleop.settings import default_settings_path, load_settings


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.description = (
        "Render live estimates on the softness display: subscribe to the estimator's estimates "
        "(latest value) and drive the display, publishing heartbeats and one 'display' message per "
        "report written (what the display renders, as numbers) on the display endpoint. Records the "
        "latency from the last loading frame's capture to the display report for every final "
        "estimate. Stops on Ctrl-C, SIGTERM or SIGHUP, setting the display free first."
    )
    parser.add_argument("--settings", metavar="FILE", default=str(default_settings_path()),
                        help="settings TOML ([display] mapping and backend, [bus] endpoints)")
    parser.add_argument("--backend", choices=sorted(BACKENDS), default=None,
                        help="display backend (default: [display] backend of the settings)")
    add_endpoint_arguments(parser, "estimate_pub", "display_pub")
    parser.add_argument("--tick-s", type=positive_number, default=0.01, metavar="S",
                        help="longest time between renderer updates (smoothing, fading, keep-alive), seconds; at "
                             "most [display] keepalive_s and [bus] heartbeat_s of the settings")
    parser.add_argument("--report", metavar="FILE", default=None,
                        help="append one JSON object per final estimate (grasp_id, state, E_pa, latency_ms, "
                             "estimates_received, and what the display renders for it: display_fraction, rigid, "
                             "unknown, uncertainty_decades, level, level_max) to FILE")
    parser.add_argument("--duration-s", type=positive_number, default=None, metavar="S",
                        help="stop after S seconds (default: run until Ctrl-C or SIGTERM)")
    add_foxglove_argument(parser, what="the display messages it publishes")
    parser.add_argument("--json", action="store_true",
                        help="on exit print one JSON object (estimates, bad_messages, grasp_ends, display_messages, "
                             "display_failures, ignored: estimates of grasps that had ended or had their final, finals; wire: what its subscribers refused on the wire, by reason, and their sequence gaps) "
                             "as the last stdout line")


def run(args: argparse.Namespace) -> int:
    settings = load_settings(args.settings)
    rendering = display_settings(settings)
    if args.backend is not None:
        rendering = dataclasses.replace(rendering, backend=args.backend)
    bus = bus_from_args(settings, args)
    check_tick_s(args.tick_s, keepalive_s=rendering.keepalive_s, heartbeat_s=bus.heartbeat_s, name="--tick-s")
    display = make_display(rendering)
    renderer = HapticRenderer(display, rendering)
    # The signals first: handled until the display has been set free and closed, so a second one
    # cannot cut that short (StopSignals ignores it).
    with StopSignals() as signals:
        try:
            with (
                Subscriber.from_settings(bus, bus.estimate_pub, INPUT_TOPICS, conflate=True) as subscriber,
                Publisher.from_settings(bus, bus.display_pub, lossless=False, source="renderer") as publisher,
                JsonLines(args.report) as report,
                LiveTap(publisher.endpoint, args.foxglove, bus=bus, name="haptics serve"),
            ):
                service = RendererService(renderer, subscriber=subscriber, publisher=publisher, report=report,
                                          tick_s=args.tick_s)
                print(f"renderer: {display} from estimates on {bus.estimate_pub}, heartbeat and display messages "
                      f"on {publisher.endpoint}",
                      file=sys.stderr)
                stats = service.run(signals.stop, duration_s=args.duration_s)
        finally:
            display.close()
    ignored = (f", {stats.ignored} not shown: their grasps had ended or had their final estimate (late, or "
               "replayed after this renderer showed them)") if stats.ignored else ""
    print(f"renderer: {stats.estimates} estimates, {stats.final_estimates} final, {display.reports_written} "
          f"reports written{ignored}", file=sys.stderr)
    if args.json:
        print(json.dumps({**stats.as_dict(), "wire": service.wire_stats()}))
    return 0
