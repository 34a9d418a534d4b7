"""``estimator train``: fit the network on a dataset's train objects, stop on its val objects.

Recipe
------
* Seeded and repeatable: ``torch.manual_seed`` (:func:`torch_seed`), deterministic algorithms, a
  seeded numpy generator for shuffles and flips, ``--threads`` torch threads.
  One thread by default: on a 2-core machine shared with anything else, two
  OpenMP threads spin against each other (docs/decisions/0012-train-on-one-thread.md).
* Augmentation that keeps the physics: random horizontal and vertical flips of
  every frame of a sample (a mirrored contact is an equally valid contact); the
  time shifts of the sampled frames are the dataset's sample sets (``--shifts``
  of ``build-dataset``).
* Loss: the network outputs a distribution over log10 E bins
  (:mod:`estimator.inference.distribution`), trained with the continuous ranked
  probability score (CRPS, in decades: a proper scoring rule that is the
  absolute error for a point mass, so the few grasps whose frames cannot tell a
  stiff plastic from a metal do not dominate as under a squared loss) plus
  ``NLL_WEIGHT`` times the log score of the label's bin (sharpens the
  distribution; also proper).
* AdamW, early stopping on the mean CRPS of the validation objects (patience
  ``--patience`` epochs); the best epoch is kept. A run whose losses pass :data:`DIVERGED_LOSS` or
  stop being finite, or whose weights do, stops with an error naming ``--lr`` (:func:`check_converging`).
* Label jitter: every step adds normal noise of ``--label-sd`` decades (0.15) to
  log10 of each label: the published labels are material-class values, uncertain
  by about a factor of 2, and without it the distribution puts its mass on the
  few moduli the labels take.
* Calibration on the validation objects
  (:func:`~estimator.training.conformal.fit_conformal`: the analytical floor, a
  temperature, and per band of grasp force the rigid probability and the
  interval scale), all in ``metadata.json`` ``calibration``, scored on the test
  objects.

Writes ``MODEL_DIR/model.onnx`` (checked against torch to 1e-4 in
onnxruntime), ``metadata.json`` (:mod:`estimator.inference.infer`: variant,
inputs, scales, the calibration of the run-time distribution,
metrics on val and test objects next to the analytical methods' on the same
grasps, the data and the recipe) and ``training_curve.png``.
"""

from __future__ import annotations

import copy
import json
import logging
import math
import time
from dataclasses import asdict, dataclass, replace
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

from estimator.errors import EstimatorError
from estimator.inference import distribution
from estimator.inference.distribution import censor, probabilities, quantile
from estimator.inference.infer import MODEL_FORMAT, MODEL_VERSION, current_scales
from estimator.inference.inputs import MEASUREMENT_VERSION, Variant
from estimator.inference.provenance import load_split
from estimator.inference.reference import REFERENCE_RECORD, reference_inputs, summarise_inputs
from estimator.training.conformal import fit_conformal
from estimator.training.dataset import load_manifest
from estimator.training.export import OPSET, export_onnx
from estimator.training.model import ComplianceNet
from estimator.training.outdir import check_out_dir, model_write_error
from estimator.training.recipe import TrainConfig
from estimator.training.splits import (
    SplitData,
    auto_policy,
    dataset_window,
    load_split_data,
    rig_range,
    split_metrics,
)
from teleop.progress import progress_bar
from teleop.settings import Settings, load_settings
from teleop.staging import staged

__all__ = ["DIVERGED_LOSS", "NLL_WEIGHT", "check_converging", "distribution_loss", "predict", "torch_seed",
           "train_epoch", "train_model"]

log = logging.getLogger(__name__)

NLL_WEIGHT = 0.05
#: A loss per sample that only a diverging run reaches: the uninformed network (uniform over the bins)
#: scores about 2 (a run at ``--lr 1`` on a few grasps scores 1e4-1e10, and its logits are too large for
#: the ONNX file to match torch).
DIVERGED_LOSS = 1e3
#: torch seeds its generator with an unsigned 64-bit number.
_TORCH_SEEDS = 2**64


def torch_seed(seed: int) -> int:
    """torch's seed for the recipe's ``seed`` (any whole number >= 0, as numpy's generators take):
    ``seed`` itself below 2**64, so models trained with those seeds stay reproducible; larger ones wrap."""
    return seed % _TORCH_SEEDS


