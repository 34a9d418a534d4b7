"""Adapt a trained model to a new rig from a few labelled grasps.

A lab with its own sensor grasps a few objects whose modulus it knows, builds a
dataset of them with ``estimator build-dataset`` (the model's ``--window``), and
fine-tunes the shipped model on it. The recipe was fixed before any held-out
figure was seen, for about 15 grasps of 5 objects:

* Start from the model's weights, rebuilt from its ONNX file
  (:func:`~estimator.learned.export.network_from_onnx`).
* Every sample of the dataset trains, whatever its split: a few objects are too
  few to hold some out, and the model's own test objects are what to score on.
* Batch-norm statistics stay frozen (a few grasps cannot estimate them; the
  rebuilt norms carry the folded ones); every weight trains.
* AdamW at ``lr`` (3e-4, a seventh of training's), cosine decay over ``epochs``
  (20) with no early stopping (:data:`FINE_TUNE_CONFIG`), the flips and label
  jitter of ``estimator train``.
* The calibration (temperature, rigid probability, interval scale) and the
  hybrid's policy stay the base model's: a few grasps cannot recalibrate them.

The fine-tuned model's metadata lists the fine-tuning objects among its train
objects (and no longer among its val or test objects), so ``estimator evaluate
--unseen-by`` scores it on objects it never saw; ``fine_tuning`` says from what
and how it was made.
"""

from __future__ import annotations

import json
import logging
import time
from dataclasses import asdict
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn
from tqdm import tqdm

from estimator.errors import EstimatorError
from estimator.learned.dataset import SPLITS, load_manifest, load_split
from estimator.learned.export import export_onnx, network_from_onnx
from estimator.learned.infer import ModelMetadata
from estimator.learned.model import ComplianceNet
from estimator.learned.train import (
    SplitData,
    TrainConfig,
    dataset_window,
    load_split_data,
    train_epoch,
)

__all__ = ["FINE_TUNE_CONFIG", "fine_tune"]

log = logging.getLogger(__name__)

FINE_TUNE_CONFIG = TrainConfig(epochs=20, batch_size=16, lr=3e-4)


def _joined(parts: list[SplitData]) -> SplitData:
    parts = [p for p in parts if len(p)]
    if not parts:
        return SplitData({}, np.zeros(0, np.float32), [])
    return SplitData({n: np.concatenate([p.inputs[n] for p in parts]) for n in parts[0].inputs},
                     np.concatenate([p.label for p in parts]), [r for p in parts for r in p.rows])


def _freeze_batch_norm(model: ComplianceNet) -> None:
    for module in model.modules():
        if isinstance(module, nn.BatchNorm2d):
            module.eval()


def _objects_after(base: dict[str, Any], added: set[str]) -> dict[str, list[str]]:
    """The base model's objects per split, with ``added`` moved to train."""
    objects = {name: [o for o in base.get(name, []) if o not in added] for name in SPLITS}
    objects["train"] = sorted({*objects["train"], *added})
    return objects


def fine_tune(model_dir: str | Path, data_dir: str | Path, out_dir: str | Path, *,
              config: TrainConfig = FINE_TUNE_CONFIG, progress: bool = True) -> dict[str, Any]:
    """Fine-tune the model in ``model_dir`` on every sample in ``data_dir``; write it to ``out_dir``.

    Returns the new model's metadata (module notes).

    Raises
    ------
    EstimatorError
        The dataset is empty, was measured by other code than the model's training data, or its
        window, frames or image size differ from the model's.
    ModelError
        The model cannot be read or rebuilt.
    """
    started = time.perf_counter()
    model_dir, data_dir, out_dir = Path(model_dir), Path(data_dir), Path(out_dir)
    meta_path = model_dir / "metadata.json"
    metadata = ModelMetadata.from_json(json.loads(meta_path.read_text()), str(meta_path))
    variant, base = metadata.variant, dict(metadata.raw)
    manifest = load_manifest(data_dir)
    version = (base.get("data") or {}).get("measurement_version")
    if manifest.get("measurement_version") != version:
        raise EstimatorError(f"{data_dir} was measured by measurement version {manifest.get('measurement_version')}, "
                             f"the model's training data by {version}: rebuild the dataset with this code")
    window = dataset_window(manifest, str(data_dir))
    if not np.allclose(window, variant.window_m, rtol=1e-9, atol=0.0):
        raise EstimatorError(f"{data_dir} holds images of a {window[0]:.6g} x {window[1]:.6g} m window, the model "
                             f"reads {variant.window_m[0]:.6g} x {variant.window_m[1]:.6g} m: build the dataset with "
                             f"--window {variant.window_m[0] * 1e3:.2f}x{variant.window_m[1] * 1e3:.2f}")
    if (manifest["n_frames"], tuple(manifest["size_px"])) != (variant.n_frames, variant.size_px):
        raise EstimatorError(f"{data_dir} holds {manifest['n_frames']} frames of {manifest['size_px']} px per sample, "
                             f"the model reads {variant.n_frames} of {list(variant.size_px)}")
    data = _joined(list(load_split_data(data_dir, variant).values()))
    if len(data) < 2:
        raise EstimatorError(f"{data_dir}: {len(data)} samples; fine-tuning needs at least 2")
    torch.use_deterministic_algorithms(True)
    torch.set_num_threads(config.threads)
    torch.manual_seed(config.seed)
    rng = np.random.default_rng(config.seed)
    model = network_from_onnx(model_dir / "model.onnx", variant,
                              check={n: v[:8] for n, v in data.inputs.items()})
    optimiser = torch.optim.AdamW(model.parameters(), lr=config.lr, weight_decay=config.weight_decay)
    scheduler = torch.optim.lr_scheduler.CosineAnnealingLR(optimiser, T_max=config.epochs)
    history = []
    for epoch in tqdm(range(1, config.epochs + 1), desc="fine-tune", unit="epoch", disable=not progress):
        model.train()
        _freeze_batch_norm(model)
        history.append({"epoch": epoch, "train_loss": train_epoch(model, data, optimiser, config, rng)})
        scheduler.step()
    model.eval()
    out_dir.mkdir(parents=True, exist_ok=True)
    export_onnx(model, out_dir / "model.onnx", example={n: v[:8] for n, v in data.inputs.items()})
    added = {r["object"] for r in data.rows}
    grasps = {(r["object"], Path(r["path"]).name.rsplit("_a", 1)[0]) for r in data.rows}
    new = {
        **base,
        "created_utc": datetime.now(UTC).isoformat(timespec="seconds"),
        "metrics": {},  # the base model's figures no longer describe this one: score it with `evaluate`
        "data": {**base["data"], "objects": _objects_after(base["data"].get("objects") or {}, added)},
        "fine_tuning": {
            "base": str(model_dir), "base_created_utc": base.get("created_utc"), "data": str(data_dir),
            "objects": sorted(added), "grasps": len(grasps), "samples": len(data),
            "split_of_data": {k: sorted(v) for k, v in load_split(data_dir / "split.json").items()},
            "config": asdict(config), "seconds": time.perf_counter() - started, "history": history,
        },
    }
    (out_dir / "metadata.json").write_text(json.dumps(new, indent=1, allow_nan=False))
    return new
