"""``estimator train``: fit the network on a dataset's train objects, stop on its val objects.

Recipe
------
* Seeded and repeatable: ``torch.manual_seed``, deterministic algorithms, a
  seeded numpy generator for shuffles and flips, ``--threads`` torch threads.
  One thread by default: on a 2-core machine shared with anything else, two
  OpenMP threads spin against each other and an epoch took 9-10 s instead of
  1.7 s (measured on the project machine, 567 samples at 64 x 88 px).
* Augmentation that keeps the physics: random horizontal and vertical flips of
  every frame of a sample (a mirrored contact is an equally valid contact); the
  time shifts of the sampled frames are the dataset's sample sets (``--shifts``
  of ``build-dataset``).
* Loss: Huber (smooth L1) on the normalised label with its knee at 0.25
  decade, by default. The score that matters is the mean |log10 error|; Huber
  is quadratic (smooth, MSE-like) for errors under the knee and linear beyond,
  so the few grasps whose frames cannot tell a stiff plastic from a metal
  (several decades apart, the paper's stated limit) do not dominate the
  gradient as they do under MSE. ``--loss mse`` gives the paper's choice.
* AdamW, early stopping on the mean |log10 error| of the validation objects
  (patience ``--patience`` epochs); the best epoch is kept.
* Trained on every sample set; validated, calibrated (interval, ``auto``) and
  scored on the live sampling only (augmentation 0, one sample per grasp), as
  the estimator meets grasps: the shifted sets exist only for grasps with long
  loading phases (soft objects, the easy ones) and would flatter the figures.

Writes ``MODEL_DIR/model.onnx`` (checked against torch to 1e-4 in
onnxruntime), ``metadata.json`` (:mod:`estimator.learned.infer`: variant,
inputs, scales, validation residual quantiles for the run-time interval,
metrics on val and test objects next to the analytical methods' on the same
grasps, the data and the recipe) and ``training_curve.png``.
"""

from __future__ import annotations

import argparse
import copy
import json
import logging
import math
import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn
from tqdm import tqdm

from estimator.errors import EstimatorError, SampleError
from estimator.evaluate import summarise
from estimator.learned.dataset import SPLITS, load_manifest, load_split, parse_size
from estimator.learned.export import OPSET, export_onnx
from estimator.learned.hybrid import MIN_SPLIT_FRAMES, interval_decades
from estimator.learned.infer import MODEL_FORMAT, MODEL_VERSION, current_scales
from estimator.learned.inputs import (
    ANALYTICAL_METHODS,
    Variant,
    distinct_frames,
    encode,
    measurement_fingerprint,
    modulus_from_normalised,
    normalise_modulus,
)
from estimator.learned.model import ComplianceNet
from estimator.samples import TrainingSample, load_sample, sample_paths

__all__ = ["SplitData", "TrainConfig", "load_split_data", "train_model"]

log = logging.getLogger(__name__)

HUBER_KNEE_DECADES = 0.25
AUTO_THRESHOLDS_DECADES = (0.1, 0.25, 0.5, 0.75, 1.0, 1.5, 2.0, 3.0)
LOG10_SPAN = 9.0  # decades of the normalised scale


@dataclass(frozen=True)
class TrainConfig:
    """The training recipe (module notes); stored in the model's metadata."""

    epochs: int = 60
    batch_size: int = 32
    lr: float = 2e-3
    weight_decay: float = 1e-4
    patience: int = 10
    loss: str = "huber"
    seed: int = 0
    threads: int = 1

    def __post_init__(self) -> None:
        if self.loss not in ("huber", "mse"):
            raise EstimatorError(f"loss {self.loss!r}: expected huber or mse")
        if min(self.epochs, self.batch_size, self.patience, self.threads) < 1:
            raise EstimatorError("epochs, batch_size, patience and threads must each be >= 1")
        if not (self.lr > 0 and self.weight_decay >= 0):
            raise EstimatorError(f"lr {self.lr} must be > 0 and weight_decay {self.weight_decay} >= 0")


