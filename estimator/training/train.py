"""``estimator train``: fit the network on a dataset's train objects, stop on its val objects.

Recipe
------
* Seeded and repeatable: ``torch.manual_seed``, deterministic algorithms, a
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
  ``--patience`` epochs); the best epoch is kept.
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
from collections.abc import Sequence
from dataclasses import asdict, dataclass, replace
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

from estimator.errors import EstimatorError, SampleError
from estimator.evaluation.metrics import summarise
from estimator.inference import distribution
from estimator.inference.distribution import censor, probabilities, quantile
from estimator.inference.hybrid import MIN_SERIES_FRAMES, interval_decades
from estimator.inference.infer import MODEL_FORMAT, MODEL_VERSION, current_scales
from estimator.inference.inputs import (
    ANALYTICAL_METHODS,
    MEASUREMENT_VERSION,
    RIG_QUANTITIES,
    Variant,
    analytical_floor,
    calibration_smoothings,
    default_window_m,
    distinct_frames,
    encode,
    gel_scale,
    smoothings_text,
)
from estimator.inference.provenance import SPLITS, load_split
from estimator.inference.reference import REFERENCE_RECORD, reference_inputs, summarise_inputs
from estimator.training.conformal import described, fit_conformal
from estimator.training.dataset import load_manifest
from estimator.training.export import OPSET, export_onnx
from estimator.training.model import ComplianceNet
from estimator.training.samples import TrainingSample, load_sample, sample_paths
from haptics.settings import display_range_pa
from teleop.progress import progress_bar
from teleop.settings import Settings, load_settings

__all__ = ["SplitData", "TrainConfig", "auto_policy", "check_dataset_fits", "load_split_data", "predict",
           "scored_rows", "split_metrics", "train_model"]

log = logging.getLogger(__name__)

NLL_WEIGHT = 0.05
AUTO_THRESHOLDS_DECADES = (0.1, 0.25, 0.5, 0.75, 1.0, 1.5, 2.0, 3.0)


@dataclass(frozen=True)
class TrainConfig:
    """The training recipe (module notes); stored in the model's metadata."""

    epochs: int = 60
    batch_size: int = 32
    lr: float = 2e-3
    weight_decay: float = 1e-4
    patience: int = 10
    label_sd_decades: float = 0.15
    seed: int = 0
    threads: int = 1

    def __post_init__(self) -> None:
        if not (math.isfinite(self.label_sd_decades) and self.label_sd_decades >= 0):
            raise EstimatorError(f"label_sd_decades {self.label_sd_decades!r}: expected a finite value >= 0")
        if min(self.epochs, self.batch_size, self.patience, self.threads) < 1:
            raise EstimatorError("epochs, batch_size, patience and threads must each be >= 1")
        if not (self.lr > 0 and self.weight_decay >= 0):
            raise EstimatorError(f"lr {self.lr} must be > 0 and weight_decay {self.weight_decay} >= 0")


@dataclass(frozen=True)
class SplitData:
    """The encoded samples of one split."""

    inputs: dict[str, np.ndarray]
    label: np.ndarray  # log10 E (Pa) on the reference gel (inputs' "Gel scale"), (n,)
    rows: list[dict[str, Any]]  # per sample: object, material, shape, truth_pa, gel_scale, estimates

    def __len__(self) -> int:
        return int(self.label.shape[0])

    @property
    def gel_scales(self) -> np.ndarray:
        """Each sample's :func:`~estimator.inference.inputs.gel_scale` (n,)."""
        return np.array([r["gel_scale"] for r in self.rows], dtype=np.float64)

    @property
    def floors_log10(self) -> np.ndarray:
        """Each sample's :func:`~estimator.inference.inputs.analytical_floor` on the reference gel (n,)."""
        return np.array([analytical_floor(r["estimates"], scale=r["gel_scale"])[0] for r in self.rows])

    def floors_for(self, variant: Variant) -> np.ndarray | None:
        """:attr:`floors_log10` for a variant that reads the analytical estimates, else None."""
        return self.floors_log10 if variant.analytical else None

    @property
    def peak_forces_n(self) -> np.ndarray:
        """Each sample's largest grasp force over its sampled frames (N), (n,)."""
        return np.array([r["peak_force_n"] for r in self.rows], dtype=np.float64)

    def subset(self, index: np.ndarray) -> SplitData:
        """The samples at ``index`` (positions, or a boolean mask)."""
        index = np.flatnonzero(index) if np.asarray(index).dtype == bool else np.asarray(index, dtype=np.int64)
        return SplitData({k: v[index] for k, v in self.inputs.items()}, self.label[index],
                         [self.rows[i] for i in index])

    def live(self) -> SplitData:
        """The samples of the live sampling (augmentation 0): one per grasp, as the estimator sees it."""
        return self.subset(np.array([r["augmentation"] == 0 for r in self.rows], dtype=bool))


