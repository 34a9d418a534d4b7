"""``estimator train``: the command line of :mod:`estimator.training.train` (its notes give the recipe), and with
``--init`` of :mod:`estimator.training.finetune`."""

from __future__ import annotations

import argparse
import json
from collections.abc import Sequence
from dataclasses import replace
from typing import Any

from estimator.errors import EstimatorError
from estimator.inference.infer import CompliancePredictor, bands_text
from estimator.inference.inputs import ANALYTICAL_METHODS, Variant
from estimator.training.dataset import load_manifest
from estimator.training.dataset_cli import parse_size
from estimator.training.finetune_cli import fine_tune_and_report
from estimator.training.outdir import OVERWRITE_HELP
from estimator.training.recipe import FINE_TUNE_CONFIG, REPLAY_RATIO, TrainConfig
from estimator.training.splits import dataset_window
from teleop.clikit import help_literal, non_negative_int
from teleop.settings import default_settings_path, load_settings

DEFAULT_VARIANT = "depth+fw+analytical"
#: The most ``--threads`` taken: past a few per core threads only spin against each other, and torch
#: refuses a count beyond a C int only after the data is loaded, with a traceback.
MAX_THREADS = 1024


def thread_count(text: str) -> int:
    """An argparse type: torch CPU threads, a whole number from 1 to :data:`MAX_THREADS`."""
    try:
        value = int(text)
    except ValueError:
        value = 0
    if not 1 <= value <= MAX_THREADS:
        raise argparse.ArgumentTypeError(f"{text!r}: expected a whole number from 1 to {MAX_THREADS}")
    return value


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.description = (
        "Train the multi-tower network on the train objects of a build-dataset directory, stop early "
        "on its val objects, export it to ONNX (checked against torch to 1e-4) and score it on the "
        "test objects beside the analytical methods. Writes MODEL_DIR/model.onnx, metadata.json and "
        "training_curve.png. With --init MODEL_DIR, fine-tune that trained model on DIR instead (the recipe "
        "of `estimator fine-tune`, which also offers a leave-one-object-out --check)."
    )
    parser.add_argument("--data", required=True, metavar="DIR", help="directory written by `estimator build-dataset`")
    parser.add_argument("--out", required=True, metavar="MODEL_DIR",
                        help="directory for the model (created; must not exist yet, or be empty, unless --overwrite)")
    parser.add_argument("--overwrite", action="store_true", help=OVERWRITE_HELP)
    parser.add_argument("--init", metavar="MODEL_DIR", default=None,
                        help="fine-tune this trained model (a shipped one, say) on the few labelled grasps of DIR "
                             "instead of training from scratch: every sample of every split trains, batch-norm "
                             "statistics stay, no early stopping; the new model counts DIR's objects as trained on")
    parser.add_argument("--replay", metavar="DIR", default=None,
                        help="with --init: the base model's training dataset, rehearsed while fine-tuning so the "
                             "model forgets less; the intervals are then recalibrated on its val objects (without "
                             "it they stay the base model's)")
    parser.add_argument("--replay-ratio", type=float, default=None,
                        help="with --replay: replayed samples per new sample in each epoch "
                             f"(default: {REPLAY_RATIO:g})")
    parser.add_argument("--variant", default=None, metavar="SPEC",
                        help="inputs: depth or rgb, then any of +markers (the other finger's images), +fw "
                             "(force and width per frame), +analytical (the analytical estimates: a hybrid "
                             f"model; without it the CNN alone) (default: {DEFAULT_VARIANT}; with --init, the "
                             "model's)")
    parser.add_argument("--frames", type=int, default=None, metavar="N",
                        help="frames per sample (default: the dataset's; must equal it)")
    parser.add_argument("--size", type=parse_size, default=None, metavar="ROWSxCOLS",
                        help="input size (default: the dataset's; must equal it)")
    parser.add_argument("--epochs", type=int, default=None,
                        help=f"maximum epochs (default: {TrainConfig.epochs}; with --init, "
                             f"{FINE_TUNE_CONFIG.epochs}, all run)")
    parser.add_argument("--patience", type=int, default=None,
                        help="stop after this many epochs without a better validation error "
                             f"(default: {TrainConfig.patience}; not with --init)")
    parser.add_argument("--batch-size", type=int, default=None,
                        help=f"samples per step (default: {TrainConfig.batch_size}; with --init, "
                             f"{FINE_TUNE_CONFIG.batch_size})")
    parser.add_argument("--lr", type=float, default=None,
                        help=f"AdamW learning rate, cosine decay (default: {TrainConfig.lr:g}; with --init, "
                             f"{FINE_TUNE_CONFIG.lr:g})")
    parser.add_argument("--weight-decay", type=float, default=TrainConfig.weight_decay, help="AdamW weight decay")
    parser.add_argument("--settings", metavar="FILE", default=None,
                        help="settings TOML whose estimating sensor's resolution limit the intervals are "
                             f"calibrated at (default: the shipped {help_literal(default_settings_path())}; not with --init, which "
                             "keeps the base model's)")
    parser.add_argument("--label-sd", dest="label_sd", type=float, default=TrainConfig.label_sd_decades,
                        metavar="DECADES",
                        help="standard deviation of the normal jitter added to log10 of each label at every step: "
                             "the published labels are material-class values, uncertain by about a factor of 2")
    parser.add_argument("--seed", type=non_negative_int, default=TrainConfig.seed, help="seed of weights, shuffles and flips")
    parser.add_argument("--threads", type=thread_count, default=TrainConfig.threads,
                        help=f"torch CPU threads, 1 to {MAX_THREADS} (default: {TrainConfig.threads})")
    parser.add_argument("--json", action="store_true",
                        help="print one JSON object (out, variant, epochs_run, best_epoch, metrics) on the last "
                             "stdout line")


