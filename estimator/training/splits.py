"""The encoded samples of a ``build-dataset`` directory and how a model's answers on them are scored.

Shared by training, fine-tuning, pooling and recalibrating, and torch-free: ``estimator recalibrate``
refits a model's calibration through onnxruntime alone, without the ``train`` extra.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from estimator.errors import EstimatorError, SampleError
from estimator.evaluation.metrics import summarise
from estimator.inference.distribution import probabilities, quantile
from estimator.inference.hybrid import MIN_SERIES_FRAMES, interval_decades
from estimator.inference.inputs import (
    ANALYTICAL_METHODS,
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
from estimator.training.conformal import described
from estimator.training.dataset import load_manifest
from estimator.training.samples import TrainingSample, load_sample, sample_paths
from haptics.settings import display_range_pa
from teleop.settings import Settings

__all__ = ["SplitData", "auto_policy", "check_dataset_fits", "dataset_window", "load_split_data", "rig_range",
           "scored_rows", "split_metrics"]

log = logging.getLogger(__name__)

AUTO_THRESHOLDS_DECADES = (0.1, 0.25, 0.5, 0.75, 1.0, 1.5, 2.0, 3.0)


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