def _row(sample: TrainingSample, path: Path) -> dict[str, Any]:
    if sample.label_modulus_pa is None:
        raise SampleError(f"{path}: sample has no label_modulus_pa")
    return {"object": sample.object_name, "augmentation": sample.augmentation,
            "gel_scale": gel_scale(sample.gel_modulus_pa), "material": sample.material or "unknown",
            "shape": sample.shape or "unknown", "truth_pa": sample.label_modulus_pa,
            "estimates": sample.estimates, "frames": distinct_frames(sample.force_n),
            "peak_force_n": float(np.max(sample.force_n)), "path": str(path),
            **{name: getattr(sample, name) for name in RIG_QUANTITIES}}


def rig_range(rows: Sequence[dict[str, Any]]) -> dict[str, list[float]]:
    """[least, most] of each rig quantity (:data:`RIG_QUANTITIES`) over the samples that record it: the
    rigs a model was trained on (``metadata.json`` ``data.rig_range``)."""
    out = {}
    for name in RIG_QUANTITIES:
        values = [r[name] for r in rows if r.get(name) is not None]
        if values:
            out[name] = [float(min(values)), float(max(values))]
    return out


def load_split_data(data_dir: str | Path, variant: Variant, splits: Sequence[str] = SPLITS) -> dict[str, SplitData]:
    """Encode every sample of ``splits`` of a ``build-dataset`` directory, per split.

    Raises
    ------
    SampleError
        A sample lies in a split its object is not assigned to (a leak), has no
        label, or does not fit the variant.
    """
    data_dir = Path(data_dir)
    split = load_split(data_dir / "split.json")
    out = {}
    for name in splits:
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
            label = np.log10([r["truth_pa"] * r["gel_scale"] for r in rows]).astype(np.float32)
        else:
            batch = {k: np.zeros((0, *s), np.float32) for k, s in variant.input_shapes.items()}
            label = np.zeros(0, np.float32)
        out[name] = SplitData(batch, label, rows)
    return out


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
    the mode the caller set; returns the mean loss per sample."""
    names = list(model.variant.input_shapes)
    label = torch.from_numpy(censor(data.label).astype(np.float32))
    order = torch.from_numpy(rng.permutation(len(data)))
    total = 0.0
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
    return total / len(data)


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


def scored_rows(data: SplitData, logits: np.ndarray, method: str, calibration: dict[str, Any]
                ) -> list[dict[str, Any]]:
    """evaluate-style rows: the model's calibrated estimate and each analytical estimate, per sample."""
    rows = []
    for row, said in zip(data.rows, described(logits, calibration, data.gel_scales, data.peak_forces_n,
                                               data.floors_log10), strict=True):
        base = {k: row[k] for k in ("object", "material", "shape", "truth_pa")}
        rows.append({**base, "method": method, "state": said.state, "e_pa": said.e_pa, "low_pa": said.low_pa,
                     "high_pa": said.high_pa})
        for est in row["estimates"]:
            low, high = est.interval_pa
            rows.append({**base, "method": est.method, "state": est.state, "e_pa": est.e_pa,
                         "low_pa": low, "high_pa": high})
    return rows


