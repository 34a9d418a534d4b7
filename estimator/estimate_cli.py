"""``estimator estimate``: Young's modulus of the object in each grasp record, by one method.

The method is analytical (:func:`~estimator.measure.estimate_grasp`) or learned
(``hybrid``, ``cnn`` or ``auto``: :class:`~estimator.inference.hybrid.HybridEstimator`
over a trained model, loaded once for every record). The records need no label: this is how a
session's exported grasps are read back (``estimator evaluate`` scores labelled ones).
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Callable
from pathlib import Path

from estimator.analytical import METHODS
from estimator.errors import CalibrationError, EstimatorError
from estimator.estimate import Estimate
from estimator.inference.hybrid import ALL_METHODS, HybridEstimator
from estimator.inference.infer import load_predictor
from estimator.measure import estimate_grasp
from estimator.measurements import missing_calibration
from teleop.errors import ComplianceTeleopError
from teleop.record import GraspRecord, read_record
from teleop.settings import Settings, default_settings_path, load_settings

Estimator = Callable[[GraspRecord], tuple[Estimate, str | None]]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.description = (
        "Estimate the grasped object's Young's modulus from each .grasp record given, in order. States: ok (E with "
        "an interval: 90 % for a learned model, as its model card and metadata.json calibration.level "
        "state; for the analytical fits, the fit's own uncertainty, without the error of the contact "
        "mechanics it assumes, so it holds less often: estimator evaluate says how often), lower_bound (stiffer than the data resolve, e.g. "
        "metal: E_pa is the bound), upper_bound (softer than resolved), insufficient_data (a refusal "
        "with its reason; exit status is still 0). A record that cannot be read or measured is named "
        "with the cause on stderr and the others are still estimated, as is a folder with no record in "
        "it; the exit status is then 2. Each latency is the estimate's own: the first record is "
        "estimated once untimed, which loads the calibration and fills the caches, as the live service "
        "does when it starts."
    )
    parser.add_argument("grasps", metavar="GRASP", nargs="+",
                        help="grasp records (.grasp files), or folders searched recursively for them "
                             "(e.g. what `teleop export` wrote)")
    parser.add_argument(
        "--method", choices=ALL_METHODS, default="auto",
        help="auto (as the live service answers): per grasp the cheapest answer whose "
             "expected error fits (the series fit when its interval is narrow enough, else the model); "
             "no_tactile: Hooke on force and width only; elastic: stress F/A over strain with "
             "measured contact area and depth; hertz: Hertz contact through MDR; series: the gel's "
             "share of the approach at the first-contact point; hybrid: a trained model over sampled "
             "tactile frames, force, width and the analytical estimates; cnn: a model trained without "
             "the analytical estimates",
    )
    parser.add_argument(
        "--model", metavar="DIR", default=None,
        help="trained model directory for hybrid, cnn and auto; hybrid needs a model with analytical "
             "inputs, cnn one without (its metadata.json variant says which). Default: the settings' "
             "estimator.model_path, else the shipped model (estimator/models/default)",
    )
    parser.add_argument(
        "--calibration", metavar="CAL", default=None,
        help="colour-to-gradient calibration (.npz); default: the file the record's sensor names "
             "(as the record's settings resolved it)",
    )
    parser.add_argument(
        "--settings", metavar="FILE", default=str(default_settings_path()),
        help="settings TOML: which finger to read, contact force, frames, object Poisson ratio, "
             "finger stiffness",
    )
    parser.add_argument(
        "--camera-lag", action="store_true",
        help="estimate the camera's clock lag from the onset of tactile change and correct for it "
             "(analytical methods only: a model measures a grasp as its training data was measured)",
    )
    parser.add_argument(
        "--no-width-lag", dest="width_lag", action="store_false",
        help="do not estimate and correct how late the gripper widths are stamped (by default it is "
             "estimated from when the fingers stop against the force peak: a host stamps a gripper "
             "read when it returns, ~0.1 s late; analytical methods only)",
    )
    parser.add_argument(
        "--json", action="store_true",
        help="print one JSON object per record, one a line (grasp: its path, E_pa, interval_pa [low, "
             "high] with null for an open side, state, reason, latency_ms, and model: the learned "
             "model's id, null for an analytical method; for a record that failed, or a folder with no record, "
             "grasp and error)",
    )


def _pa(value: float | None) -> str:
    return "-" if value is None else f"{value:.3g} Pa"


def grasp_paths(arguments: list[str]) -> list[tuple[Path, EstimatorError | None]]:
    """The records the arguments name, each with None: files as given, folders' ``.grasp`` files sorted
    by path; a folder without one is named with its EstimatorError, to be reported as an unreadable
    record is while the others are still estimated."""
    paths: list[tuple[Path, EstimatorError | None]] = []
    for argument in arguments:
        path = Path(argument)
        if path.is_dir():
            found = sorted(path.rglob("*.grasp"))
            if not found:
                paths.append((path, EstimatorError(f"{path}: a folder with no .grasp record in it")))
            paths += [(record, None) for record in found]
        else:
            paths.append((path, None))
    return paths


def learned_estimator(args: argparse.Namespace, settings: Settings) -> Estimator:
    """The ``hybrid``, ``cnn`` or ``auto`` estimate of a record with the model ``args.model``, and that
    model's id (:func:`~estimator.inference.infer.model_id`, as the live service names it)."""
    if args.camera_lag:
        raise EstimatorError(f"--camera-lag: applies to the analytical methods, not {args.method} (a model "
                             "measures a grasp as its training data was measured)")
    predictor = load_predictor(args.model, settings=settings)
    variant = predictor.variant
    if args.method != "auto" and variant.method != args.method:
        need = "without" if args.method == "cnn" else "with"
        raise EstimatorError(f"--method {args.method}: model {predictor.model_dir} is a {variant.method} "
                             f"({variant.name}); {args.method} needs a model trained {need} analytical "
                             "inputs (--model DIR)")
    estimator = HybridEstimator(predictor, settings=settings, calibration=args.calibration)
    mode = "auto" if args.method == "auto" else "model"
    return explained(lambda record: (estimator.estimate(record, mode=mode), predictor.model_id), args, settings,
                     markers=variant.markers)


