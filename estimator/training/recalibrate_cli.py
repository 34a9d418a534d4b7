"""``estimator recalibrate``: the command line of :mod:`estimator.training.recalibrate`."""

from __future__ import annotations

import argparse
import json
import sys

from estimator.errors import EstimatorError
from estimator.inference.infer import band_names, bands_text
from estimator.training.outdir import OVERWRITE_HELP
from estimator.training.recalibrate import cross_validate, recalibrate
from teleop.clikit import help_literal, non_negative_int
from teleop.settings import default_settings_path, load_settings

_SHOWN = ("temperature", "coverage")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.description = (
        "Refit a trained model's calibration (analytical floor, temperature, and per force band the rigid "
        "probability and interval scale) on the val objects of its own build-dataset directory and score it "
        "again on the val and test objects, without retraining: for a change to how answers are described or "
        "calibrated. Rewrites MODEL_DIR/metadata.json (or writes "
        "OUT) and keeps the replaced calibration under `recalibrated`. With --cross-validate it writes nothing "
        "and says what such a calibration scores on objects it did not see."
    )
    parser.add_argument("--model", required=True, metavar="MODEL_DIR", help="the trained model")
    parser.add_argument("--data", required=True, metavar="DIR",
                        help="the model's dataset (`estimator build-dataset` output; metadata.json data.dir)")
    parser.add_argument("--out", metavar="MODEL_DIR", default=None,
                        help="write the model here instead of in place (created; must not exist yet, or be empty, "
                             "unless --overwrite)")
    parser.add_argument("--overwrite", action="store_true", help=OVERWRITE_HELP)
    parser.add_argument("--settings", metavar="FILE", default=None,
                        help="settings TOML whose resolution limit the intervals are calibrated at "
                             f"(default: the shipped {help_literal(default_settings_path())})")
    parser.add_argument("--cross-validate", type=int, nargs="?", const=5, default=None, metavar="FOLDS",
                        help="write nothing: deal the val objects into FOLDS groups (default 5), answer each group's "
                             "grasps under a calibration fitted on the others, and print what those answers score "
                             "(felt error, dangerous misses, coverage per force band): the figures to compare two "
                             "ways of calibrating or describing by, without touching the test objects")
    parser.add_argument("--seed", type=non_negative_int, default=0, help="how the val objects are dealt into folds (default 0)")
    parser.add_argument("--json", action="store_true", help="print the new and previous calibration (or the "
                                                            "cross-validated figures) as JSON")


def _print_cross_validation(result: dict) -> None:
    m, level = result["metrics"], result["level"]
    rigid, soft_width = m["rigid_shown_rigid"], m["soft_interval_width_decades_median"]
    print(f"{result['folds']}-fold cross-validation by object (seed {result['seed']}) over {result['objects']} val "
          f"objects, {result['grasps']} grasps, {result['method']}:")
    print(f"felt error      {m['felt_log10_error']:.4f} decade, {100 * m['felt_within_2x']:.1f} % within a factor 2")
    print(f"dangerous       {m['dangerous_misses']}; rigid shown rigid "
          f"{'-' if rigid is None else f'{100 * rigid:.1f} %'}")
    print(f"coverage        {100 * m['interval_coverage']:.1f} % at the stated {100 * level:.0f} %; median width "
          f"{'-' if soft_width is None else f'{soft_width:.2f} decade'} at or below 3 MPa")
    bands = band_names(tuple(result["force_band_edges_n"]))
    for label, n, cover in zip(bands, result["band_n"], result["band_coverage"], strict=True):
        print(f"  {label:14s} {n:5d} grasps, coverage {'-' if cover is None else f'{100 * cover:.1f} %'}")


def run(args: argparse.Namespace) -> int:
    if args.overwrite and not args.out:
        raise EstimatorError("--overwrite: replaces a model in --out; without --out the model is recalibrated in "
                             "place")
    if args.cross_validate is not None:
        if args.out:
            raise EstimatorError("--out: --cross-validate writes nothing; leave --out out")
        result = cross_validate(args.model, args.data, folds=args.cross_validate, seed=args.seed,
                                settings=load_settings(args.settings))
        if args.json:
            print(json.dumps(result, allow_nan=False))
        else:
            _print_cross_validation(result)
        return 0
    meta = recalibrate(args.model, args.data, out_dir=args.out, settings=load_settings(args.settings),
                       overwrite=args.overwrite)
    new, old = meta["calibration"], meta["recalibrated"]["previous"]
    if not meta["metrics"].get("test"):
        left_out = meta["recalibrated"]["left_out"]
        why = f" once the objects its fine-tuning trained on ({', '.join(left_out)}) are left out" if left_out else ""
        print(f"note: no test grasps to score{why}: the metadata's metrics.test is empty", file=sys.stderr)
    if args.json:
        print(json.dumps({"out": args.out or args.model, "calibration": new, "previous": old}, allow_nan=False))
        return 0
    for key in _SHOWN:
        before = old.get(key)
        print(f"{key:15s} {'-' if before is None else f'{before:.4g}':>8s} -> {new[key]:.4g}")
    print(f"force bands     {bands_text(old)}\n             -> {bands_text(new)}")
    print(f"on {new['n']} val grasps; wrote {args.out or args.model}/metadata.json")
    return 0
