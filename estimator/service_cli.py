"""``estimator serve``: serve live estimates of the grasps on the bus (:mod:`estimator.service`).

``--report`` appends the service's per-grasp report lines to a file; ``--json`` prints its
counts on exit. ``--foxglove`` serves the estimates it publishes live to Foxglove
(:class:`~teleop.session.foxglove_live.LiveTap`). ``--model DIR`` serves that model; a running
service switches to another on ``estimator reload --model DIR`` (:mod:`estimator.reload_cli`).
Model switches and refusals are logged at the default log level.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import sys

from estimator.analytical import METHODS
from estimator.inference.infer import model_files
from estimator.measurements import resolve_calibration
from estimator.model_slot import ModelSlot, model_log
from estimator.service import COMMAND_TOPICS, INPUT_TOPICS, EstimatorService, resolve_model_dir
from estimator.settings import configured_methods
from teleop.bus.pubsub import Publisher, Subscriber
from teleop.clikit import positive_number
from teleop.live import JsonLines, StopSignals, add_endpoint_arguments, bus_from_args
from teleop.session.foxglove_live import LiveTap, add_foxglove_argument
from teleop.settings import default_settings_path, load_settings

log = logging.getLogger(__name__)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.description = (
        "Serve live estimates: subscribe to the robot node's frames, forces, widths and grasp events "
        "and publish a provisional estimate per tactile frame while a grasp loads and a final one when "
        "loading ends; every estimate names the model that made it. Stops on Ctrl-C or SIGTERM. Switches "
        "models between grasps, after loading and checking the new one (the old one stays if it fails): "
        "`estimator reload --model DIR` (a load_model message on --control) switches to another folder; "
        "SIGHUP or a reload_model command reads the served folder again; the service takes both messages "
        "on --command and --control alike; a new model.onnx and metadata.json copied into the served folder are "
        "taken once both have stopped changing. Run it with OPENBLAS_NUM_THREADS=1 (one core)."
    )
    parser.add_argument("--settings", metavar="FILE", default=str(default_settings_path()),
                        help="settings TOML (sensors, estimator, gripper, bus)")
    parser.add_argument("--calibration", metavar="CAL", default=None,
                        help="colour-to-gradient calibration (.npz) of the estimator's finger; default: "
                             "the file its sensor names (a relative path against the settings file's folder)")
    parser.add_argument("--methods", nargs="+", choices=METHODS, default=None, metavar="METHOD",
                        help="analytical methods in order of preference; the first that does not refuse "
                             f"is published (default: [estimator] methods of the settings; choices: {', '.join(METHODS)})")
    parser.add_argument("--model", metavar="DIR", default=None,
                        help="learned model folder (model.onnx and metadata.json) for final estimates, or "
                             "'none' for analytical estimates only (default: [estimator] model_path of the "
                             "settings, else the shipped default model)")
    parser.add_argument("--mode", choices=("auto", "model"), default="auto",
                        help="with a model: auto (the series fit when its interval is narrow, else the model) "
                             "or model (always the model)")
    add_endpoint_arguments(parser, "robot_pub", "estimate_pub", "command", "control")
    parser.add_argument("--report", metavar="FILE", default=None,
                        help="append one JSON object per grasp (contact time, time to first estimate, "
                             "provisional count, final estimate) to FILE")
    parser.add_argument("--duration-s", type=positive_number, default=None, metavar="S",
                        help="stop after S seconds (default: run until Ctrl-C or SIGTERM)")
    add_foxglove_argument(parser, what="the estimates it publishes")
    parser.add_argument("--json", action="store_true",
                        help="on exit print one JSON object (messages, bad_messages, ignored, grasps, "
                             "provisional, final, reloads, reload_requests, load_requests, model_refusals, "
                             "model; wire: what its subscribers refused on the wire, by reason, and their sequence gaps) as the last stdout line")


def run(args: argparse.Namespace) -> int:
    if model_log.getEffectiveLevel() > logging.INFO:
        model_log.setLevel(logging.INFO)  # model switches and refusals show at the default level
    settings = load_settings(args.settings)
    model_dir = resolve_model_dir(args.model, settings)
    if model_dir is not None:
        model_files(model_dir)  # a folder that is not a model: said first, naming the missing file
    methods = tuple(args.methods or configured_methods(settings))
    calibration = resolve_calibration(settings.sensor(settings.sensing.finger), args.calibration)
    bus = bus_from_args(settings, args)
    model = None if model_dir is None else ModelSlot(model_dir, settings=settings, calibration=calibration,
                                                      mode=args.mode)
    if os.environ.get("OPENBLAS_NUM_THREADS") != "1":
        log.warning("OPENBLAS_NUM_THREADS is not 1: BLAS threads may slow per-frame estimation down")
    service: EstimatorService | None = None

    def hangup() -> None:  # the slot the service holds now: load_model may have made one
        slot = None if service is None else service.model
        if slot is not None:
            slot.request_reload()

    # The signals first: handled until the sockets have closed, so a second one cannot cut that short.
    with (
        StopSignals(on_hangup=hangup) as signals,
        Subscriber.from_settings(bus, bus.robot_pub, INPUT_TOPICS) as subscriber,
        Subscriber.from_settings(bus, [bus.command, bus.control], COMMAND_TOPICS) as commands,
        Publisher.from_settings(bus, bus.estimate_pub, lossless=False, source="estimator") as publisher,
        JsonLines(args.report) as report,
        LiveTap(publisher.endpoint, args.foxglove, bus=bus, name="estimator serve"),
    ):
        service = EstimatorService(settings, calibration=calibration, subscriber=subscriber, publisher=publisher,
                                   methods=methods, model=model, report=report, commands=commands)
        served = "" if model is None else f" + model {model.model_id} ({model_dir})"
        print(f"estimator: {', '.join(methods)}{served}; robot data from {bus.robot_pub}, estimates on "
              f"{publisher.endpoint}", file=sys.stderr)
        stats = service.run(signals.stop, duration_s=args.duration_s)
    print(f"estimator: {stats.grasps} grasps, {stats.provisional} provisional and {stats.final} final "
          f"estimates, {stats.bad_messages} bad messages", file=sys.stderr)
    if args.json:
        print(json.dumps({**stats.as_dict(), "model": None if service.model is None else service.model.model_id,
                          "wire": service.wire_stats()}))
    return 0