def check_converging(model: nn.Module, losses: dict[str, float], epoch: int, lr: float, what: str) -> None:
    """Stop a run (``what``: "training", "fine-tuning") whose ``losses`` (name -> loss per sample after
    ``epoch``) are not finite or exceed :data:`DIVERGED_LOSS`, or whose weights are not finite.

    Raises
    ------
    EstimatorError
        As above, naming the loss, the epoch and ``lr`` (``--lr``).
    """
    bad = next(((name, value) for name, value in losses.items()
                if not (math.isfinite(value) and value <= DIVERGED_LOSS)), None)
    if bad is None and all(bool(torch.isfinite(p).all()) for p in model.parameters()):
        return
    found = f"{bad[0]} {bad[1]:.3g}" if bad else "weights not finite"
    raise EstimatorError(f"{what} diverged: {found} at epoch {epoch} (--lr {lr:g}): lower --lr")


_EDGES = torch.from_numpy(distribution.EDGES_LOG10[1:-1].astype(np.float32))


def distribution_loss(logits: torch.Tensor, log10_e: torch.Tensor) -> torch.Tensor:
    """Mean CRPS (decades) of the binned distributions plus ``NLL_WEIGHT`` times the log score of the
    labels' bins (module notes), per batch, for censored labels (:func:`~estimator.inference.distribution.censor`)."""
    cdf = torch.softmax(logits, dim=1).cumsum(dim=1)[:, :-1]
    step = (log10_e[:, None] <= _EDGES[None]).to(cdf.dtype)
    crps = ((cdf - step) ** 2).sum(dim=1) * distribution.BIN_DECADES
    index = torch.from_numpy(distribution.bin_index(log10_e.detach().numpy()))
    return crps.mean() + NLL_WEIGHT * nn.functional.cross_entropy(logits, index)


def _flip(frames: torch.Tensor, generator: np.random.Generator) -> torch.Tensor:
    """Flip each sample's frames left-right and/or up-down at random (all its frames alike)."""
    flips = torch.from_numpy(generator.random((frames.shape[0], 2)) < 0.5)
    frames = torch.where(flips[:, 0, None, None, None, None], frames.flip(-1), frames)
    return torch.where(flips[:, 1, None, None, None, None], frames.flip(-2), frames)


def train_epoch(model: ComplianceNet, data: SplitData, optimiser: torch.optim.Optimizer, config: TrainConfig,
                rng: np.random.Generator) -> float:
    """One pass over ``data`` in shuffled batches (flips and label jitter as the module notes say), in
    the mode the caller set; returns the mean loss per sample trained on (a last batch of one is skipped).

    Raises
    ------
    EstimatorError
        No batch holds 2 samples (``--batch-size`` 1, or fewer than 2 samples), naming ``--batch-size``.
    """
    names = list(model.variant.input_shapes)
    label = torch.from_numpy(censor(data.label).astype(np.float32))
    order = torch.from_numpy(rng.permutation(len(data)))
    total, trained = 0.0, 0
    for start in range(0, len(data), config.batch_size):
        index = order[start:start + config.batch_size]
        if index.numel() < 2:  # batch norm needs two samples
            continue
        args = [torch.from_numpy(data.inputs[n][index.numpy()]) for n in names]
        args[0] = _flip(args[0], rng)
        optimiser.zero_grad()
        jitter = torch.from_numpy(rng.normal(0.0, config.label_sd_decades, index.numel()).astype(np.float32))
        loss = distribution_loss(model(*args), label[index] + jitter)
        loss.backward()
        optimiser.step()
        total += float(loss.detach()) * index.numel()
        trained += index.numel()
    if not trained:  # nothing would train, and the initial weights would ship as the model
        raise EstimatorError(f"--batch-size {config.batch_size}: no batch of 2 or more among {len(data)} sample(s) "
                             "(batch norm needs two a batch): expected a batch size >= 2 and at least 2 samples")
    return total / trained


def predict(model: ComplianceNet, data: SplitData, batch_size: int = 256) -> np.ndarray:
    """Logits (n, N_BINS) of every sample of ``data``."""
    model.eval()
    names = list(model.variant.input_shapes)
    out = []
    with torch.no_grad():
        for start in range(0, len(data), batch_size):
            args = [torch.from_numpy(data.inputs[n][start:start + batch_size]) for n in names]
            out.append(model(*args).numpy())
    return np.concatenate(out) if out else np.zeros((0, distribution.N_BINS), np.float32)


def _mean_log10_error(logits: np.ndarray, label: np.ndarray) -> float:
    """Mean |median - label| in decades."""
    return float(np.mean(np.abs(quantile(probabilities(logits), 0.5) - label)))