def split_metrics(data: SplitData, logits: np.ndarray, method: str, calibration: dict[str, Any],
                  settings: Settings) -> dict[str, Any]:
    """The model's figures on ``data`` (its calibrated answers, as ``estimator evaluate`` scores them) beside
    the analytical methods' on the same grasps."""
    if not len(data):
        return {}
    display = display_range_pa(settings)
    summary = summarise(scored_rows(data, logits, method, calibration), [method, *ANALYTICAL_METHODS],
                        display_range_pa=display, interval_levels={method: calibration["level"]})
    for value in summary.values():
        value.pop("paper", None)
    summary["objects"] = len({r["object"] for r in data.rows})
    return summary


def auto_policy(data: SplitData, logits: np.ndarray) -> dict[str, Any]:
    """``auto``'s series threshold: the widest interval at which the series fit, on the validation grasps
    it would answer (``ok`` over at least ``MIN_SERIES_FRAMES`` frames), errs no more on average than
    the model on those grasps (0: never)."""
    truth = np.log10([r["truth_pa"] for r in data.rows])
    model_error = np.abs(quantile(probabilities(logits), 0.5) - np.log10([r["gel_scale"] for r in data.rows]) - truth)
    series = [next((e for e in r["estimates"] if e.method == "series"), None) for r in data.rows]
    ok = np.array([e is not None and e.state == "ok" and r["frames"] >= MIN_SERIES_FRAMES
                   for e, r in zip(series, data.rows, strict=True)])
    width = np.array([interval_decades(e) if o else np.inf for e, o in zip(series, ok, strict=True)])
    series_error = np.array([abs(math.log10(e.e_pa) - t) if o else np.inf for e, o, t in zip(series, ok, truth,
                                                                                             strict=True)])
    table, chosen = [], 0.0
    for threshold in AUTO_THRESHOLDS_DECADES:
        taken = width <= threshold
        n = int(taken.sum())
        entry = {"max_interval_decades": threshold, "n": n, "share": n / len(data.rows),
                 "series_log10_error": float(series_error[taken].mean()) if n else None,
                 "model_log10_error": float(model_error[taken].mean()) if n else None}
        table.append(entry)
        if n and entry["series_log10_error"] <= entry["model_log10_error"]:
            chosen = threshold
    return {"max_series_interval_decades": chosen, "chosen_on": "val", "table": table}


