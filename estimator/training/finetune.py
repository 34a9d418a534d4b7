"""Adapt a trained model to a new rig from a few labelled grasps.

A lab with its own sensor grasps a few objects whose modulus it knows, builds a
dataset of them with ``estimator build-dataset`` (the model's ``--window``), and
fine-tunes the shipped model on it. The recipe was fixed before any held-out
figure was seen, for about 15 grasps of 5 objects:

* Start from the model's weights, rebuilt from its ONNX file
  (:func:`~estimator.training.export.network_from_onnx`; a pooled model's members
  train together through the pool, :func:`~estimator.training.pool.pooled_from_onnx`).
* Every sample of the dataset trains, whatever its split: a few objects are too
  few to hold some out, and the model's own test objects are what to score on.
* Batch-norm statistics stay frozen (a few grasps cannot estimate them; the
  rebuilt norms carry the folded ones); every weight trains.
* AdamW at ``lr`` (3e-4, a seventh of training's), cosine decay over ``epochs``
  (20) with no early stopping (:data:`~estimator.training.recipe.FINE_TUNE_CONFIG`),
  the flips and label jitter of ``estimator train``, and its stop when the loss or the weights
  diverge (:func:`~estimator.training.train.check_converging`).
* Without ``replay``, the calibration (temperature, rigid probability, interval
  scale) and the hybrid's policy stay the base model's: a few grasps cannot
  recalibrate them.
* With ``replay`` (a ``build-dataset`` directory of the base model's own
  training data, such as ``make model`` writes), rehearsal keeps what the model
  knew: every epoch trains on the new samples plus ``replay_ratio`` times as
  many drawn afresh from the replay dataset's train split
  (:data:`~estimator.training.recipe.REPLAY_RATIO`, 1; how it was chosen:
  ``docs/decisions/0006-fine-tuning-recipe.md``), and the intervals
  are then recalibrated (:func:`~estimator.training.conformal.fit_conformal`) on its
  validation objects that fine-tuning did not train on. Its train objects must
  be the base model's train objects, so that nothing the base model held out
  is trained on, and its val and test objects ones the base model never trained
  on, but for those an earlier fine-tuning did, which are left out as ``estimator
  recalibrate`` leaves them out (:func:`~estimator.training.recalibrate.trained_held_out`,
  checked before any training).

Whether fine-tuning pays off on a rig can be told from its own grasps before any test
(:func:`check_by_object`, ``estimator fine-tune --check``): each object is left out in turn, the
model fine-tuned on the rest, and that object's grasps scored as the rig's display renders them,
base model against fine-tuned.

The fine-tuned model's metadata lists the fine-tuning objects among its train
objects (and no longer among its val or test objects) and in ``fine_tuning.objects``,
so ``estimator evaluate --unseen-by`` scores it on objects it never saw
(:func:`~estimator.inference.provenance.trained_objects`); ``fine_tuning`` says from what
(absolute paths of the base model, the data and the replay dataset) and how it was made (``config``,
whose ``patience`` is null: no early stopping), and ``fine_tuning.earlier`` keeps the steps that
made the base model, earliest first, so a model fine-tuned twice still names every object any step
trained on (:func:`~estimator.training.recalibrate.fine_tuned_objects`). With ``replay`` the base
model's ``recalibrated`` record is dropped: its calibration is no longer the one in use. Whether
it is better than the base model on a lab's own labelled records of other objects is
:func:`estimator.evaluation.compare.compare_models` (``estimator fine-tune --compare RECORDS``, or
``estimator compare`` afterwards).
"""

from __future__ import annotations

import json
import logging
import math
import time
from dataclasses import asdict
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

from estimator.errors import EstimatorError
from estimator.inference.infer import CompliancePredictor, ModelMetadata, read_metadata
from estimator.inference.inputs import Variant
from estimator.inference.provenance import SPLITS, load_split
from estimator.training.conformal import fit_conformal
from estimator.training.export import export_onnx, network_from_onnx
from estimator.training.model import ComplianceNet
from estimator.training.outdir import check_out_dir, model_write_error
from estimator.training.pool import pooled_from_onnx
from estimator.training.recalibrate import trained_held_out
from estimator.training.recipe import FINE_TUNE_CONFIG, REPLAY_RATIO, TrainConfig
from estimator.training.splits import SplitData, check_dataset_fits, load_split_data, split_metrics
from estimator.training.train import check_converging, predict, torch_seed, train_epoch
from teleop.progress import progress_bar
from teleop.settings import Settings
from teleop.staging import staged

__all__ = ["check_by_object", "check_out", "fine_tune"]

log = logging.getLogger(__name__)


