"""``estimator fine-tune``: adapt a trained model to a new rig from a few labelled grasps
(:mod:`estimator.training.finetune`, whose notes give the recipe)."""

from __future__ import annotations

import argparse
import json
import sys
from collections import Counter
from dataclasses import replace
from pathlib import Path
from typing import Any

from estimator.errors import EstimatorError, ModelError
from estimator.evaluation.compare import compare_models, unseen_records
from estimator.evaluation.compare_cli import print_comparison
from estimator.evaluation.evaluate_cli import print_skipped
from estimator.inference.provenance import load_split, trained_objects
from estimator.training.dataset import load_manifest
from estimator.training.outdir import OVERWRITE_HELP
from estimator.training.recipe import FINE_TUNE_CONFIG, REPLAY_RATIO, TrainConfig
from teleop.clikit import help_literal, non_negative_int
from teleop.settings import Settings, default_settings_path, load_settings


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.description = (
        "Fine-tune a trained model on a few labelled grasps of a new rig (a build-dataset directory made with "
        "the model's --window; every sample of every split trains). Batch-norm statistics and (without --replay) "
        "the interval calibration stay the base model's. Writes OUT/model.onnx and metadata.json, whose train objects "
        "include the fine-tuning objects, so `estimator evaluate --unseen-by OUT` keeps them out. With "
        "--compare RECORDS, the new model is then compared with the base on the labelled records of objects "
        "neither trained on (as `estimator compare`), and the verdict printed: base, candidate or undecided."
    )
    parser.add_argument("--model", required=True, metavar="MODEL_DIR",
                        help="the model to start from (a folder with metadata.json and model.onnx, e.g. "
                             "estimator/models/default)")
    parser.add_argument("--data", required=True, metavar="DIR", help="directory written by `estimator build-dataset`")
    parser.add_argument("--out", required=True, metavar="MODEL_DIR",
                        help="directory for the fine-tuned model (created; must not exist yet, or be empty, "
                             "unless --overwrite)")
    parser.add_argument("--overwrite", action="store_true", help=OVERWRITE_HELP)
    parser.add_argument("--replay", metavar="DIR",
                        help="the base model's training dataset (build-dataset directory, as `make model` writes): "
                             "rehearse it while fine-tuning, then recalibrate the intervals on its val objects")
    parser.add_argument("--replay-ratio", type=float, default=REPLAY_RATIO,
                        help="replayed samples per new sample in each epoch (with --replay)")
    parser.add_argument("--epochs", type=int, default=FINE_TUNE_CONFIG.epochs, help="epochs (no early stopping)")
    parser.add_argument("--lr", type=float, default=FINE_TUNE_CONFIG.lr, help="AdamW learning rate (cosine decay)")
    parser.add_argument("--batch-size", type=int, default=FINE_TUNE_CONFIG.batch_size, help="samples per step")
    parser.add_argument("--seed", type=non_negative_int, default=FINE_TUNE_CONFIG.seed, help="seed of shuffles, flips and jitter")
    parser.add_argument("--check", action="store_true",
                        help="first, leave one object out: fine-tune without each object in turn and score its "
                             "grasps as the display would render them, base model against fine-tuned, to see "
                             "whether fine-tuning helps on objects it did not see (one fine-tuning per object)")
    parser.add_argument("--compare", metavar="RECORDS", default=None,
                        help="afterwards, compare the new model with the base on the labelled .grasp records under "
                             "RECORDS whose object neither trained on (the base's train and val objects and the "
                             "fine-tuning objects are left out; checked before fine-tuning) and print the verdict, "
                             "as `estimator compare`: which is better by the felt error, with a 90 %% interval "
                             "from a bootstrap over the objects")
    parser.add_argument("--settings", metavar="FILE", default=None,
                        help="with --check or --compare: the new rig's settings TOML, whose resolution limit and "
                             f"display the grasps are scored at (default: the shipped {help_literal(default_settings_path())})")
    parser.add_argument("--json", action="store_true",
                        help="print one JSON object (out, objects, grasps, samples, seconds; check with --check, "
                             "compare with --compare) on the last stdout line")


def run(args: argparse.Namespace) -> int:
    config = replace(FINE_TUNE_CONFIG, epochs=args.epochs, lr=args.lr, batch_size=args.batch_size, seed=args.seed)
    return fine_tune_and_report(args.model, args.data, args.out, config=config, replay=args.replay,
                                replay_ratio=args.replay_ratio, overwrite=args.overwrite,
                                check_settings=load_settings(args.settings) if args.check else None,
                                compare=args.compare,
                                compare_settings=load_settings(args.settings) if args.compare else None,
                                as_json=args.json)


