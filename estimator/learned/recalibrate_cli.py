"""``estimator recalibrate``: the command line of :mod:`estimator.learned.recalibrate`."""

from __future__ import annotations

import argparse
import json

from estimator.learned.infer import bands_text
from estimator.learned.recalibrate import recalibrate
from teleop.settings import load_settings

_SHOWN = ("temperature", "coverage")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.description = (
        "Refit a trained model's calibration (analytical floor, temperature, and per force band the rigid "
        "probability and interval scale) on the val objects of its own build-dataset directory and score it "
        "again on the val and test objects, without retraining: for a change to how answers are described or "
        "calibrated. Rewrites MODEL_DIR/metadata.json (or writes "
        "OUT) and keeps the replaced calibration under `recalibrated`."
    )
    parser.add_argument("--model", required=True, metavar="MODEL_DIR", help="the trained model")
    parser.add_argument("--data", required=True, metavar="DIR",
                        help="the model's dataset (`estimator build-dataset` output; metadata.json data.dir)")
    parser.add_argument("--out", metavar="MODEL_DIR", default=None, help="write the model here instead of in place")
    parser.add_argument("--settings", metavar="FILE", default=None,
                        help="settings TOML whose resolution limit the intervals are calibrated at "
                             "(default: the shipped configs/settings.toml)")
    parser.add_argument("--json", action="store_true", help="print the new and previous calibration as JSON")


def run(args: argparse.Namespace) -> int:
    meta = recalibrate(args.model, args.data, out_dir=args.out, settings=load_settings(args.settings))
    new, old = meta["calibration"], meta["recalibrated"]["previous"]
    if args.json:
        print(json.dumps({"out": args.out or args.model, "calibration": new, "previous": old}, allow_nan=False))
        return 0
    for key in _SHOWN:
        before = old.get(key)
        print(f"{key:15s} {'-' if before is None else f'{before:.4g}':>8s} -> {new[key]:.4g}")
    print(f"force bands     {bands_text(old)}\n             -> {bands_text(new)}")
    print(f"on {new['n']} val grasps; wrote {args.out or args.model}/metadata.json")
    return 0