def _joined(parts: list[SplitData]) -> SplitData:
    parts = [p for p in parts if len(p)]
    if not parts:
        return SplitData({}, np.zeros(0, np.float32), [])
    return SplitData({n: np.concatenate([p.inputs[n] for p in parts]) for n in parts[0].inputs},
                     np.concatenate([p.label for p in parts]), [r for p in parts for r in p.rows])


def _replay_data(replay_dir: Path, variant: Variant, base: dict[str, Any], added: set[str]
                 ) -> tuple[SplitData, SplitData]:
    """The replay dataset's train split and the live samples of its val objects to recalibrate on: those
    neither in ``added`` nor trained on by an earlier fine-tuning
    (:func:`~estimator.training.recalibrate.trained_held_out`, which refuses val or test objects the base
    model trained on otherwise)."""
    check_dataset_fits(replay_dir, variant, base.get("data") or {})
    trained_on = set(((base.get("data") or {}).get("objects") or {}).get("train") or [])
    split = load_split(replay_dir / "split.json")
    foreign = sorted(set(split["train"]) - trained_on)
    if foreign:
        raise EstimatorError(f"{replay_dir}: train objects the base model did not train on ({', '.join(foreign[:5])}"
                             f"{', ...' if len(foreign) > 5 else ''}): replay the base model's own training data")
    left_out = {*trained_held_out(base, replay_dir), *added}
    parts = load_split_data(replay_dir, variant, ("train", "val"))
    val = parts["val"].live()
    val = val.subset(np.array([r["object"] not in left_out for r in val.rows], dtype=bool))
    if not len(parts["train"]) or not len(val):
        raise EstimatorError(f"{replay_dir}: {len(parts['train'])} train and {len(val)} val samples to replay and "
                             "recalibrate on; both are needed")
    return parts["train"], val


def _freeze_batch_norm(model: ComplianceNet) -> None:
    for module in model.modules():
        if isinstance(module, nn.BatchNorm2d):
            module.eval()


def _objects_after(base: dict[str, Any], added: set[str]) -> dict[str, list[str]]:
    """The base model's objects per split, with ``added`` moved to train."""
    objects = {name: [o for o in base.get(name, []) if o not in added] for name in SPLITS}
    objects["train"] = sorted({*objects["train"], *added})
    return objects


def _lineage(base: dict[str, Any]) -> list[dict[str, Any]]:
    """The fine-tuning steps that made the base model, earliest first: what ``fine_tuning.earlier`` keeps."""
    tuning = base.get("fine_tuning")
    if not tuning:
        return []
    return [*(tuning.get("earlier") or []), {k: v for k, v in tuning.items() if k != "earlier"}]


def _tuned(model_dir: Path, base: dict[str, Any], variant: Variant, data: SplitData, replayed: SplitData | None, *,
           config: TrainConfig, replay_ratio: float, progress: bool, desc: str = "fine-tune"
           ) -> tuple[ComplianceNet, list[dict[str, Any]]]:
    """The base model rebuilt from its ONNX file and fine-tuned on ``data`` (module notes), and its history."""
    torch.use_deterministic_algorithms(True)
    torch.set_num_threads(config.threads)
    torch.manual_seed(torch_seed(config.seed))
    rng = np.random.default_rng(config.seed)
    check = {n: v[:8] for n, v in data.inputs.items()}
    if base.get("ensemble"):  # a pooled model (`estimator pool`) is fine-tuned as one network
        temperatures = [m["temperature"] for m in base["ensemble"]["members"]]
        model = pooled_from_onnx(model_dir / "model.onnx", variant, temperatures, check=check)
    else:
        model = network_from_onnx(model_dir / "model.onnx", variant, check=check)
    optimiser = torch.optim.AdamW(model.parameters(), lr=config.lr, weight_decay=config.weight_decay)
    scheduler = torch.optim.lr_scheduler.CosineAnnealingLR(optimiser, T_max=config.epochs)
    history = []
    for epoch in progress_bar(range(1, config.epochs + 1), desc=desc, unit="epoch", enabled=progress):
        model.train()
        _freeze_batch_norm(model)
        epoch_data = data
        if replayed is not None:
            drawn = rng.choice(len(replayed), size=min(len(replayed), round(replay_ratio * len(data))), replace=False)
            epoch_data = _joined([data, replayed.subset(np.sort(drawn))])
        history.append({"epoch": epoch, "train_loss": train_epoch(model, epoch_data, optimiser, config, rng)})
        check_converging(model, {"training loss": history[-1]["train_loss"]}, epoch, config.lr, "fine-tuning")
        scheduler.step()
    model.eval()
    return model, history