@dataclass(frozen=True)
class SplitData:
    """The encoded samples of one split."""

    inputs: dict[str, np.ndarray]
    label: np.ndarray  # normalised, (n,)
    rows: list[dict[str, Any]]  # per sample: object, material, shape, truth_pa, estimates

    def __len__(self) -> int:
        return int(self.label.shape[0])

    def live(self) -> SplitData:
        """The samples of the live sampling (augmentation 0): one per grasp, as the estimator sees it."""
        keep = np.array([r["augmentation"] == 0 for r in self.rows], dtype=bool)
        return SplitData({k: v[keep] for k, v in self.inputs.items()}, self.label[keep],
                         [r for r, k in zip(self.rows, keep, strict=True) if k])


def _row(sample: TrainingSample, path: Path) -> dict[str, Any]:
    if sample.label_modulus_pa is None:
        raise SampleError(f"{path}: sample has no label_modulus_pa")
    return {"object": sample.object_name, "augmentation": sample.augmentation,
            "material": sample.material or "unknown",
            "shape": sample.shape or "unknown", "truth_pa": sample.label_modulus_pa,
            "estimates": sample.estimates, "frames": distinct_frames(sample.force_n), "path": str(path)}


def load_split_data(data_dir: str | Path, variant: Variant) -> dict[str, SplitData]:
    """Encode every sample of a ``build-dataset`` directory, per split.

    Raises
    ------
    SampleError
        A sample lies in a split its object is not assigned to (a leak), has no
        label, or does not fit the variant.
    """
    data_dir = Path(data_dir)
    split = load_split(data_dir / "split.json")
    out = {}
    for name in SPLITS:
        allowed = set(split[name])
        directory = data_dir / name
        paths = sample_paths(directory) if directory.is_dir() else []
        samples, rows = [], []
        for path in paths:
            sample = load_sample(path)
            if sample.object_name not in allowed:
                raise SampleError(f"{path}: object {sample.object_name!r} is not in the {name} split of "
                                  f"{data_dir / 'split.json'} (objects must not cross splits)")
            samples.append(sample)
            rows.append(_row(sample, path))
        if samples:
            batch = encode(variant, samples, where=str(directory))
            label = normalise_modulus([r["truth_pa"] for r in rows]).astype(np.float32)
        else:
            batch = {k: np.zeros((0, *s), np.float32) for k, s in variant.input_shapes.items()}
            label = np.zeros(0, np.float32)
        out[name] = SplitData(batch, label, rows)
    return out


def _loss(kind: str) -> nn.Module:
    if kind == "mse":
        return nn.MSELoss()
    return nn.HuberLoss(delta=HUBER_KNEE_DECADES / LOG10_SPAN)


def _flip(frames: torch.Tensor, generator: np.random.Generator) -> torch.Tensor:
    """Flip each sample's frames left-right and/or up-down at random (all its frames alike)."""
    flips = torch.from_numpy(generator.random((frames.shape[0], 2)) < 0.5)
    frames = torch.where(flips[:, 0, None, None, None, None], frames.flip(-1), frames)
    return torch.where(flips[:, 1, None, None, None, None], frames.flip(-2), frames)


def _predict(model: ComplianceNet, data: SplitData, batch_size: int = 256) -> np.ndarray:
    model.eval()
    names = list(model.variant.input_shapes)
    out = []
    with torch.no_grad():
        for start in range(0, len(data), batch_size):
            args = [torch.from_numpy(data.inputs[n][start:start + batch_size]) for n in names]
            out.append(model(*args).numpy().reshape(-1))
    return np.concatenate(out) if out else np.zeros(0, np.float32)


def _mean_log10_error(pred: np.ndarray, label: np.ndarray) -> float:
    return float(np.mean(np.abs(pred - label)) * LOG10_SPAN)


