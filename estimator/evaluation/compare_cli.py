"""``estimator compare``: score a base and a candidate model on labelled records neither trained on and say
which is better (:mod:`estimator.evaluation.compare`, whose notes give the scoring and the verdict)."""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Mapping
from typing import Any

from estimator.errors import EstimatorError, ModelError
from estimator.evaluation.compare import (
    LEVEL,
    MIN_OBJECTS,
    MODES,
    RESAMPLES,
    SEED,
    NothingToCompare,
    compare_models,
)
from estimator.evaluation.evaluate_cli import fmt_value, print_skipped
from estimator.inference.provenance import trained_objects
from teleop.settings import default_settings_path, load_settings

__all__ = ["add_arguments", "print_comparison", "run"]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.description = (
        "Score a base and a candidate model (a fine-tuned one, say) on the labelled .grasp records under "
        "RECORDS whose object neither model trained on (each model's train, val and fine-tuning objects are "
        "left out; any other object counts, whatever the records' source), as the service answers (auto), "
        "and say which is better by the felt error (what the display renders, against the label): base, "
        f"candidate or undecided. The uncertainty comes from the number of objects: a paired bootstrap over "
        f"objects ({RESAMPLES} resamples, seed {SEED}) gives the {LEVEL * 100:g} % interval of candidate minus base; "
        f"undecided when it contains 0 or with fewer than {MIN_OBJECTS} objects. Per model the figures of "
        "`estimator evaluate` (felt error, within a factor 2, dangerous misses, rigid objects shown rigid, "
        "coverage, interval widths, soft objects' width) and the share of grasps answered. Skipped records "
        "are listed with their cause; with no record left the command fails."
    )
    parser.add_argument("records", metavar="RECORDS", help="directory searched recursively for .grasp records")
    parser.add_argument("--base", required=True, metavar="MODEL_DIR", help="the model in use (e.g. "
                        "estimator/models/default)")
    parser.add_argument("--candidate", required=True, metavar="MODEL_DIR",
                        help="the model that would replace it (e.g. the output of `estimator fine-tune`)")
    parser.add_argument("--settings", metavar="FILE", default=str(default_settings_path()),
                        help="settings TOML of the rig: estimator sections, and the display's range for the felt "
                             "figures")
    parser.add_argument("--calibration", metavar="CAL", default=None,
                        help="calibration (.npz) for every record; default: the file each record's sensor names")
    parser.add_argument("--mode", choices=MODES, default="auto",
                        help="auto: answer as the service does (the series-compliance fit where its interval is "
                             "narrow, else the network); model: the network alone")
    parser.add_argument("--workers", type=int, default=1, help="worker processes")
    parser.add_argument("--json", action="store_true",
                        help="print one JSON object on the last stdout line: base and candidate (their figures), "
                             "difference (felt error, candidate minus base, and its interval), better, "
                             "dangerous_misses_increase, verdict, objects, skipped")


def print_comparison(result: Mapping[str, Any], *, file: Any = None) -> None:
    """The comparison as a short table and the verdict in one sentence."""
    print(f"compared on {result['grasps']} grasps of {result['n_objects']} objects neither model trained on "
          f"({result['records']} records; answering: {result['mode']})", file=file)
    print(f"{'model':<9} {'n':>4} {'felt err':>8} {'felt2x':>7} {'danger':>6} {'rigid':>6} {'answered':>8} "
          f"{'coverage':>8} {'width':>6} {'soft width':>10}  dir", file=file)
    for role in ("base", "candidate"):
        m = result[role]
        print(f"{role:<9} {m['n']:>4} {fmt_value(m['felt_log10_error'], '8.3f')} {fmt_value(m['felt_within_2x'], '7.1%')} "
              f"{m['dangerous_misses'] if m['dangerous_misses'] is not None else '-':>6} "
              f"{fmt_value(m['rigid_shown_rigid'], '6.1%')} {fmt_value(m['answered'], '8.1%')} "
              f"{fmt_value(m['interval_coverage'], '8.1%')} {fmt_value(m['interval_width_decades_median'], '6.2f')} "
              f"{fmt_value(m['soft_interval_width_decades_median'], '10.2f')}  {m['model']}", file=file)
    if not any(result[role].get("soft_n") for role in ("base", "candidate")):
        print("note: no soft object (label at or below 3 MPa) among them: the display's scale, where models "
              "differ, is not tested; add held-out soft objects", file=file)
    print(result["verdict"], file=file)


def run(args: argparse.Namespace) -> int:
    if args.workers < 1:
        raise EstimatorError(f"--workers {args.workers}: expected at least 1")
    settings = load_settings(args.settings)
    for option, model in (("--base", args.base), ("--candidate", args.candidate)):
        try:
            trained_objects(model)
        except ModelError as exc:
            raise ModelError(f"{option} {exc}") from exc
    try:
        result = compare_models(args.base, args.candidate, args.records, settings=settings,
                                calibration=args.calibration, mode=args.mode, workers=args.workers)
    except NothingToCompare as exc:
        print_skipped(exc.skipped, len(exc.skipped), file=sys.stderr)
        raise
    if args.json:
        print(json.dumps(result, allow_nan=False))
        return 0
    print_skipped(result["skipped"], result["records"])
    print_comparison(result)
    return 0
