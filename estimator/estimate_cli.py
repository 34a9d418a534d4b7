"""``estimator estimate``: Young's modulus of the object in one grasp record, by one method."""

from __future__ import annotations

import argparse
import json

from estimator.analytical import METHODS
from estimator.measure import estimate_grasp
from teleop.record import read_record
from teleop.settings import default_settings_path, load_settings


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.description = (
        "Estimate the grasped object's Young's modulus from one .grasp record. States: ok (E with "
        "a ~95 % interval), lower_bound (stiffer than the data resolve, e.g. metal: E_pa is the "
        "bound), upper_bound (softer than resolved), insufficient_data (a refusal with its reason; "
        "exit status is still 0)."
    )
    parser.add_argument("grasp", metavar="GRASP", help="grasp record (.grasp file)")
    parser.add_argument(
        "--method", choices=METHODS, default="split",
        help="no_tactile: Hooke on force and width only; elastic: stress F/A over strain with "
             "measured contact area and depth; hertz: Hertz contact through MDR; split: the gel's "
             "share of the approach at the first-contact point",
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
        help="estimate the camera's clock lag from the onset of tactile change and correct for it",
    )
    parser.add_argument(
        "--no-width-lag", dest="width_lag", action="store_false",
        help="do not estimate and correct how late the gripper widths are stamped (by default it is "
             "estimated from when the fingers stop against the force peak: a host stamps a gripper "
             "read when it returns, ~0.1 s late)",
    )
    parser.add_argument(
        "--json", action="store_true",
        help="print one JSON object (E_pa, interval_pa [low, high] with null for an open side, "
             "state, reason, latency_ms) on the last stdout line",
    )


def _pa(value: float | None) -> str:
    return "-" if value is None else f"{value:.3g} Pa"


def run(args: argparse.Namespace) -> int:
    settings = load_settings(args.settings)
    record = read_record(args.grasp)
    estimate = estimate_grasp(record, args.method, settings=settings, calibration=args.calibration,
                              correct_camera_lag=args.camera_lag, correct_width_lag=args.width_lag)
    if args.json:
        print(json.dumps({"grasp": args.grasp, **estimate.to_json()}, allow_nan=False))
        return 0
    low, high = estimate.interval_pa
    print(f"{args.method}: {estimate.state}  E = {_pa(estimate.e_pa)}  interval [{_pa(low)}, {_pa(high)}]  "
          f"({estimate.latency_s * 1e3:.1f} ms)")
    print(f"  {estimate.reason}")
    return 0