def _rows(data: SplitData, pred_norm: np.ndarray, method: str, residual: dict[str, float]
          ) -> list[dict[str, Any]]:
    """evaluate-style rows: the model's estimate (interval from the validation residuals) and each
    analytical estimate, per sample."""
    rows = []
    for row, e_pa in zip(data.rows, modulus_from_normalised(pred_norm), strict=True):
        base = {k: row[k] for k in ("object", "material", "shape", "truth_pa")}
        low, high = min(e_pa * 10.0 ** -residual["q975"], e_pa), max(e_pa * 10.0 ** -residual["q025"], e_pa)
        rows.append({**base, "method": method, "state": "ok", "e_pa": float(e_pa), "low_pa": low, "high_pa": high})
        for est in row["estimates"]:
            low, high = est.interval_pa
            rows.append({**base, "method": est.method, "state": est.state, "e_pa": est.e_pa,
                         "low_pa": low, "high_pa": high})
    return rows


def _metrics(data: SplitData, pred_norm: np.ndarray, method: str, residual: dict[str, float]) -> dict[str, Any]:
    if not len(data):
        return {}
    summary = summarise(_rows(data, pred_norm, method, residual), [method, *ANALYTICAL_METHODS])
    for value in summary.values():
        value.pop("paper", None)
    summary["objects"] = len({r["object"] for r in data.rows})
    return summary


def _auto_policy(data: SplitData, pred_norm: np.ndarray) -> dict[str, Any]:
    """``auto``'s split threshold: the widest interval at which the split, on the validation grasps
    it would answer (``ok`` over at least ``MIN_SPLIT_FRAMES`` frames), errs no more on average than
    the model on those grasps (0: never)."""
    truth = np.log10([r["truth_pa"] for r in data.rows])
    model_error = np.abs(np.log10(modulus_from_normalised(pred_norm)) - truth)
    split = [next((e for e in r["estimates"] if e.method == "split"), None) for r in data.rows]
    ok = np.array([e is not None and e.state == "ok" and r["frames"] >= MIN_SPLIT_FRAMES
                   for e, r in zip(split, data.rows, strict=True)])
    width = np.array([interval_decades(e) if o else np.inf for e, o in zip(split, ok, strict=True)])
    split_error = np.array([abs(math.log10(e.e_pa) - t) if o else np.inf for e, o, t in zip(split, ok, truth,
                                                                                           strict=True)])
    table, chosen = [], 0.0
    for threshold in AUTO_THRESHOLDS_DECADES:
        taken = width <= threshold
        n = int(taken.sum())
        entry = {"max_interval_decades": threshold, "n": n, "share": n / len(data.rows),
                 "split_log10_error": float(split_error[taken].mean()) if n else None,
                 "model_log10_error": float(model_error[taken].mean()) if n else None}
        table.append(entry)
        if n and entry["split_log10_error"] <= entry["model_log10_error"]:
            chosen = threshold
    return {"max_split_interval_decades": chosen, "chosen_on": "val", "table": table}


