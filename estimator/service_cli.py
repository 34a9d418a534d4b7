"""``estimator serve``: serve live estimates of the grasps on the bus (:mod:`estimator.service`).

``--report`` appends the service's per-grasp report lines to a file; ``--json`` prints its
counts on exit. ``--foxglove`` serves the estimates it publishes live to Foxglove
(:class:`~teleop.session.foxglove_live.LiveTap`).
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import sys

from estimator.analytical import METHODS
from estimator.measure import resolve_calibration
from estimator.service import INPUT_TOPICS, EstimatorService, ModelSlot, resolve_model_dir
from estimator.stream import configured_methods
from teleop.bus.pubsub import Publisher, Subscriber
from teleop.live import JsonLines, StopSignals, add_endpoint_arguments, bus_from_args
from teleop.session.foxglove_live import LiveTap, add_foxglove_argument
from teleop.settings import default_settings_path, load_settings

log = logging.getLogger(__name__)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.description = (
        "Serve live estimates: subscribe to the robot node's frames, forces, widths and grasp events "
        "and publish a provisional estimate per tactile frame while a grasp loads and a final one when "
        "loading ends. Stops on Ctrl-C or SIGTERM; SIGHUP or a reload_model command (on --command) reloads "
        "the model between grasps. Run it with "
        "OPENBLAS_NUM_THREADS=1 (one core)."
    )
    parser.add_argument("--settings", metavar="FILE", default=str(default_settings_path()),
                        help="settings TOML (sensors, estimator, gripper, bus)")
    parser.add_argument("--calibration", metavar="CAL", default=None,
                        help="colour-to-gradient calibration (.npz) of the estimator's finger; default: "
                             "the file its sensor names (relative to configs/)")
    parser.add_argument("--methods", nargs="+", choices=METHODS, default=None, metavar="METHOD",
                        help="analytical methods in order of preference; the first that does not refuse "
                             f"is published (default: [estimator] methods of the settings; choices: {', '.join(METHODS)})")
    parser.add_argument("--model", metavar="DIR", default=None,
                        help="learned model directory (model.onnx + metadata.json) for final estimates; "
                             "'none' for analytical only; default: [estimator] model_path, else the shipped "
                             "default model if there is one")
    parser.add_argument("--mode", choices=("auto", "model"), default="auto",
                        help="with a model: auto (the split when its interval is narrow, else the model) "
                             "or model (always the model)")
    add_endpoint_arguments(parser, "robot_pub", "estimate_pub", "command")
    parser.add_argument("--report", metavar="FILE", default=None,
                        help="append one JSON object per grasp (contact time, time to first estimate, "
                             "provisional count, final estimate) to FILE")
    parser.add_argument("--duration-s", type=float, default=None, metavar="S",
                        help="stop after S seconds (default: run until Ctrl-C or SIGTERM)")
    add_foxglove_argument(parser, what="the estimates it publishes")
    parser.add_argument("--json", action="store_true",
                        help="on exit print one JSON object (messages, bad_messages, ignored, grasps, "
                             "provisional, final, reloads, reload_requests) as the last stdout line")


def run(args: argparse.Namespace) -> int:
    settings = load_settings(args.settings)
    methods = tuple(args.methods or configured_methods(settings))
    calibration = resolve_calibration(settings.sensor(settings.sensing.finger), args.calibration)
    bus = bus_from_args(settings, args)
    model_dir = resolve_model_dir(args.model, settings)
    model = None if model_dir is None else ModelSlot(model_dir, settings=settings, calibration=calibration,
                                                      mode=args.mode)
    if os.environ.get("OPENBLAS_NUM_THREADS") != "1":
        log.warning("OPENBLAS_NUM_THREADS is not 1: BLAS threads may slow per-frame estimation down")
    with (
        Subscriber.from_settings(bus, bus.robot_pub, INPUT_TOPICS) as subscriber,
        Subscriber.from_settings(bus, bus.command, ("command",)) as commands,
        Publisher.from_settings(bus, bus.estimate_pub, lossless=False, source="estimator") as publisher,
        JsonLines(args.report) as report,
        LiveTap(publisher.endpoint, args.foxglove, bus=bus, name="estimator serve"),
        StopSignals(on_hangup=model.request_reload if model is not None else None) as signals,
    ):
        service = EstimatorService(settings, calibration=calibration, subscriber=subscriber, publisher=publisher,
                                   methods=methods, model=model, report=report, commands=commands)
        print(f"estimator: {', '.join(methods)}{'' if model is None else f' + model {model_dir}'}; "
              f"robot data from {bus.robot_pub}, estimates on {publisher.endpoint}", file=sys.stderr)
        stats = service.run(signals.stop, duration_s=args.duration_s)
    print(f"estimator: {stats.grasps} grasps, {stats.provisional} provisional and {stats.final} final "
          f"estimates, {stats.bad_messages} bad messages", file=sys.stderr)
    if args.json:
        print(json.dumps(stats.as_dict()))
    return 0
