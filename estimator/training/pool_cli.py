"""``estimator pool``: the command line of :mod:`estimator.training.pool`."""

from __future__ import annotations

import argparse
import json

from estimator.inference.infer import bands_text
from estimator.training.outdir import OVERWRITE_HELP
from teleop.clikit import help_literal
from teleop.settings import default_settings_path, load_settings


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.description = (
        "Pool two or more models of one variant, trained on one dataset (other seeds), into one model: an ONNX "
        "file computing the log of the mean of their temperature-scaled bin probabilities, calibrated on the "
        "dataset's val objects and scored on its val and test objects. The estimator runs it like any model."
    )
    parser.add_argument("--model", required=True, action="append", metavar="MODEL_DIR",
                        help="a member (repeat: at least two)")
    parser.add_argument("--data", required=True, metavar="DIR", help="the members' dataset (`estimator build-dataset`)")
    parser.add_argument("--out", required=True, metavar="MODEL_DIR",
                        help="directory for the pooled model (created; must not exist yet, or be empty, unless "
                             "--overwrite)")
    parser.add_argument("--overwrite", action="store_true", help=OVERWRITE_HELP)
    parser.add_argument("--settings", metavar="FILE", default=None,
                        help="settings TOML whose resolution limit the intervals are calibrated at "
                             f"(default: the shipped {help_literal(default_settings_path())})")
    parser.add_argument("--json", action="store_true", help="print one JSON object (out, members, calibration)")


def run(args: argparse.Namespace) -> int:
    # Imported here: torch is the 'train' extra, which --help does not need.
    from estimator.training.pool import pool_models

    meta = pool_models(args.model, args.data, args.out, settings=load_settings(args.settings),
                       overwrite=args.overwrite)
    calibration = meta["calibration"]
    if args.json:
        print(json.dumps({"out": args.out, "members": len(args.model), "calibration": calibration}, allow_nan=False))
        return 0
    print(f"pooled {len(args.model)} models into {args.out}: coverage {calibration['coverage']:.1%} on "
          f"{calibration['n']} val grasps; {bands_text(calibration)}")
    return 0