def _plot(history: list[dict[str, float]], best_epoch: int, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    epochs = [h["epoch"] for h in history]
    fig, (ax_loss, ax_err) = plt.subplots(1, 2, figsize=(10, 4))
    ax_loss.plot(epochs, [h["train_loss"] for h in history], label="train")
    ax_loss.plot(epochs, [h["val_loss"] for h in history], label="val")
    ax_loss.set(xlabel="epoch", ylabel="loss (normalised log10 E)", yscale="log", title="loss")
    ax_err.plot(epochs, [h["train_log10_error"] for h in history], label="train")
    ax_err.plot(epochs, [h["val_log10_error"] for h in history], label="val")
    for ax in (ax_loss, ax_err):
        ax.axvline(best_epoch, color="0.5", ls="--", lw=1, label="kept")
        ax.legend()
    ax_err.set(xlabel="epoch", ylabel="mean |log10 E_hat - log10 E|", title="error (decades)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def train_model(
    data_dir: str | Path,
    out_dir: str | Path,
    *,
    variant: Variant,
    config: TrainConfig = TrainConfig(),
    progress: bool = True,
) -> dict[str, Any]:
    """Train ``variant`` on the dataset in ``data_dir``; write the model to ``out_dir``; return its metadata.

    Raises
    ------
    EstimatorError
        The dataset has no train or no val samples, or does not match the variant.
    """
    started = time.perf_counter()
    data_dir, out_dir = Path(data_dir), Path(out_dir)
    manifest = load_manifest(data_dir)
    if manifest.get("measurement_fingerprint") != measurement_fingerprint():
        log.warning("%s was built by other measurement code (fingerprint %s, now %s): the model will learn "
                    "inputs the estimator no longer produces; rebuild the dataset", data_dir,
                    manifest.get("measurement_fingerprint"), measurement_fingerprint())
    if variant.markers and not manifest.get("markers"):
        raise EstimatorError(f"variant {variant.name} reads markers; {data_dir} was built without --markers")
    data = load_split_data(data_dir, variant)
    train, val = data["train"], data["val"].live()
    if not len(train) or not len(val):
        raise EstimatorError(f"{data_dir}: {len(train)} train and {len(val)} val samples; both splits need "
                             "samples (more objects, or other --split fractions)")
    torch.manual_seed(config.seed)
    torch.use_deterministic_algorithms(True)
    torch.set_num_threads(config.threads)
    rng = np.random.default_rng(config.seed)
    model = ComplianceNet(variant)
    optimiser = torch.optim.AdamW(model.parameters(), lr=config.lr, weight_decay=config.weight_decay)
    scheduler = torch.optim.lr_scheduler.CosineAnnealingLR(optimiser, T_max=config.epochs)
    loss_fn = _loss(config.loss)
    names = list(variant.input_shapes)
    tensors = {n: torch.from_numpy(train.inputs[n]) for n in names}
    label = torch.from_numpy(train.label)
    history: list[dict[str, float]] = []
    best = (math.inf, 0, copy.deepcopy(model.state_dict()))
    bar = tqdm(range(1, config.epochs + 1), desc="train", unit="epoch", disable=not progress)
    for epoch in bar:
        model.train()
        order = torch.from_numpy(rng.permutation(len(train)))
        total = 0.0
        for start in range(0, len(train), config.batch_size):
            index = order[start:start + config.batch_size]
            if index.numel() < 2:  # batch norm needs two samples
                continue
            args = [tensors[n][index] for n in names]
            args[0] = _flip(args[0], rng)
            optimiser.zero_grad()
            loss = loss_fn(model(*args).reshape(-1), label[index])
            loss.backward()
            optimiser.step()
            total += float(loss.detach()) * index.numel()
        scheduler.step()
        train_pred, val_pred = _predict(model, train), _predict(model, val)
        with torch.no_grad():
            val_loss = float(loss_fn(torch.from_numpy(val_pred), torch.from_numpy(val.label)))
        entry = {"epoch": epoch, "train_loss": total / len(train), "val_loss": val_loss,
                 "train_log10_error": _mean_log10_error(train_pred, train.label),
                 "val_log10_error": _mean_log10_error(val_pred, val.label)}
        history.append(entry)
        bar.set_postfix(val_err=f"{entry['val_log10_error']:.3f}", best=best[1])
        if entry["val_log10_error"] < best[0]:
            best = (entry["val_log10_error"], epoch, copy.deepcopy(model.state_dict()))
        elif epoch - best[1] >= config.patience:
            break
    model.load_state_dict(best[2])
    model.eval()
    out_dir.mkdir(parents=True, exist_ok=True)
    example = {n: val.inputs[n][:8] if len(val) >= 2 else train.inputs[n][:8] for n in names}
    export_onnx(model, out_dir / "model.onnx", example=example)
    val_pred = _predict(model, val)
    errors = (val_pred - val.label) * LOG10_SPAN
    residual = {"q025": float(np.quantile(errors, 0.025)), "q975": float(np.quantile(errors, 0.975)),
                "median_abs": float(np.median(np.abs(errors))), "n": int(errors.size)}
    metadata = {
        "format": MODEL_FORMAT,
        "version": MODEL_VERSION,
        "created_utc": datetime.now(UTC).isoformat(timespec="seconds"),
        "variant": {"name": variant.name, "n_frames": variant.n_frames, "size_px": list(variant.size_px),
                    "method": variant.method},
        "inputs": {n: [None, *s] for n, s in variant.input_shapes.items()},
        "output": "e_norm",
        "scales": current_scales(),
        "residual_log10": residual,
        "auto": _auto_policy(val, val_pred),
        "metrics": {name: _metrics(part, _predict(model, part), variant.method, residual)
                    for name, part in (("val", val), ("test", data["test"].live()))},
        "training": {**asdict(config), "epochs_run": len(history), "best_epoch": best[1],
                     "best_val_log10_error": best[0], "seconds": time.perf_counter() - started,
                     "parameters": sum(p.numel() for p in model.parameters()), "torch": torch.__version__,
                     "opset": OPSET, "history": history},
        "data": {"dir": str(data_dir), **{k: manifest.get(k) for k in (
            "n_frames", "shifts", "size_px", "markers", "finger", "depth_binning", "samples", "records",
            "grasps_used", "measurement_fingerprint")},
            # Names, not counts: `estimator evaluate --unseen-by` keeps the records of the test objects.
            "objects": {name: sorted(objects) for name, objects in load_split(data_dir / "split.json").items()},
            "split_seed": json.loads((data_dir / "split.json").read_text()).get("seed")},
    }
    (out_dir / "metadata.json").write_text(json.dumps(metadata, indent=1, allow_nan=False))
    _plot(history, best[1], out_dir / "training_curve.png")
    return metadata


# --------------------------------------------------------------------------- command


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
    parser.add_argument("--loss", choices=("huber", "mse"), default=TrainConfig.loss,
                        help="huber: smooth L1 with its knee at 0.25 decade (robust to hopeless grasps); "
                             "mse: the paper's")
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
    return Variant.parse(args.variant, n_frames=frames, size_px=size)


def _fmt(metrics: dict[str, Any], method: str) -> str:
    m = metrics.get(method) or {}
    if m.get("log10_error") is None:
        return "-"
    return f"{m['log10_error']:.2f} / {m['within_10x']:.0%} (n={m['n']})"


def run(args: argparse.Namespace) -> int:
    manifest = load_manifest(args.data)
    variant = _variant(args, manifest)
    config = TrainConfig(epochs=args.epochs, batch_size=args.batch_size, lr=args.lr, weight_decay=args.weight_decay,
                         patience=args.patience, loss=args.loss, seed=args.seed, threads=args.threads)
    meta = train_model(args.data, args.out, variant=variant, config=config)
    training = meta["training"]
    if args.json:
        print(json.dumps({"out": str(args.out), "variant": variant.name, "epochs_run": training["epochs_run"],
                          "best_epoch": training["best_epoch"], "seconds": training["seconds"],
                          "metrics": meta["metrics"]}, allow_nan=False))
        return 0
    print(f"{variant.name} ({variant.n_frames} frames, {variant.size_px[0]}x{variant.size_px[1]}): best epoch "
          f"{training['best_epoch']} of {training['epochs_run']}, {training['seconds']:.0f} s -> {args.out}")
    for split in ("val", "test"):
        metrics = meta["metrics"][split]
        if metrics:
            methods: Sequence[str] = [variant.method, *ANALYTICAL_METHODS]
            print(f"  {split:<4} ({metrics['objects']} objects) log10 error / within 10x: "
                  + ", ".join(f"{m} {_fmt(metrics, m)}" for m in methods))
    return 0
