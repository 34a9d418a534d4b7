"""``estimator build-dataset``: labelled grasp records to training samples, split by object
(:mod:`estimator.training.dataset`); also the ``ROWSxCOLS`` and ``HEIGHTxWIDTH`` option parsers."""

from __future__ import annotations

import argparse
import json
import os
import re
import sys

from estimator.errors import EstimatorError
from estimator.inference.inputs import size_px_ok, size_px_range_text
from estimator.inference.provenance import SPLITS
from estimator.training.dataset import DEFAULT_FRACTIONS, DatasetOptions, build_dataset
from teleop.clikit import help_literal, non_negative_int
from teleop.record import find_records
from teleop.settings import config_dir, default_settings_path, load_settings


def parse_size(text: str) -> tuple[int, int]:
    """``ROWSxCOLS`` -> (rows, cols), within what a model may read (:data:`~estimator.inference.inputs.SIZE_PX_RANGE`)."""
    match = re.fullmatch(r"(\d+)x(\d+)", text.strip())
    if not match:
        raise argparse.ArgumentTypeError(f"size {text!r}: expected ROWSxCOLS, e.g. 64x88")
    rows, cols = int(match.group(1)), int(match.group(2))
    # Refused here, not after a build that training would then refuse.
    if not size_px_ok(rows, cols):
        raise argparse.ArgumentTypeError(f"size {text!r}: expected {size_px_range_text()}")
    return rows, cols


def parse_window_mm(text: str) -> tuple[float, float]:
    """``HEIGHTxWIDTH`` in mm -> (height, width) in m."""
    match = re.fullmatch(r"(\d+(?:\.\d*)?)x(\d+(?:\.\d*)?)", text.strip())
    if not match or not all(float(v) > 0 for v in match.groups()):
        raise argparse.ArgumentTypeError(f"window {text!r}: expected HEIGHTxWIDTH in mm, e.g. 22.73x31.82")
    return float(match.group(1)) * 1e-3, float(match.group(2)) * 1e-3


def _fractions(text: str) -> tuple[float, float, float]:
    try:
        values = tuple(float(v) for v in text.split(","))
    except ValueError:
        values = ()
    if len(values) != 3:
        raise argparse.ArgumentTypeError(f"split {text!r}: expected TRAIN,VAL,TEST fractions, e.g. 0.7,0.15,0.15")
    return values


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.description = (
        "Turn labelled .grasp records into training samples with the live estimator's own "
        "measurement code (segmentation, warp, depth, contact features, analytical fits), split "
        "by object into train/val/test (seeded, stratified by material) so that no grasp or "
        "augmentation of a val or test object is ever trained on. Writes OUT/dataset.json, "
        "OUT/split.json and OUT/<split>/<object>/<object>_g<i>_a<k>.npz (i: the object's i-th record in "
        "path order; dataset.json lists which record gave which samples, and every record skipped with "
        "its cause). OUT is written beside itself under a hidden name and appears only when complete. "
        "Exits non-zero when no sample could be made."
    )
    parser.add_argument("--records", required=True, metavar="DIR",
                        help="directory searched recursively for labelled .grasp records")
    parser.add_argument("--out", required=True, metavar="DIR",
                        help="output directory (created; must not exist yet, or be empty)")
    parser.add_argument("--frames", type=int, default=3, metavar="N",
                        help="frames sampled equidistantly in time over each loading phase")
    parser.add_argument("--shifts", type=int, default=3, metavar="K",
                        help="sample sets per grasp: set k starts k loading frames after contact "
                             "(set 0 is the live sampling; later sets need N distinct frames)")
    parser.add_argument("--size", type=parse_size, default=(64, 88), metavar="ROWSxCOLS",
                        help="images and depth are stored area-averaged to this size (the sensor "
                             "grid is 250x350); the model reads them at this size (default: 64x88)")
    parser.add_argument("--window", type=parse_window_mm, default=None, metavar="HEIGHTxWIDTH",
                        help="gel patch (mm) the images show, centred on each record's pad (cut from a larger "
                             "pad, zero-padded around a smaller one); the model's input pitch is this over "
                             "--size (default: the pad of the settings' estimator sensor, 22.73x31.82 for the "
                             "simulated Wedge)")
    parser.add_argument("--markers", action="store_true",
                        help="also store the other finger's (marker sensor's) images and depth")
    parser.add_argument("--calibration", metavar="CAL", default=None,
                        help="calibration (.npz) of the estimator's finger for every record; default: "
                             "the one each record carries (`teleop export` puts it inside), else the file "
                             f"its sensor names (a relative name is under {help_literal(config_dir())})")
    parser.add_argument("--marker-calibration", metavar="CAL", default=None,
                        help="calibration of the marker finger (with --markers); default: the file "
                             "its sensor names")
    parser.add_argument("--split", type=_fractions, default=DEFAULT_FRACTIONS, metavar="TRAIN,VAL,TEST",
                        help="object fractions of the three splits (default: "
                             f"{','.join(f'{f:g}' for f in DEFAULT_FRACTIONS)})")
    parser.add_argument("--seed", type=non_negative_int, default=0, help="seed of the object split")
    parser.add_argument("--workers", type=int, default=1, metavar="W", help="worker processes")
    parser.add_argument("--settings", metavar="FILE", default=str(default_settings_path()),
                        help="settings TOML (estimator and gripper sections are used)")
    parser.add_argument("--json", action="store_true",
                        help="print the manifest (with 'skipped': [{path, cause, reason}] and 'used') as one "
                             "JSON object on the last stdout line")


def run(args: argparse.Namespace) -> int:
    if args.workers < 1 or args.frames < 1 or args.shifts < 1:
        raise EstimatorError(f"--workers {args.workers}, --frames {args.frames}, --shifts {args.shifts}: "
                             "expected each >= 1")
    paths = find_records(args.records, name="--records")
    options = DatasetOptions(n_frames=args.frames, shifts=args.shifts, size_px=args.size, window_m=args.window,
                             markers=args.markers,
                             calibration=args.calibration, marker_calibration=args.marker_calibration)
    manifest = build_dataset(paths, args.out, settings=load_settings(args.settings), options=options,
                             seed=args.seed, fractions=args.split,
                             workers=min(args.workers, os.cpu_count() or 1, len(paths)))
    for item in manifest["skipped"]:
        print(f"skipped {item['path']}: {item['reason']}", file=sys.stderr)
    if args.json:
        print(json.dumps(manifest | {"out": str(args.out)}))
        return 0
    print(f"{sum(manifest['samples'].values())} samples from {manifest['grasps_used']} of {len(paths)} records "
          f"in {manifest['seconds']:.1f} s -> {args.out}")
    for s in SPLITS:
        print(f"  {s:<5} {manifest['objects'][s]:>4} objects {manifest['samples'][s]:>6} samples")
    if manifest["skipped_reasons"]:
        print(f"  skipped {len(manifest['skipped'])} records (listed above): "
              + ", ".join(f"{k} ({v})" for k, v in manifest["skipped_reasons"].items()))
    return 0
