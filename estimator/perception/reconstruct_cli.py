"""``estimator reconstruct``: check a calibration on held-out ball presses.

Each press is reconstructed into a depth map, a sphere is fitted to the
indentation (:func:`~estimator.perception.depth.fit_sphere`, no use of the
recorded circle), and its radius is compared with the ball's and its centre
with the press's recorded (or detected) centre. When the presses are the set
the calibration was fitted on (same fingerprint), only the presses it did not
use are checked unless ``--all``; a different set is checked whole.
"""

from __future__ import annotations

import argparse
import json
import math
import sys

import numpy as np

from estimator.errors import CalibrationError
from estimator.measurements import calibration_sensor_mismatch
from estimator.perception.calibrate_cli import add_press_arguments, chosen_sensor, prepare_presses
from estimator.perception.calibration import load_calibration
from estimator.perception.depth import fit_sphere, reconstruct_depth
from estimator.perception.markers import detect_markers
from teleop.progress import progress_bar


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_press_arguments(parser)
    parser.add_argument("--calibration", required=True, metavar="CAL", help="calibration file (.npz)")
    parser.add_argument(
        "--all", action="store_true",
        help="check every press, including those the calibration was fitted on",
    )


def _median(values: list[float]) -> float | None:
    return float(np.median(values)) if values else None


def run(args: argparse.Namespace) -> int:
    calibration = load_calibration(args.calibration)
    presses, _, ball_m, record = prepare_presses(
        args, stated_mm_per_px=(f"{args.calibration} (pixel_pitch_m)", calibration.pixel_pitch_m * 1e3)
    )
    sensor = chosen_sensor(args)
    mismatch = None if sensor is None else calibration_sensor_mismatch(calibration, sensor)
    if mismatch:  # as `teleop doctor` warns: another sensor's colours read as other slopes here
        print(f"warning: {mismatch}: the presses are scored against another sensor's calibration; give "
              f"[sensors.{sensor.finger}]'s own --calibration, or the --finger it was made for", file=sys.stderr)
    if presses.reference.shape[:2] != calibration.image_shape:
        raise CalibrationError(
            f"{args.presses}: images are {presses.reference.shape[:2]} px, the calibration is for "
            f"{calibration.image_shape} (warp them with --settings?)"
        )
    same_set = calibration.provenance.get("presses_sha256") == presses.sha256
    trained = set(calibration.provenance.get("train_indices", [])) if same_set else set()
    indices = [i for i in range(len(presses)) if args.all or i not in trained]
    if not indices:
        raise CalibrationError(
            f"{args.presses}: the calibration used every press; nothing is held out (use --all)"
        )
    results, failures = [], []
    for i in progress_bar(indices, desc="reconstructing presses", unit="press"):
        image = presses.images[i]
        mask = detect_markers(image, presses.reference) if record["markers"] else None
        depth = reconstruct_depth(image, presses.reference, calibration, marker_mask=mask)
        fit = fit_sphere(depth, pixel_pitch_m=calibration.pixel_pitch_m)
        if not fit:
            failures.append({"index": i, "reason": fit.reason})
            continue
        results.append({
            "index": i,
            "radius_mm": fit.radius_m * 1e3,
            "radius_rel_error": abs(fit.radius_m - ball_m) / ball_m,
            "center_px": [round(v, 2) for v in fit.center_px],
            "center_px_error": math.dist(fit.center_px, presses.centers_px[i]),
            "contact_radius_mm": fit.contact_radius_m * 1e3,
            "apex_depth_mm": fit.apex_depth_m * 1e3,
        })
    summary = {
        "n": len(results),
        "n_failed": len(failures),
        "split": "all" if args.all else ("held_out" if same_set else "all (not the calibration's press set)"),
        "ball_radius_mm": ball_m * 1e3,
        "radius_mm_median": _median([r["radius_mm"] for r in results]),
        "radius_rel_error_median": _median([r["radius_rel_error"] for r in results]),
        "center_px_error_median": _median([r["center_px_error"] for r in results]),
        "centers_from": presses.circles,
        "markers": record["markers"],
        "presses": results,
        "failures": failures,
    }
    out = sys.stderr if args.json else sys.stdout
    for r in results:
        print(f"press {r['index']:3d}: radius {r['radius_mm']:.3f} mm ({100 * r['radius_rel_error']:.1f}% off), "
              f"centre {r['center_px_error']:.1f} px from the {presses.circles} one", file=out)
    for f in failures:
        print(f"press {f['index']:3d}: no sphere: {f['reason']}", file=out)
    if results:
        print(f"{len(results)} presses: median radius {summary['radius_mm_median']:.3f} mm "
              f"(median error {100 * summary['radius_rel_error_median']:.1f}%), median centre error "
              f"{summary['center_px_error_median']:.2f} px", file=out)
    if args.json:
        print(json.dumps(summary))
    return 0 if results else 1
