"""Pool several trained models of one variant into one model (torch; building only).

Members trained on one dataset split with other seeds err partly on different grasps, so their
pooled distribution is less often sure of a wrong answer (a deep ensemble). The pooled
network (:class:`PooledNet`) outputs the log of the mean of the members' temperature-scaled
bin probabilities (a linear opinion pool), exported as one ONNX file with the members' inputs
and output, so the estimator runs it like any other model. Its calibration and ``auto`` policy
are then fitted on the validation objects (:func:`~estimator.training.recalibrate.recalibrate`);
``metadata.json`` ``ensemble`` names the members. :func:`pooled_from_onnx` rebuilds the pooled
network from its file, to fine-tune it as one.
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

from estimator.errors import EstimatorError
from estimator.inference.infer import CompliancePredictor
from estimator.inference.inputs import Variant, smoothings_text
from estimator.training.export import (
    check_rebuilt,
    export_onnx,
    load_exported_weights,
    network_from_onnx,
    onnx_weights,
)
from estimator.training.model import ComplianceNet
from estimator.training.outdir import (
    ModelWriteError,
    check_out_dir,
    make_out_dir,
    model_write_error,
)
from estimator.training.recalibrate import recalibrate
from estimator.training.splits import check_dataset_fits, load_split_data
from teleop.settings import Settings
from teleop.staging import staged_dir

__all__ = ["PooledNet", "pool_models", "pooled_from_onnx"]


class PooledNet(nn.Module):
    """log mean_i softmax(member_i(inputs) / temperature_i): log-probabilities (B, N_BINS), which
    are logits of the pooled distribution."""

    def __init__(self, members: Sequence[ComplianceNet], temperatures: Sequence[float]):
        super().__init__()
        self.variant = members[0].variant
        self.members = nn.ModuleList(members)
        self.register_buffer("inverse_temperatures", torch.tensor([1.0 / t for t in temperatures]))

    def forward(self, *inputs: torch.Tensor) -> torch.Tensor:
        log_probs = torch.stack([torch.log_softmax(member(*inputs) * self.inverse_temperatures[i], dim=1)
                                 for i, member in enumerate(self.members)])
        return torch.logsumexp(log_probs, dim=0) - math.log(len(self.members))


def pooled_from_onnx(path: str | Path, variant: Variant, temperatures: Sequence[float], *,
                     check: dict[str, np.ndarray]) -> PooledNet:
    """The pooled network ``path`` (written by :func:`pool_models`) computes, rebuilt in torch (eval mode):
    one member per temperature, each read from the weights named ``members.<i>.``; it must agree with
    onnxruntime within 1e-4 on ``check`` (ModelError otherwise)."""
    weights = onnx_weights(path)
    members = [load_exported_weights(ComplianceNet(variant), weights, prefix=f"members.{i}.", source=str(path))
               for i in range(len(temperatures))]
    return check_rebuilt(PooledNet(members, temperatures), path, check)


def _variant_text(variant: Variant) -> str:
    """A variant as a person reads it: its name, frames, image size and window."""
    window = "" if variant.window_m is None else (
        f", a {variant.window_m[0] * 1e3:.3g} x {variant.window_m[1] * 1e3:.3g} mm window")
    return f"{variant.name} ({variant.n_frames} frames of {variant.size_px[0]}x{variant.size_px[1]} px{window})"


def _provenance(model_dir: Path, predictor: CompliancePredictor) -> dict[str, Any]:
    """Where a member came from: its directory then, when and how it was trained (its ``training``,
    with the learning curve), and its temperature."""
    return {"dir": str(model_dir), "created_utc": predictor.metadata.raw.get("created_utc"),
            "training": predictor.metadata.raw.get("training"), "temperature": predictor.metadata.temperature}


def pool_models(model_dirs: Sequence[str | Path], data_dir: str | Path, out_dir: str | Path, *,
                settings: Settings | None = None, overwrite: bool = False) -> dict[str, Any]:
    """Pool the models in ``model_dirs`` into ``out_dir``, calibrated on the val objects of ``data_dir``
    (the dataset they were all trained on); returns the new metadata. ``out_dir`` must be new or empty
    unless ``overwrite`` (:func:`~estimator.training.outdir.check_out_dir`).

    Raises
    ------
    EstimatorError
        ``out_dir`` is a file or, without ``overwrite``, not empty; fewer than two models, a model given more than once, models of other variants, trained on
        other object splits or on depth of other calibration smoothings than the first, or a dataset
        that does not fit them.
    ModelError
        A model cannot be read or rebuilt.
    """
    if len(model_dirs) < 2:
        raise EstimatorError(f"pooling needs at least two models, got {len(model_dirs)}")
    model_dirs, data_dir, out_dir = [Path(d) for d in model_dirs], Path(data_dir), Path(out_dir)
    # A model pooled with itself passes the count but pools nothing; spelled two ways, it is still one model.
    resolved = [d.resolve() for d in model_dirs]
    twice = sorted({str(d) for d in resolved if resolved.count(d) > 1})
    if twice:
        raise EstimatorError(f"model {twice[0]}: given more than once")
    check_out_dir(out_dir, overwrite=overwrite)
    predictors = [CompliancePredictor(d) for d in model_dirs]
    first = predictors[0]
    for directory, predictor in zip(model_dirs[1:], predictors[1:], strict=True):
        if predictor.variant != first.variant:
            raise EstimatorError(f"--model {directory}: reads {_variant_text(predictor.variant)}, the first --model "
                                 f"{model_dirs[0]} reads {_variant_text(first.variant)}: pool models of one variant")
        if (predictor.metadata.raw.get("data") or {}).get("objects") != (first.metadata.raw.get("data") or {}).get("objects"):
            raise EstimatorError(f"{directory} was trained on another split of objects than {model_dirs[0]}: "
                                 "pool models trained on one dataset")
        if predictor.calibration_smoothing_px != first.calibration_smoothing_px:
            raise EstimatorError(f"{directory} was trained on depth from calibrations smoothing by "
                                 f"{smoothings_text(predictor.calibration_smoothing_px)}, {model_dirs[0]} by "
                                 f"{smoothings_text(first.calibration_smoothing_px)}: "
                                 "pool models trained on one dataset")
    if any(p.metadata.raw.get("ensemble") for p in predictors):
        raise EstimatorError("a pooled model cannot be pooled again: pool its members")
    check_dataset_fits(data_dir, first.variant, first.metadata.raw.get("data") or {})
    val = load_split_data(data_dir, first.variant, ("val",))["val"].live()
    if len(val) < 2:
        raise EstimatorError(f"{data_dir}: {len(val)} val samples; pooling needs at least 2 to check the export")
    example = {n: v[:8] for n, v in val.inputs.items()}
    members = [network_from_onnx(d / "model.onnx", first.variant, check=example) for d in model_dirs]
    pooled = PooledNet(members, [p.metadata.temperature for p in predictors])
    metadata = {
        **{k: v for k, v in first.metadata.raw.items() if k != "training"},  # each member's is in "ensemble"
        "created_utc": datetime.now(UTC).isoformat(timespec="seconds"),
        "ensemble": {"members": [_provenance(d, p) for d, p in zip(model_dirs, predictors, strict=True)],
                     "pool": "linear: log mean of the members' temperature-scaled bin probabilities"},
    }
    # Built beside and swapped in whole: an interrupt leaves the folder's earlier model as it was.
    try:
        try:
            out_dir.parent.mkdir(parents=True, exist_ok=True)
            with staged_dir(out_dir) as build:
                export_onnx(pooled, build / "model.onnx", example=example)
                (build / "metadata.json").write_text(json.dumps(metadata, indent=1, allow_nan=False))
                # The calibration in the file so far is the first member's, which recalibrate() reads the model by.
                result = recalibrate(build, data_dir, settings=settings, record=False)
        except OSError as exc:  # a full or read-only disk (recalibrate's own reads name their files)
            raise model_write_error(out_dir, exc) from exc
    except ModelWriteError as exc:  # recalibrate's writes name the hidden build folder: said of out_dir
        raise model_write_error(out_dir, exc.cause) from exc
    make_out_dir(out_dir)  # an earlier model's curve, carried over, would describe another network
    return result