def analytical_estimator(args: argparse.Namespace, settings: Settings) -> Estimator:
    """The analytical method ``args.method``'s estimate of a record (no model: None)."""
    if args.model is not None:
        raise EstimatorError(f"--model: applies to hybrid, cnn and auto, not {args.method}")
    return explained(lambda record: (estimate_grasp(record, args.method, settings=settings,
                                                    calibration=args.calibration, correct_camera_lag=args.camera_lag,
                                                    correct_width_lag=args.width_lag), None), args, settings)


def explained(estimate_record: Estimator, args: argparse.Namespace, settings: Settings, *,
              markers: bool = False) -> Estimator:
    """``estimate_record`` whose CalibrationError for a calibration file the record names and that is
    gone says what to do, as ``estimator evaluate`` does
    (:func:`~estimator.measurements.missing_calibration`): that of the settings' finger unless
    ``--calibration`` gives one, and with ``markers`` (a model reading them) the marker finger's."""
    def estimate(record: GraspRecord) -> tuple[Estimate, str | None]:
        try:
            return estimate_record(record)
        except CalibrationError as exc:
            missing = missing_calibration(record, settings.sensing.finger, args.calibration, markers=markers)
            if not missing:
                raise
            raise CalibrationError(missing) from exc
    return estimate


def run(args: argparse.Namespace) -> int:
    settings = load_settings(args.settings)
    make = analytical_estimator if args.method in METHODS else learned_estimator
    estimate_record = make(args, settings)
    paths = grasp_paths(args.grasps)
    name_each = len(args.grasps) > 1 or Path(args.grasps[0]).is_dir()
    warm = False
    failed = 0
    for path, unreadable in paths:
        try:
            if unreadable is not None:
                raise unreadable
            record = read_record(path)
            if not warm:
                estimate_record(record)  # untimed: the calibration and the caches, loaded once
                warm = True
            estimate, model = estimate_record(record)
        except ComplianceTeleopError as exc:
            failed += 1
            where = "" if str(path) in str(exc) else f"{path}: "
            print(f"estimator estimate: error: {where}{exc}", file=sys.stderr)
            if args.json:
                print(json.dumps({"grasp": str(path), "error": str(exc)}), flush=True)
            continue
        if args.json:
            print(json.dumps({"grasp": str(path), **estimate.to_json(), "model": model}, allow_nan=False), flush=True)
            continue
        low, high = estimate.interval_pa
        by = "" if model is None else f", model {model}"
        if name_each:
            print(path)
        print(f"{args.method}: {estimate.state}  E = {_pa(estimate.e_pa)}  interval [{_pa(low)}, {_pa(high)}]  "
              f"({estimate.latency_s * 1e3:.1f} ms{by})")
        print(f"  {estimate.reason}", flush=True)
    return 2 if failed else 0