def _check_paths(model: str, data: str, replay: str | None, model_option: str) -> None:
    """A clear error naming the option for a model or replay directory that is not there (before any work)."""
    if not (Path(model) / "metadata.json").is_file():
        what = "no such directory" if not Path(model).is_dir() else "no metadata.json in it"
        raise ModelError(f"{model_option} {model}: {what}; expected a trained model's directory (metadata.json "
                         "and model.onnx), e.g. estimator/models/default")
    if replay is not None and not (Path(replay) / "dataset.json").is_file():
        what = "no such directory" if not Path(replay).is_dir() else "no dataset.json in it"
        raise EstimatorError(f"--replay {replay}: {what}; expected the base model's training dataset (a directory "
                             "written by `estimator build-dataset`)")
    load_manifest(data)


def _records_to_compare(model: str, data: str, records: str) -> frozenset[str]:
    """The objects a comparison after fine-tuning leaves out (the base's and the data's), checked to leave
    at least one labelled record under ``records``."""
    left_out = trained_objects(model) | {name for names in load_split(Path(data) / "split.json").values()
                                         for name in names}
    kept, skipped = unseen_records(records, frozenset(left_out))
    if not kept:
        causes = Counter(s["cause"].split(":")[0] for s in skipped)
        raise EstimatorError(f"--compare {records}: no labelled record of an object neither {model} nor the "
                             f"fine-tuning data trained on ({', '.join(f'{n} {c}' for c, n in causes.items())}); "
                             "give records of other objects, or leave --compare out")
    return frozenset(left_out)


def _felt(value: float | None, spec: str) -> str:
    return "- (every grasp shown unknown)" if value is None else format(value, spec)


def check_text(check: dict[str, Any]) -> str:
    """The line saying what :func:`~estimator.training.finetune.check_by_object` found; a felt figure over no
    grasp (every held-out grasp shown unknown) is shown as ``-`` and says so."""
    before, after = check["base"], check["fine_tuned"]
    unknown = (f"; shown unknown {before['shown_unknown']} -> {after['shown_unknown']}, left out of the felt figures"
               if before["shown_unknown"] or after["shown_unknown"] else "")
    return (f"leaving one object out, on {before['n']} grasps: felt error {_felt(before['felt_log10_error'], '.3f')} -> "
            f"{_felt(after['felt_log10_error'], '.3f')} decade, within a factor 2 {_felt(before['felt_within_2x'], '.0%')} "
            f"-> {_felt(after['felt_within_2x'], '.0%')}, dangerous misses {before['dangerous_misses']} -> "
            f"{after['dangerous_misses']} (base -> fine-tuned){unknown}")


def fine_tune_and_report(model: str, data: str, out: str, *, config: TrainConfig, replay: str | None,
                         replay_ratio: float, check_settings: Settings | None = None, compare: str | None = None,
                         compare_settings: Settings | None = None, as_json: bool = False,
                         model_option: str = "--model", overwrite: bool = False) -> int:
    """Fine-tune ``model`` on ``data`` into ``out`` and print what happened (``estimator fine-tune``, and
    ``estimator train --init``, whose option naming the model is ``model_option``); with ``check_settings``,
    first the leave-one-object-out check on that rig; with ``compare`` (a records directory), then the
    comparison with the base model on those records (:func:`estimator.evaluation.compare.compare_models`);
    ``overwrite`` lets ``out`` hold a model already."""
    # Imported here: torch is the 'train' extra, which --help does not need.
    from estimator.training.finetune import check_by_object, check_out, fine_tune

    _check_paths(model, data, replay, model_option)
    check_out(model, out, overwrite=overwrite)  # before --check's fine-tunings too
    if compare is not None:
        _records_to_compare(model, data, compare)
    if replay is None:
        print("note: without --replay the model may forget what it knew about other objects (on the held-out "
              "sensor of the model card it did); pass the base model's training dataset if you have it",
              file=sys.stderr)
    check = None
    if check_settings is not None:
        check = check_by_object(model, data, settings=check_settings, config=config, replay=replay,
                                replay_ratio=replay_ratio)
    meta = fine_tune(model, data, out, config=config, replay=replay, replay_ratio=replay_ratio, overwrite=overwrite)
    tuned = meta["fine_tuning"]
    summary = {"out": str(out), "objects": tuned["objects"], "grasps": tuned["grasps"],
               "samples": tuned["samples"], "seconds": tuned["seconds"],
               "final_train_loss": tuned["history"][-1]["train_loss"]}
    if check is not None:
        summary["check"] = check
    comparison = None
    if compare is not None:
        comparison = compare_models(model, out, compare, settings=compare_settings or load_settings(None))
        summary["compare"] = comparison
    if as_json:
        print(json.dumps(summary, allow_nan=False))
        return 0
    if check is not None:
        print(check_text(check))
    print(f"fine-tuned {model} on {tuned['grasps']} grasps ({tuned['samples']} samples) of "
          f"{len(tuned['objects'])} objects in {tuned['seconds']:.0f} s -> {out}; final train loss "
          f"{summary['final_train_loss']:.3f}.")
    if comparison is None:
        print(f"Compare it with {model} on labelled records of other objects before serving it: "
              f"estimator compare RECORDS --base {model} --candidate {out}")
        return 0
    print_skipped(comparison["skipped"], comparison["records"])
    print_comparison(comparison)
    return 0