def _plot(fitted: Fitted, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    history = fitted.history
    epochs = [h["epoch"] for h in history]
    fig, (ax_loss, ax_err) = plt.subplots(1, 2, figsize=(10, 4))
    ax_loss.plot(epochs, [h["train_loss"] for h in history], label="train")
    ax_loss.plot(epochs, [h["val_loss"] for h in history], label="val")
    ax_loss.set(xlabel="epoch", ylabel="CRPS + log score (decades)", yscale="log", title="loss")
    ax_err.plot(epochs, [h["train_log10_error"] for h in history], label="train")
    ax_err.plot(epochs, [h["val_log10_error"] for h in history], label="val")
    for ax in (ax_loss, ax_err):
        ax.axvline(fitted.best_epoch, color="0.5", ls="--", lw=1, label="kept")
        ax.legend()
    ax_err.set(xlabel="epoch", ylabel="mean |median - log10 E|", title="error (decades, E censored at 100 MPa)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
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
    torch.manual_seed(config.seed)
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
        entry = {"epoch": epoch, "train_loss": total, "val_loss": val_loss,
                 "train_log10_error": _mean_log10_error(train_pred, censor(train.label)),
                 "val_log10_error": _mean_log10_error(val_pred, val_label)}
        history.append(entry)
        bar.set_postfix(val_loss=f"{val_loss:.3f}", val_err=f"{entry['val_log10_error']:.3f}", best=best[1])
        if val_loss < best[0]:
            best = (val_loss, epoch, copy.deepcopy(model.state_dict()))
        elif epoch - best[1] >= config.patience:
            break
    model.load_state_dict(best[2])
    return Fitted(model.eval(), history, best[1], best[0])


def dataset_window(manifest: dict[str, Any], where: str) -> tuple[float, float]:
    """The input window (height, width; m) a dataset's images show (``window_m`` of its manifest); for a
    dataset built before the key, the pad of the default sensor (the simulated Wedge), with a note."""
    window = manifest.get("window_m")
    if window is None:
        window = default_window_m()
        log.info("%s: the manifest records no window_m; its images show the pad of the default sensor "
                 "(the simulated Wedge, %.2f x %.2f mm)", where, *(v * 1e3 for v in window))
    return (float(window[0]), float(window[1]))


def check_dataset_fits(data_dir: Path, variant: Variant, model_data: dict[str, Any]) -> None:
    """Refuse a dataset measured otherwise than a model's training data (``model_data``, its metadata's
    ``data``: measurement version, depth binning, calibration smoothing), or of another window, frame
    count or image size than ``variant``."""
    manifest = load_manifest(data_dir)
    version = model_data.get("measurement_version")
    if manifest.get("measurement_version") != version:
        raise EstimatorError(f"{data_dir} was measured by measurement version {manifest.get('measurement_version')}, "
                             f"the model's training data by {version}: rebuild the dataset with this code")
    binning, trained = manifest.get("depth_binning") or 1, model_data.get("depth_binning") or 1
    if binning != trained:
        raise EstimatorError(f"{data_dir} holds depth binned by {binning}, the model's training data by {trained}: "
                             f"build the dataset with settings whose estimator.depth_binning is {trained}")
    smoothings, trained_smoothings = calibration_smoothings(manifest), calibration_smoothings(model_data)
    if not set(smoothings) <= set(trained_smoothings):
        raise EstimatorError(f"{data_dir} holds depth from calibrations smoothing colours by "
                             f"{smoothings_text(smoothings)}, the model's training data from "
                             f"{smoothings_text(trained_smoothings)}: calibrate with `estimator calibrate "
                             f"--smoothing-px {trained_smoothings[0]:g}` and rebuild the dataset")
    window = dataset_window(manifest, str(data_dir))
    if not np.allclose(window, variant.window_m, rtol=1e-9, atol=0.0):
        raise EstimatorError(f"{data_dir} holds images of a {window[0]:.6g} x {window[1]:.6g} m window, the model "
                             f"reads {variant.window_m[0]:.6g} x {variant.window_m[1]:.6g} m: build the dataset with "
                             f"--window {variant.window_m[0] * 1e3:.2f}x{variant.window_m[1] * 1e3:.2f}")
    if (manifest["n_frames"], tuple(manifest["size_px"])) != (variant.n_frames, variant.size_px):
        raise EstimatorError(f"{data_dir} holds {manifest['n_frames']} frames of {manifest['size_px']} px per sample, "
                             f"the model reads {variant.n_frames} of {list(variant.size_px)}")


def train_model(
    data_dir: str | Path,
    out_dir: str | Path,
    *,
    variant: Variant,
    config: TrainConfig = TrainConfig(),
    settings: Settings | None = None,
    progress: bool = True,
) -> dict[str, Any]:
    """Train ``variant`` on the dataset in ``data_dir``; write the model to ``out_dir``; return its metadata.

    ``settings`` (default: the shipped ones) give the sensor's resolution limit at which the
    intervals are calibrated (:func:`fit_conformal`). The model's input window is the dataset's
    (:func:`dataset_window`; ``variant.window_m``, when given, must equal it); it is written to the
    metadata as ``variant.window_m``.

    Raises
    ------
    EstimatorError
        The dataset has no train or no val samples, or does not match the variant.
    """
    started = time.perf_counter()
    settings = load_settings() if settings is None else settings
    data_dir, out_dir = Path(data_dir), Path(out_dir)
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
    out_dir.mkdir(parents=True, exist_ok=True)
    example = {n: val.inputs[n][:8] if len(val) >= 2 else train.inputs[n][:8] for n in names}
    export_onnx(model, out_dir / "model.onnx", example=example)
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
    (out_dir / "metadata.json").write_text(json.dumps(metadata, indent=1, allow_nan=False))
    _plot(fitted, out_dir / "training_curve.png")
    return metadata