def _calibration(model: ComplianceNet, base: dict[str, Any], variant: Variant, recalibrate_on: SplitData | None,
                 replay: str | Path | None) -> dict[str, Any]:
    """The base model's calibration, or with ``replay`` one refitted on its validation samples."""
    calibration = base["calibration"]
    if recalibrate_on is None:
        return calibration
    return {**fit_conformal(predict(model, recalibrate_on), recalibrate_on.label, gel_scales=recalibrate_on.gel_scales,
                            peak_forces_n=recalibrate_on.peak_forces_n,
                            floors_log10=recalibrate_on.floors_for(variant),
                            soft_pa=calibration["soft_pa"],
                            limit_pa=calibration["limit_pa"], level=calibration["level"]),
            "chosen_on": f"val of {Path(replay).resolve()}"}


def _prepared(model_dir: Path, data_dir: Path, replay: str | Path | None, replay_ratio: float
              ) -> tuple[dict[str, Any], Variant, SplitData, SplitData | None, SplitData | None]:
    """The base metadata, its variant, every sample of ``data_dir``, and the replay's train and val samples."""
    meta_path, raw = read_metadata(model_dir)
    metadata = ModelMetadata.from_json(raw, str(meta_path))
    variant, base = metadata.variant, dict(metadata.raw)
    check_dataset_fits(data_dir, variant, base.get("data") or {})
    if not (math.isfinite(replay_ratio) and replay_ratio > 0):
        raise EstimatorError(f"replay_ratio {replay_ratio!r}: expected a finite value > 0")
    data = _joined(list(load_split_data(data_dir, variant).values()))
    if len(data) < 2:
        raise EstimatorError(f"{data_dir}: {len(data)} samples; fine-tuning needs at least 2")
    added = {r["object"] for r in data.rows}
    replayed, recalibrate_on = (None, None) if replay is None else _replay_data(Path(replay), variant, base, added)
    return base, variant, data, replayed, recalibrate_on


def check_out(model_dir: str | Path, out_dir: str | Path, *, overwrite: bool) -> None:
    """Refuse an ``out_dir`` that is the base model, even with ``overwrite``, or that
    :func:`~estimator.training.outdir.check_out_dir` refuses (EstimatorError)."""
    model_dir, out_dir = Path(model_dir), Path(out_dir)
    if out_dir.resolve() == model_dir.resolve():
        raise EstimatorError(f"--out {out_dir}: is the base model; write the fine-tuned one to another folder "
                             "and compare the two (`estimator compare`)")
    check_out_dir(out_dir, overwrite=overwrite)


def fine_tune(model_dir: str | Path, data_dir: str | Path, out_dir: str | Path, *,
              config: TrainConfig = FINE_TUNE_CONFIG, replay: str | Path | None = None,
              replay_ratio: float = REPLAY_RATIO, progress: bool = True, overwrite: bool = False
              ) -> dict[str, Any]:
    """Fine-tune the model in ``model_dir`` on every sample in ``data_dir``; write it to ``out_dir``, which
    must be new or empty unless ``overwrite`` (:func:`~estimator.training.outdir.check_out_dir`).

    ``replay`` names the base model's training dataset to rehearse and recalibrate on, ``replay_ratio``
    (> 0) how many of its samples each epoch adds per new sample (module notes).

    Returns the new model's metadata (module notes).

    Raises
    ------
    EstimatorError
        ``out_dir`` is the base model, a file or, without ``overwrite``, not empty; the dataset is
        empty, was measured by other code than the model's training data, or its window, frames or
        image size differ from the model's; the replay dataset likewise, or it trains on objects the
        base model did not, or its val or test objects include ones the base model trained on (but
        for an earlier fine-tuning's), or it leaves no val samples to recalibrate on; fine-tuning
        diverges (before ``out_dir`` is made).
    ModelError
        The model cannot be read or rebuilt.
    """
    started = time.perf_counter()
    model_dir, data_dir, out_dir = Path(model_dir), Path(data_dir), Path(out_dir)
    check_out(model_dir, out_dir, overwrite=overwrite)
    base, variant, data, replayed, recalibrate_on = _prepared(model_dir, data_dir, replay, replay_ratio)
    added = {r["object"] for r in data.rows}
    model, history = _tuned(model_dir, base, variant, data, replayed, config=config, replay_ratio=replay_ratio,
                            progress=progress)
    calibration = _calibration(model, base, variant, recalibrate_on, replay)
    grasps = {(r["object"], Path(r["path"]).name.rsplit("_a", 1)[0]) for r in data.rows}
    new = {
        **base,
        "created_utc": datetime.now(UTC).isoformat(timespec="seconds"),
        "calibration": calibration,
        "metrics": {},  # the base model's figures no longer describe this one: score it with `evaluate`
        "data": {**base["data"], "objects": _objects_after(base["data"].get("objects") or {}, added)},
        "fine_tuning": {
            "base": str(model_dir.resolve()), "base_created_utc": base.get("created_utc"),
            "data": str(data_dir.resolve()), "objects": sorted(added), "grasps": len(grasps), "samples": len(data),
            "split_of_data": {k: sorted(v) for k, v in load_split(data_dir / "split.json").items()},
            "replay": None if replay is None else {"data": str(Path(replay).resolve()), "ratio": replay_ratio},
            "config": {**asdict(config), "patience": None},  # no early stopping: every epoch runs
            "seconds": time.perf_counter() - started, "history": history, "earlier": _lineage(base),
        },
    }
    if replay is not None:  # the base's record of how its calibration was fitted: this one was fitted here
        new.pop("recalibrated", None)
    # Both files under staged names first, renamed back to back only once both are complete: an
    # interrupted run leaves the earlier model, and its training curve, as they were. The curve
    # (of the earlier network) goes only after the new model is in place.
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
        with staged(out_dir / "model.onnx", out_dir / "metadata.json") as (model_path, metadata_path):
            export_onnx(model, model_path, example={n: v[:8] for n, v in data.inputs.items()})
            metadata_path.write_text(json.dumps(new, indent=1, allow_nan=False))
    except OSError as exc:  # a full or read-only disk
        raise model_write_error(out_dir, exc) from exc
    (out_dir / "training_curve.png").unlink(missing_ok=True)
    return new