def _variant(args: argparse.Namespace, manifest: dict[str, Any]) -> Variant:
    frames, size = manifest["n_frames"], tuple(manifest["size_px"])
    if args.frames is not None and args.frames != frames:
        raise EstimatorError(f"--frames {args.frames}: the dataset holds {frames} frames per sample")
    if args.size is not None and tuple(args.size) != size:
        raise EstimatorError(f"--size {args.size[0]}x{args.size[1]}: the dataset holds {size[0]}x{size[1]} images")
    return Variant.parse(args.variant or DEFAULT_VARIANT, n_frames=frames, size_px=size,
                         window_m=dataset_window(manifest, args.data))


def _fine_tune(args: argparse.Namespace) -> int:
    """``--init``: fine-tune the model there with ``estimator fine-tune``'s recipe and report."""
    unused = [flag for flag, value in (("--patience", args.patience), ("--settings", args.settings))
              if value is not None]
    if unused:
        raise EstimatorError(f"{', '.join(unused)}: not used with --init (fine-tuning runs every epoch and keeps "
                             "the base model's resolution limit)")
    if args.variant is not None:
        variant = CompliancePredictor(args.init).variant
        if Variant.parse(args.variant).name != variant.name:  # the parts, in any order
            raise EstimatorError(f"--variant {args.variant}: the model of --init {args.init} reads {variant.name}")
    _variant(args, load_manifest(args.data))  # --frames and --size must fit the dataset
    config = replace(FINE_TUNE_CONFIG, epochs=_given(args.epochs, FINE_TUNE_CONFIG.epochs),
                     batch_size=_given(args.batch_size, FINE_TUNE_CONFIG.batch_size),
                     lr=_given(args.lr, FINE_TUNE_CONFIG.lr), weight_decay=args.weight_decay,
                     label_sd_decades=args.label_sd, seed=args.seed, threads=args.threads)
    return fine_tune_and_report(args.init, args.data, args.out, config=config, replay=args.replay,
                                replay_ratio=_given(args.replay_ratio, REPLAY_RATIO), as_json=args.json,
                                model_option="--init", overwrite=args.overwrite)


def _given(value: Any, default: Any) -> Any:
    return default if value is None else value


def _share(value: float | None) -> str:
    return "-" if value is None else f"{value:.1%}"


def _fmt(metrics: dict[str, Any], method: str) -> str:
    m = metrics.get(method) or {}
    if m.get("log10_error") is None:
        return "-"
    felt = "" if m.get("felt_log10_error") is None else f", felt {m['felt_log10_error']:.2f} / {m['felt_within_2x']:.0%}"
    return f"{m['log10_error']:.2f} / {m['within_10x']:.0%}{felt} (n={m['n']})"


def run(args: argparse.Namespace) -> int:
    # Imported here: torch is the 'train' extra, which --help does not need.
    from estimator.training.train import train_model

    if args.init is not None:
        return _fine_tune(args)
    if args.replay is not None or args.replay_ratio is not None:
        raise EstimatorError("--replay and --replay-ratio rehearse a base model's data: they need --init MODEL_DIR")
    manifest = load_manifest(args.data)
    variant = _variant(args, manifest)
    config = TrainConfig(epochs=_given(args.epochs, TrainConfig.epochs),
                         batch_size=_given(args.batch_size, TrainConfig.batch_size), lr=_given(args.lr, TrainConfig.lr),
                         weight_decay=args.weight_decay, patience=_given(args.patience, TrainConfig.patience),
                         label_sd_decades=args.label_sd, seed=args.seed, threads=args.threads)
    meta = train_model(args.data, args.out, variant=variant, config=config, settings=load_settings(args.settings),
                       overwrite=args.overwrite)
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