def _plot(fitted: Fitted, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    history = fitted.history
    epochs = [h["epoch"] for h in history]
    fig, (ax_loss, ax_err) = plt.subplots(1, 2, figsize=(10, 4))
    ax_loss.plot(epochs, [h["train_loss"] for h in history], label="train")
    ax_loss.plot(epochs, [h["val_loss"] for h in history], label="val")
    variant = getattr(getattr(fitted.model, "variant", None), "name", None) or "model"
    # Linear: the loss moves by less than a decade. Its two terms have different units: the CRPS
    # in decades of E, the log score of the label's bin in nats (distribution_loss).
    ax_loss.set(xlabel="epoch", ylabel=f"CRPS (decades) + {NLL_WEIGHT:g} x log score (nats)",
                title=f"{variant}: training loss")
    ax_err.plot(epochs, [h["train_log10_error"] for h in history], label="train")
    ax_err.plot(epochs, [h["val_log10_error"] for h in history], label="val")
    for ax in (ax_loss, ax_err):
        ax.axvline(fitted.best_epoch, color="0.5", ls="--", lw=1, label="kept")
        ax.legend()
    ax_err.set(xlabel="epoch", ylabel="mean |median - log10 E| (decades)",
               title=f"{variant}: error (E censored at 100 MPa)")
    fig.tight_layout()
    fig.savefig(path, dpi=110, format="png")  # the staged name does not end in .png
    plt.close(fig)


@dataclass
class Fitted:
    """The trained network at its best validation epoch, and how it got there."""

    model: ComplianceNet
    history: list[dict[str, float]]
    best_epoch: int
    best_val_loss: float


def _fit(train: SplitData, val: SplitData, variant: Variant, config: TrainConfig, *, progress: bool) -> Fitted:
    """Train the network (seeded weights, shuffles, flips and label jitter); early-stopped on the
    validation loss, the best epoch kept."""
    torch.manual_seed(torch_seed(config.seed))
    rng = np.random.default_rng(config.seed)
    model = ComplianceNet(variant)
    optimiser = torch.optim.AdamW(model.parameters(), lr=config.lr, weight_decay=config.weight_decay)
    scheduler = torch.optim.lr_scheduler.CosineAnnealingLR(optimiser, T_max=config.epochs)
    val_label = censor(val.label).astype(np.float32)
    history: list[dict[str, float]] = []
    best = (math.inf, 0, copy.deepcopy(model.state_dict()))
    bar = progress_bar(range(1, config.epochs + 1), desc="train", unit="epoch", enabled=progress)
    for epoch in bar:
        model.train()
        total = train_epoch(model, train, optimiser, config, rng)
        scheduler.step()
        train_pred, val_pred = predict(model, train), predict(model, val)
        with torch.no_grad():
            val_loss = float(distribution_loss(torch.from_numpy(val_pred), torch.from_numpy(val_label)))
        check_converging(model, {"training loss": total, "validation loss": val_loss}, epoch, config.lr, "training")
        entry = {"epoch": epoch, "train_loss": total, "val_loss": val_loss,
                 "train_log10_error": _mean_log10_error(train_pred, censor(train.label)),
                 "val_log10_error": _mean_log10_error(val_pred, val_label)}
        history.append(entry)
        improved = val_loss < best[0]
        if improved:
            best = (val_loss, epoch, copy.deepcopy(model.state_dict()))
        # After the update: the bar's best is the epoch kept so far, as the metadata's best_epoch.
        bar.set_postfix(val_loss=f"{val_loss:.3f}", val_err=f"{entry['val_log10_error']:.3f}", best=best[1])
        if not improved and epoch - best[1] >= config.patience:
            break
    model.load_state_dict(best[2])
    return Fitted(model.eval(), history, best[1], best[0])


def train_model(
    data_dir: str | Path,
    out_dir: str | Path,
    *,
    variant: Variant,
    config: TrainConfig | None = None,
    settings: Settings | None = None,
    progress: bool = True,
    overwrite: bool = False,
) -> dict[str, Any]:
    """Train ``variant`` on the dataset in ``data_dir``; write the model to ``out_dir``; return its metadata.

    ``config`` defaults to :class:`~estimator.training.recipe.TrainConfig`'s defaults. ``settings`` (default: the shipped ones) give the sensor's resolution limit at which the
    intervals are calibrated (:func:`fit_conformal`). The model's input window is the dataset's
    (:func:`dataset_window`; ``variant.window_m``, when given, must equal it); it is written to the
    metadata as ``variant.window_m``. ``out_dir`` must be new or empty unless ``overwrite``
    (:func:`~estimator.training.outdir.check_out_dir`).

    Raises
    ------
    EstimatorError
        ``out_dir`` is a file or, without ``overwrite``, not empty; the dataset has no train or no val
        samples, or does not match the variant; training diverges (:func:`check_converging`, before
        ``out_dir`` is made); the model cannot be written into ``out_dir`` (a full
        or read-only disk; :func:`~estimator.training.outdir.model_write_error`).
    """
    started = time.perf_counter()
    config = TrainConfig() if config is None else config
    settings = load_settings() if settings is None else settings
    data_dir, out_dir = Path(data_dir), Path(out_dir)
    check_out_dir(out_dir, overwrite=overwrite)
    manifest = load_manifest(data_dir)
    if manifest.get("measurement_version") != MEASUREMENT_VERSION:
        log.warning("%s was measured by measurement version %s, this code is version %s: the model will learn "
                    "inputs the estimator no longer produces; rebuild the dataset", data_dir,
                    manifest.get("measurement_version"), MEASUREMENT_VERSION)
    window = dataset_window(manifest, str(data_dir))
    if variant.window_m is None:
        variant = replace(variant, window_m=window)
    elif not np.allclose(variant.window_m, window, rtol=1e-9, atol=0.0):
        raise EstimatorError(f"variant window {variant.window_m} m: {data_dir} holds images of a "
                             f"{window[0]:.6g} x {window[1]:.6g} m window")
    if variant.markers and not manifest.get("markers"):
        raise EstimatorError(f"variant {variant.name} reads markers; {data_dir} was built without --markers")
    data = load_split_data(data_dir, variant)
    train, val = data["train"], data["val"].live()
    if not len(train) or not len(val):
        raise EstimatorError(f"{data_dir}: {len(train)} train and {len(val)} val samples; both splits need "
                             "samples (more objects, or other --split fractions)")
    torch.use_deterministic_algorithms(True)
    torch.set_num_threads(config.threads)
    fitted = _fit(train, val, variant, config, progress=progress)
    model = fitted.model
    names = list(variant.input_shapes)
    example = {n: val.inputs[n][:8] if len(val) >= 2 else train.inputs[n][:8] for n in names}
    val_pred = predict(model, val)
    # In the reference gel's moduli, as the network's labels.
    soft_pa = float(min(r["truth_pa"] * r["gel_scale"] for r in train.rows))
    calibration = fit_conformal(val_pred, val.label, gel_scales=val.gel_scales, peak_forces_n=val.peak_forces_n,
                                floors_log10=val.floors_for(variant), soft_pa=soft_pa,
                                limit_pa=settings.resolution_limit_pa)
    metadata = {
        "format": MODEL_FORMAT,
        "version": MODEL_VERSION,
        "created_utc": datetime.now(UTC).isoformat(timespec="seconds"),
        "variant": {"name": variant.name, "n_frames": variant.n_frames, "size_px": list(variant.size_px),
                    "window_m": list(variant.window_m), "method": variant.method},
        "inputs": {n: [None, *s] for n, s in variant.input_shapes.items()},
        "output": "log10_e_logits",
        "scales": current_scales(),
        "calibration": calibration,
        "reference": {"record": REFERENCE_RECORD.name,
                      "inputs": summarise_inputs(reference_inputs(variant, settings=settings))},
        "auto": auto_policy(val, val_pred),
        "metrics": {name: split_metrics(part, predict(model, part), variant.method, calibration, settings)
                    for name, part in (("val", val), ("test", data["test"].live()))},
        "training": {**asdict(config), "epochs_run": len(fitted.history), "best_epoch": fitted.best_epoch,
                     "best_val_loss": fitted.best_val_loss, "seconds": time.perf_counter() - started,
                     "parameters": sum(p.numel() for p in model.parameters()), "torch": torch.__version__,
                     "opset": OPSET, "history": fitted.history},
        "data": {"dir": str(data_dir), **{k: manifest.get(k) for k in (
            "n_frames", "shifts", "size_px", "window_m", "markers", "finger", "depth_binning", "samples", "records",
            "grasps_used", "measurement_version", "calibration_smoothing_px")},
            "rig_range": rig_range(train.rows),
            # Names, not counts: `estimator evaluate --unseen-by` keeps the records of the test objects.
            "objects": {name: sorted(objects) for name, objects in load_split(data_dir / "split.json").items()},
            "split_seed": json.loads((data_dir / "split.json").read_text()).get("seed")},
    }
    # An OSError here is the disk (full, read-only), not the model: say which folder, and that the
    # earlier model there is whole.
    try:
        out_dir.mkdir(parents=True, exist_ok=True)  # an earlier curve stays until the new one replaces it
        # Every file under a staged name first, renamed into place together at the end (the curve, then
        # model.onnx and metadata.json back to back): an interrupted run leaves the earlier model, curve
        # included, as it was. A watcher can at most see, for the microseconds between the last two
        # renames, the new model.onnx beside the old metadata.json; it takes the folder up once both
        # stop changing (estimator.model_slot).
        with staged(out_dir / "training_curve.png", out_dir / "model.onnx", out_dir / "metadata.json") as (
                curve_path, model_path, metadata_path):
            export_onnx(model, model_path, example=example)
            metadata_path.write_text(json.dumps(metadata, indent=1, allow_nan=False))
            _plot(fitted, curve_path)
    except OSError as exc:
        raise model_write_error(out_dir, exc) from exc
    return metadata