def _felt(data: SplitData, logits: np.ndarray, calibration: dict[str, Any], settings: Settings) -> dict[str, Any]:
    """The display's figures of the model's answers on ``data``, described at ``settings``' limit as at run time."""
    at_limit = {**calibration, "limit_pa": settings.resolution_limit_pa}
    figures = split_metrics(data, logits, "model", at_limit, settings)["model"]
    return {k: figures[k] for k in ("n", "shown_unknown", "felt_log10_error", "felt_within_2x", "dangerous_misses")}


def check_by_object(model_dir: str | Path, data_dir: str | Path, *, settings: Settings,
                    config: TrainConfig = FINE_TUNE_CONFIG, replay: str | Path | None = None,
                    replay_ratio: float = REPLAY_RATIO, progress: bool = True) -> dict[str, Any]:
    """Whether fine-tuning on ``data_dir`` helps on objects it did not see, from those grasps alone.

    Leave one object out: for each object of ``data_dir``, fine-tune as :func:`fine_tune` would on
    the others and answer that object's grasps (their live samples) with it and with the base model,
    at the resolution limit and on the display of ``settings`` (the new rig's). Nothing is written.

    Returns ``base`` and ``fine_tuned`` (``n``, ``shown_unknown``, ``felt_log10_error``, ``felt_within_2x``,
    ``dangerous_misses`` over every held-out grasp; the felt figures over those not shown unknown, None
    when every one is) and ``per_object`` (object -> the two felt errors, None likewise).

    Raises
    ------
    EstimatorError
        As :func:`fine_tune`, or ``data_dir`` holds fewer than 2 objects.
    """
    model_dir, data_dir = Path(model_dir), Path(data_dir)
    base, variant, data, replayed, recalibrate_on = _prepared(model_dir, data_dir, replay, replay_ratio)
    objects = sorted({r["object"] for r in data.rows})
    if len(objects) < 2:
        raise EstimatorError(f"{data_dir}: {len(objects)} object; leaving one out needs at least 2")
    base_predictor = CompliancePredictor(model_dir)
    figures: dict[str, list[dict[str, Any]]] = {"base": [], "fine_tuned": []}
    for n, name in enumerate(objects, start=1):
        own = np.array([r["object"] == name for r in data.rows], dtype=bool)
        model, _ = _tuned(model_dir, base, variant, data.subset(~own), replayed, config=config,
                          replay_ratio=replay_ratio, progress=progress, desc=f"without {name} ({n}/{len(objects)})")
        held = data.subset(own).live()
        figures["base"].append(_felt(held, base_predictor.predict_logits(held.inputs), base["calibration"], settings))
        figures["fine_tuned"].append(_felt(held, predict(model, held), _calibration(model, base, variant, recalibrate_on, replay),
                                           settings))
    return {
        **{which: _pooled(folds) for which, folds in figures.items()},
        "per_object": {name: {which: figures[which][i]["felt_log10_error"] for which in figures}
                       for i, name in enumerate(objects)},
    }


def _pooled(folds: list[dict[str, Any]]) -> dict[str, Any]:
    """Figures over the grasps of every fold, from each fold's: the felt ones over the grasps not shown
    unknown (each fold's weighted by its count of those), None when no fold has one."""
    felt = [(f, f["n"] - f["shown_unknown"]) for f in folds if f["felt_log10_error"] is not None]
    n_felt = sum(count for _, count in felt)
    return {"n": sum(f["n"] for f in folds), "shown_unknown": sum(f["shown_unknown"] for f in folds),
            "dangerous_misses": sum(f["dangerous_misses"] for f in folds),
            **{k: sum(f[k] * count for f, count in felt) / n_felt if n_felt else None
               for k in ("felt_log10_error", "felt_within_2x")}}
