"""``estimator train``: the command line of :mod:`estimator.learned.train` (its notes give the recipe)."""

from __future__ import annotations

import argparse
import json
from collections.abc import Sequence
from typing import Any

from estimator.errors import EstimatorError
from estimator.learned.dataset import load_manifest
from estimator.learned.dataset_cli import parse_size
from estimator.learned.infer import bands_text
from estimator.learned.inputs import ANALYTICAL_METHODS, Variant
from estimator.learned.train import TrainConfig, dataset_window, train_model
from teleop.settings import load_settings


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.description = (
        "Train the multi-tower network on the train objects of a build-dataset directory, stop early "
        "on its val objects, export it to ONNX (checked against torch to 1e-4) and score it on the "
        "test objects beside the analytical methods. Writes MODEL_DIR/model.onnx, metadata.json and "
        "training_curve.png."
    )
    parser.add_argument("--data", required=True, metavar="DIR", help="directory written by `estimator build-dataset`")
    parser.add_argument("--out", required=True, metavar="MODEL_DIR", help="directory for the model (created)")
    parser.add_argument("--variant", default="depth+fw+analytical", metavar="SPEC",
                        help="inputs: depth or rgb, then any of +markers (the other finger's images), +fw "
                             "(force and width per frame), +analytical (the analytical estimates: a hybrid "
                             "model; without it the CNN alone)")
    parser.add_argument("--frames", type=int, default=None, metavar="N",
                        help="frames per sample (default: the dataset's; must equal it)")
    parser.add_argument("--size", type=parse_size, default=None, metavar="ROWSxCOLS",
                        help="input size (default: the dataset's; must equal it)")
    parser.add_argument("--epochs", type=int, default=TrainConfig.epochs, help="maximum epochs")
    parser.add_argument("--patience", type=int, default=TrainConfig.patience,
                        help="stop after this many epochs without a better validation error")
    parser.add_argument("--batch-size", type=int, default=TrainConfig.batch_size, help="samples per step")
    parser.add_argument("--lr", type=float, default=TrainConfig.lr, help="AdamW learning rate (cosine decay)")
    parser.add_argument("--weight-decay", type=float, default=TrainConfig.weight_decay, help="AdamW weight decay")
    parser.add_argument("--settings", metavar="FILE", default=None,
                        help="settings TOML whose estimating sensor's resolution limit the intervals are "
                             "calibrated at (default: the shipped configs/settings.toml)")
    parser.add_argument("--label-sd", dest="label_sd", type=float, default=TrainConfig.label_sd_decades,
                        metavar="DECADES",
                        help="standard deviation of the normal jitter added to log10 of each label at every step: "
                             "the published labels are material-class values, uncertain by about a factor of 2")
    parser.add_argument("--seed", type=int, default=TrainConfig.seed, help="seed of weights, shuffles and flips")
    parser.add_argument("--threads", type=int, default=TrainConfig.threads, help="torch CPU threads")
    parser.add_argument("--json", action="store_true",
                        help="print one JSON object (out, variant, epochs_run, best_epoch, metrics) on the last "
                             "stdout line")


def _variant(args: argparse.Namespace, manifest: dict[str, Any]) -> Variant:
    frames, size = manifest["n_frames"], tuple(manifest["size_px"])
    if args.frames is not None and args.frames != frames:
        raise EstimatorError(f"--frames {args.frames}: the dataset holds {frames} frames per sample")
    if args.size is not None and tuple(args.size) != size:
        raise EstimatorError(f"--size {args.size[0]}x{args.size[1]}: the dataset holds {size[0]}x{size[1]} images")
    return Variant.parse(args.variant, n_frames=frames, size_px=size, window_m=dataset_window(manifest, args.data))


def _share(value: float | None) -> str:
    return "-" if value is None else f"{value:.1%}"


def _fmt(metrics: dict[str, Any], method: str) -> str:
    m = metrics.get(method) or {}
    if m.get("log10_error") is None:
        return "-"
    felt = "" if m.get("felt_log10_error") is None else f", felt {m['felt_log10_error']:.2f} / {m['felt_within_2x']:.0%}"
    return f"{m['log10_error']:.2f} / {m['within_10x']:.0%}{felt} (n={m['n']})"


def run(args: argparse.Namespace) -> int:
    manifest = load_manifest(args.data)
    variant = _variant(args, manifest)
    config = TrainConfig(epochs=args.epochs, batch_size=args.batch_size, lr=args.lr, weight_decay=args.weight_decay,
                         patience=args.patience, label_sd_decades=args.label_sd, seed=args.seed,
                       threads=args.threads)
    meta = train_model(args.data, args.out, variant=variant, config=config, settings=load_settings(args.settings))
    training = meta["training"]
    if args.json:
        print(json.dumps({"out": str(args.out), "variant": variant.name, "epochs_run": training["epochs_run"],
                          "best_epoch": training["best_epoch"], "seconds": training["seconds"],
                          "metrics": meta["metrics"]}, allow_nan=False))
        return 0
    cal = meta["calibration"]
    print(f"{variant.name} ({variant.n_frames} frames, {variant.size_px[0]}x{variant.size_px[1]}): best epoch "
          f"{training['best_epoch']} of {training['epochs_run']}, {training['seconds']:.0f} s -> {args.out}")
    for split in ("val", "test"):
        metrics = meta["metrics"][split]
        if metrics:
            methods: Sequence[str] = [variant.method, *ANALYTICAL_METHODS]
            print(f"  {split:<4} ({metrics['objects']} objects) log10 error / within 10x: "
                  + ", ".join(f"{m} {_fmt(metrics, m)}" for m in methods))
    print(f"  calibration on val: temperature {cal['temperature']:.2f}; {cal['level']:.0%} answers per force band: "
          f"{bands_text(cal)}; coverage ok {_share(cal['ok_coverage'])} of {cal['n_ok']}, bounds "
          f"{_share(cal['bound_coverage'])}, all {_share(cal['coverage'])} of {cal['n']}")
    return 0
