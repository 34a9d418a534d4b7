"""``estimator estimate``: Young's modulus of the object in one grasp record, by one method.

The method is analytical (:func:`~estimator.measure.estimate_grasp`) or learned
(``hybrid``, ``cnn`` or ``auto``: :class:`~estimator.inference.hybrid.HybridEstimator`
over a trained model).
"""

from __future__ import annotations

import argparse
import json

from estimator.analytical import METHODS
from estimator.errors import EstimatorError
from estimator.estimate import Estimate
from estimator.inference.hybrid import ALL_METHODS, HybridEstimator
from estimator.inference.infer import load_predictor
from estimator.measure import estimate_grasp
from teleop.record import GraspRecord, read_record
from teleop.settings import Settings, default_settings_path, load_settings


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.description = (
        "Estimate the grasped object's Young's modulus from one .grasp record. States: ok (E with "
        "an interval: 90 % for a learned model, as its model card and metadata.json calibration.level "
        "state; about 95 % for the analytical fits), lower_bound (stiffer than the data resolve, e.g. "
        "metal: E_pa is the bound), upper_bound (softer than resolved), insufficient_data (a refusal "
        "with its reason; exit status is still 0)."
    )
    parser.add_argument("grasp", metavar="GRASP", help="grasp record (.grasp file)")
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
             "(relative to configs/)",
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
        help="print one JSON object (E_pa, interval_pa [low, high] with null for an open side, "
             "state, reason, latency_ms, and model: the learned model's id, null for an analytical "
             "method) on the last stdout line",
    )


def _pa(value: float | None) -> str:
    return "-" if value is None else f"{value:.3g} Pa"


def learned_estimate(record: GraspRecord, args: argparse.Namespace, settings: Settings) -> tuple[Estimate, str]:
    """The ``hybrid``, ``cnn`` or ``auto`` estimate of ``record`` with the model ``args.model``, and that
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
    return estimator.estimate(record, mode="auto" if args.method == "auto" else "model"), predictor.model_id


def run(args: argparse.Namespace) -> int:
    if args.method in METHODS and args.model is not None:
        raise EstimatorError(f"--model: applies to hybrid, cnn and auto, not {args.method}")
    settings = load_settings(args.settings)
    record = read_record(args.grasp)
    model = None
    if args.method in METHODS:
        estimate = estimate_grasp(record, args.method, settings=settings, calibration=args.calibration,
                                  correct_camera_lag=args.camera_lag, correct_width_lag=args.width_lag)
    else:
        estimate, model = learned_estimate(record, args, settings)
    if args.json:
        print(json.dumps({"grasp": args.grasp, **estimate.to_json(), "model": model}, allow_nan=False))
        return 0
    low, high = estimate.interval_pa
    by = "" if model is None else f", model {model}"
    print(f"{args.method}: {estimate.state}  E = {_pa(estimate.e_pa)}  interval [{_pa(low)}, {_pa(high)}]  "
          f"({estimate.latency_s * 1e3:.1f} ms{by})")
    print(f"  {estimate.reason}")
    return 0
