"""``estimator bench``: latency and error of every estimator configuration (:mod:`estimator.evaluation.bench`).

Besides :func:`~estimator.evaluation.bench.bench`'s figures, the result (``--json``) lists under ``models``
each model with ``measurement_code_matches``: whether this code measures grasps as the code
that built its training data did (when not, its figures are those of a model fed inputs it
was not trained on).

The records skipped (unreadable or unlabelled) are named with their cause as ``estimator evaluate``
names them: listed under the header (on stderr with ``--json``, so stdout stays one JSON object), and
before the error when none is left to bench.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from estimator.errors import EstimatorError
from estimator.evaluation.bench import NothingToBench, bench, configurations, plot
from estimator.evaluation.evaluate_cli import print_skipped
from estimator.inference.infer import CompliancePredictor, default_model_dir
from estimator.settings import estimator_settings
from teleop.clikit import PLOT_SUFFIXES, output_file
from teleop.record import find_records
from teleop.settings import default_settings_path, load_settings


def _frame_count(text: str) -> int:
    """An argparse type: a frame count 1..64, the range of the settings' n_frames and of a model's
    (checked before benching starts, not by the sampler mid-run)."""
    try:
        value = int(text)
    except ValueError:
        value = 0
    if not 1 <= value <= 64:
        raise argparse.ArgumentTypeError(f"{text!r}: expected a whole number of frames in 1..64")
    return value


def cell(value: float | None, spec: str, width: int) -> str:
    """A table cell: ``value`` formatted by ``spec``, or "-" for None, right-aligned to ``width``."""
    return f"{'-' if value is None else format(value, spec):>{width}}"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.description = (
        "Median latency per grasp on one core (in-process, from decoded frames, after warm-up) and "
        "error over the labelled .grasp records in DIR of every configuration: each analytical "
        "method over all loading frames and over N sampled frames, the tactile ones on coarser depth "
        "grids (--binning), each model given (hybrid or cnn) and its auto mode. Marks the Pareto "
        "frontier of latency against error."
    )
    parser.add_argument("dir", metavar="DIR", help="directory searched recursively for labelled .grasp records")
    parser.add_argument("--models", nargs="*", metavar="MODEL_DIR", default=None,
                        help="trained model directories (default: the shipped default model, when present)")
    parser.add_argument("--frames", type=_frame_count, nargs="*", metavar="N", default=None,
                        help="frame counts of the sampled analytical configurations (default: those of the "
                             "models, else the settings' n_frames)")
    parser.add_argument("--binning", type=int, nargs="*", metavar="K", default=[],
                        help="also run the tactile analytical methods with depth measured on the image grid "
                             "binned by K (K x K pixel blocks averaged) instead of the settings' "
                             "estimator.depth_binning; K divides both sides of the image grid and the raw frame, "
                             "e.g. 1 (the full grid) or 5 for 250 x 350 px from 640 x 480: speed against error (default: "
                             "none, only the settings' binning)")
    parser.add_argument("--repeats", type=int, default=5, help="timed runs per grasp and configuration")
    parser.add_argument("--limit", type=int, default=None, metavar="K", help="bench only the first K records")
    parser.add_argument("--calibration", metavar="CAL", default=None,
                        help="calibration (.npz) for every record; default: the file each record's sensor names")
    parser.add_argument("--no-width-lag", dest="width_lag", action="store_false",
                        help="do not estimate and correct how late each record's widths are stamped (analytical "
                             "methods over all loading frames), as estimator evaluate --no-width-lag; by default "
                             "they are scored as estimator evaluate scores them")
    parser.add_argument("--settings", metavar="FILE", default=str(default_settings_path()), help="settings TOML")
    parser.add_argument("--plot", metavar="PNG", default=None, help="write latency (log x) against error with the frontier")
    parser.add_argument("--json", action="store_true",
                        help='print {"configs": [{"name", "latency_ms_p50", "felt_log10_error", "felt_within_2x", '
                             '"log10_error", "within_10x", "pareto", ...}], ...} as one JSON object on the last '
                             'stdout line')


def run(args: argparse.Namespace) -> int:
    for option, value in (("--repeats", args.repeats), ("--limit", args.limit)):
        if value is not None and value < 1:
            raise EstimatorError(f"{option} {value}: expected at least 1")
    output_file("--plot", args.plot, suffixes=PLOT_SUFFIXES)
    root = Path(args.dir)
    paths = find_records(root)[: args.limit]
    settings = load_settings(args.settings)
    model_dirs = args.models
    if model_dirs is None:
        model_dirs = [default_model_dir()] if (default_model_dir() / "metadata.json").is_file() else []
    models = [CompliancePredictor(d, threads=1) for d in model_dirs]
    frames = args.frames
    if frames is None:
        frames = sorted({m.variant.n_frames for m in models}) or [estimator_settings(settings).n_frames]
    configs = configurations(settings=settings, calibration=args.calibration, frames=frames, models=models,
                             binning=args.binning, correct_width_lag=args.width_lag)
    try:
        benched = bench(paths, settings=settings, configs=configs, calibration=args.calibration,
                    repeats=args.repeats)
    except NothingToBench as exc:
        print_skipped(exc.skipped, len(paths), file=sys.stderr)
        raise EstimatorError(f"{root}: {exc}" + ("; listed above" if exc.skipped else "")) from exc
    result = {"dir": str(root), **benched,
              "models": [{"dir": str(m.model_dir), "variant": m.variant.name,
                          "measurement_code_matches": m.measurement_code_matches} for m in models],
              "plot": args.plot}
    if args.plot:
        plot(result, args.plot)
    if args.json:
        print_skipped(result["skipped_records"], result["records"], file=sys.stderr)
        print(json.dumps(result, allow_nan=False))
        return 0
    for m in result["models"]:
        if not m["measurement_code_matches"]:
            print(f"note: {m['dir']} was trained on inputs measured by other code; its figures are not its own")
    ref = result["reference_ms_p50"]
    print(f"{result['labelled']} labelled grasps, {args.repeats} timed runs each, one core: {result['one_core']}; "
          f"no-contact reference alone {'-' if ref is None else f'{ref:.1f}'} ms")
    print_skipped(result["skipped_records"], result["records"])
    print(f"{'configuration':<44} {'p50 ms':>8} {'felt err':>8} {'felt2x':>6} {'log10 err':>9} {'within10x':>9} "
          f"{'refused':>7}  pareto")
    for c in sorted(result["configs"], key=lambda c: c["latency_ms_p50"]):
        cells = [cell(c["felt_log10_error"], ".3f", 8), cell(c["felt_within_2x"], ".0%", 6),
                 cell(c["log10_error"], ".2f", 9), cell(c["within_10x"], ".0%", 9)]
        print(f"{c['name']:<44} {c['latency_ms_p50']:>8.2f} {' '.join(cells)} {c['refusals']:>7}  "
              f"{'*' if c['pareto'] else ''}")
    return 0
