"""Refit a trained model's calibration on its validation objects, without retraining.

The network's weights stay. What is fitted on the validation objects from its outputs (the
calibration of :func:`~estimator.learned.calibrate.calibrate`: temperature, rigid probability, interval
scale; and ``auto``'s split threshold) is fitted anew, with this code's rules for what an answer
says, and the model's ``metrics`` on its val and test objects are scored again: a change to how
answers are described or calibrated needs no retraining. The dataset is a ``build-dataset``
directory of the model's own data (``metadata.json`` ``data.dir``); its val and test objects must
be objects the model never trained on. ``recalibrated`` in the metadata says when, from what, and
keeps the calibration it replaced.
"""

from __future__ import annotations

import json
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np

from estimator.errors import EstimatorError
from estimator.learned.calibrate import calibrate
from estimator.learned.dataset import load_split
from estimator.learned.infer import CompliancePredictor
from estimator.learned.train import (
    SplitData,
    auto_policy,
    check_dataset_fits,
    load_split_data,
    split_metrics,
)
from teleop.settings import Settings, load_settings

__all__ = ["recalibrate"]

_BATCH = 256


def _logits(predictor: CompliancePredictor, data: SplitData) -> np.ndarray:
    """The model's logits for every sample of ``data``, in batches (onnxruntime)."""
    chunks = [predictor.predict_logits({n: v[start:start + _BATCH] for n, v in data.inputs.items()})
              for start in range(0, len(data), _BATCH)]
    return np.concatenate(chunks) if chunks else np.zeros((0, 0), np.float32)


def recalibrate(model_dir: str | Path, data_dir: str | Path, *, out_dir: str | Path | None = None,
                settings: Settings | None = None, record: bool = True) -> dict[str, Any]:
    """Refit the calibration of the model in ``model_dir`` on the val objects of ``data_dir`` and score
    it on the val and test objects; write the metadata to ``out_dir`` (default: in place, with
    ``model.onnx`` copied there when elsewhere). ``settings`` (default: the shipped ones) give the
    resolution limit, as for ``estimator train``. ``record`` keeps when, from what and the calibration it
    replaced under ``recalibrated`` (off for a model whose calibration is its first). Returns the new
    metadata.

    Raises
    ------
    EstimatorError
        The dataset does not fit the model (measurement version, window, frames, size), has no val
        samples, or holds val or test objects the model trained on.
    ModelError
        The model cannot be read.
    """
    model_dir, data_dir = Path(model_dir), Path(data_dir)
    out_dir = model_dir if out_dir is None else Path(out_dir)
    predictor = CompliancePredictor(model_dir)
    variant, metadata = predictor.variant, dict(predictor.metadata.raw)
    settings = load_settings() if settings is None else settings
    check_dataset_fits(data_dir, variant, metadata.get("data") or {})
    trained_on = set(((metadata.get("data") or {}).get("objects") or {}).get("train") or [])
    split = load_split(data_dir / "split.json")
    seen = sorted(trained_on & (set(split["val"]) | set(split["test"])))
    if seen:
        raise EstimatorError(f"{data_dir}: val or test objects the model trained on ({', '.join(seen[:5])}"
                             f"{', ...' if len(seen) > 5 else ''}): use the dataset the model was trained on")
    parts = {name: part.live() for name, part in load_split_data(data_dir, variant, ("val", "test")).items()}
    if not len(parts["val"]):
        raise EstimatorError(f"{data_dir}: no val samples to calibrate on")
    logits = {name: _logits(predictor, part) for name, part in parts.items()}
    val = parts["val"]
    calibration = calibrate(logits["val"], val.label, gel_scales=val.gel_scales, peak_forces_n=val.peak_forces_n,
                            floors_log10=val.floors_for(variant), soft_pa=predictor.metadata.soft_pa,
                            limit_pa=settings.resolution_limit_pa)
    new = {
        **metadata,
        "calibration": calibration,
        "auto": auto_policy(val, logits["val"]),
        "metrics": {name: split_metrics(part, logits[name], variant.method, calibration, settings)
                    for name, part in parts.items()},
    }
    if record:
        new["recalibrated"] = {"utc": datetime.now(UTC).isoformat(timespec="seconds"), "data": str(data_dir),
                               "settings": str(settings.source) if settings.source else None,
                               "previous": metadata["calibration"]}
    out_dir.mkdir(parents=True, exist_ok=True)
    if out_dir.resolve() != model_dir.resolve():
        (out_dir / "model.onnx").write_bytes((model_dir / "model.onnx").read_bytes())
    (out_dir / "metadata.json").write_text(json.dumps(new, indent=1, allow_nan=False))
    return new
