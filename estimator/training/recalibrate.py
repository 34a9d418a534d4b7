"""Refit a trained model's calibration on its validation objects, without retraining.

The network's weights stay. What is fitted on the validation objects from its outputs (the
calibration of :func:`~estimator.training.conformal.fit_conformal`: temperature, rigid probability, interval
scale; and ``auto``'s split threshold) is fitted anew, with this code's rules for what an answer
says, and the model's ``metrics`` on its val and test objects are scored again: a change to how
answers are described or calibrated needs no retraining. The dataset is a ``build-dataset``
directory of the model's own data (``metadata.json`` ``data.dir``); its val and test objects must
be objects the model never trained on, except that the val and test objects any of its fine-tuning
steps trained on (:func:`fine_tuned_objects`: ``fine_tuning.objects`` in its metadata, and those of
``fine_tuning.earlier``; fine-tuning moves them to train) are left out (:func:`trained_held_out`,
whose rule fine-tuning's own recalibration on ``--replay`` follows too). ``recalibrated`` in the metadata says when, from what,
which objects were left out (``left_out``), and keeps the calibration it replaced.

:func:`cross_validate` (``estimator recalibrate --cross-validate``) says what such a calibration
scores on objects it was not fitted on, from the val objects alone (k folds by object): the figures
to choose between two ways of calibrating or describing answers by, leaving the test objects for
the verdict.
"""

from __future__ import annotations

import json
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np

from estimator.errors import EstimatorError
from estimator.evaluation.metrics import summarise
from estimator.inference.distribution import force_band
from estimator.inference.infer import CompliancePredictor
from estimator.inference.provenance import load_split
from estimator.training.conformal import fit_conformal
from estimator.training.outdir import check_out_dir, make_out_dir, model_write_error
from estimator.training.splits import (
    SplitData,
    auto_policy,
    check_dataset_fits,
    load_split_data,
    scored_rows,
    split_metrics,
)
from haptics.settings import display_range_pa
from teleop.settings import Settings, load_settings
from teleop.staging import staged

__all__ = ["cross_validate", "fine_tuned_objects", "recalibrate", "trained_held_out"]

_BATCH = 256


def _logits(predictor: CompliancePredictor, data: SplitData) -> np.ndarray:
    """The model's logits for every sample of ``data``, in batches (onnxruntime)."""
    chunks = [predictor.predict_logits({n: v[start:start + _BATCH] for n, v in data.inputs.items()})
              for start in range(0, len(data), _BATCH)]
    return np.concatenate(chunks) if chunks else np.zeros((0, 0), np.float32)


def fine_tuned_objects(metadata: dict[str, Any]) -> set[str]:
    """Every object the fine-tuning steps that made a model trained on: ``fine_tuning.objects`` of its
    last step and of each earlier one (``fine_tuning.earlier``, :func:`~estimator.training.finetune.fine_tune`).

    Parameters
    ----------
    metadata : dict
        The model's ``metadata.json``.

    Returns
    -------
    set of str
        The objects' names (empty for a model that was not fine-tuned).
    """
    tuning = metadata.get("fine_tuning") or {}
    return {str(name) for step in [*(tuning.get("earlier") or []), tuning] for name in step.get("objects") or []}


def trained_held_out(metadata: dict[str, Any], data_dir: Path) -> list[str]:
    """The val and test objects of the dataset in ``data_dir`` that the model of ``metadata`` trained on
    because a fine-tuning step did (module notes): what calibrating on that dataset leaves out.

    Parameters
    ----------
    metadata : dict
        The model's ``metadata.json`` (its ``data.objects.train`` and ``fine_tuning``).
    data_dir : Path
        A ``build-dataset`` directory (its ``split.json``).

    Returns
    -------
    list of str
        Those objects' names, sorted.

    Raises
    ------
    EstimatorError
        The dataset's val or test objects include others the model trained on (named): it is not the
        dataset the model, or its base model, was trained on.
    """
    trained_on = set(((metadata.get("data") or {}).get("objects") or {}).get("train") or [])
    tuning = metadata.get("fine_tuning") or {}
    added = fine_tuned_objects(metadata)
    split = load_split(data_dir / "split.json")
    seen = trained_on & (set(split["val"]) | set(split["test"]))
    unexplained = sorted(seen - added)
    if unexplained:
        steps = [*(tuning.get("earlier") or []), tuning]
        hint = ("use the dataset the model was trained on" if not tuning else
                f"the model was fine-tuned (on {', '.join(str(step.get('data')) for step in steps)}), which moves "
                f"only its own objects ({', '.join(sorted(added)) or 'none'}) to train: use the dataset its base "
                "model was trained on")
        raise EstimatorError(f"{data_dir}: val or test objects the model trained on ({', '.join(unexplained[:5])}"
                             f"{', ...' if len(unexplained) > 5 else ''}): {hint}")
    return sorted(seen)


def _load(model_dir: Path, data_dir: Path, splits: tuple[str, ...]
          ) -> tuple[CompliancePredictor, dict[str, SplitData], dict[str, np.ndarray], list[str]]:
    """The model, the live samples of ``splits`` of its own dataset and its logits for them, after the
    checks of :func:`recalibrate`, and the val or test objects left out because fine-tuning trained on
    them (module notes)."""
    predictor = CompliancePredictor(model_dir)
    check_dataset_fits(data_dir, predictor.variant, predictor.metadata.raw.get("data") or {})
    dropped = trained_held_out(predictor.metadata.raw, data_dir)
    seen = set(dropped)
    parts = {}
    for name, part in load_split_data(data_dir, predictor.variant, splits).items():
        part = part.live()
        parts[name] = part.subset(np.array([r["object"] not in seen for r in part.rows], dtype=bool))
    if not len(parts["val"]):
        why = (f" once the objects its fine-tuning trained on ({', '.join(dropped)}) are left out" if dropped
               else "")
        raise EstimatorError(f"{data_dir}: no val samples to calibrate on{why}")
    return predictor, parts, {name: _logits(predictor, part) for name, part in parts.items()}, dropped


def _fit_conformal_on(predictor: CompliancePredictor, val: SplitData, logits: np.ndarray,
                  settings: Settings) -> dict[str, Any]:
    return fit_conformal(logits, val.label, gel_scales=val.gel_scales, peak_forces_n=val.peak_forces_n,
                         floors_log10=val.floors_for(predictor.variant), soft_pa=predictor.metadata.soft_pa,
                         limit_pa=settings.resolution_limit_pa)


def recalibrate(model_dir: str | Path, data_dir: str | Path, *, out_dir: str | Path | None = None,
                settings: Settings | None = None, record: bool = True, overwrite: bool = False) -> dict[str, Any]:
    """Refit the calibration of the model in ``model_dir`` on the val objects of ``data_dir`` and score
    it on the val and test objects; write the metadata to ``out_dir`` (default: in place, with
    ``model.onnx`` copied there when elsewhere; elsewhere, it must be new or empty unless ``overwrite``,
    :func:`~estimator.training.outdir.check_out_dir`). ``settings`` (default: the shipped ones) give the
    resolution limit, as for ``estimator train``. ``record`` keeps when, from what and the calibration it
    replaced under ``recalibrated`` (off for a model whose calibration is its first). Returns the new
    metadata.

    Raises
    ------
    EstimatorError
        ``out_dir`` (elsewhere) is a file or, without ``overwrite``, not empty; the dataset does not fit
        the model (measurement version, window, frames, size), has no val samples, or holds val or test
        objects the model trained on; the model cannot be written into ``out_dir`` (a full or
        read-only disk; :func:`~estimator.training.outdir.model_write_error`).
    ModelError
        The model cannot be read.
    """
    model_dir, data_dir = Path(model_dir), Path(data_dir)
    out_dir = model_dir if out_dir is None else Path(out_dir)
    in_place = out_dir.resolve() == model_dir.resolve()
    if not in_place:
        check_out_dir(out_dir, overwrite=overwrite)
    settings = load_settings() if settings is None else settings
    predictor, parts, logits, dropped = _load(model_dir, data_dir, ("val", "test"))
    variant, metadata = predictor.variant, dict(predictor.metadata.raw)
    val = parts["val"]
    calibration = _fit_conformal_on(predictor, val, logits["val"], settings)
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
                               "previous": metadata["calibration"], "left_out": dropped}
    network = None if in_place else (model_dir / "model.onnx").read_bytes()  # a read: not the write's error
    # Written beside and renamed in together: an interrupt leaves the folder's earlier model whole.
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
        with staged(out_dir / "model.onnx", out_dir / "metadata.json") as (model_tmp, metadata_tmp):
            if network is not None:
                model_tmp.write_bytes(network)
            metadata_tmp.write_text(json.dumps(new, indent=1, allow_nan=False))
    except OSError as exc:
        raise model_write_error(out_dir, exc) from exc
    if not in_place:
        make_out_dir(out_dir)  # an earlier model's curve would describe another network
    return new


def cross_validate(model_dir: str | Path, data_dir: str | Path, *, folds: int = 5, seed: int = 0,
                   settings: Settings | None = None) -> dict[str, Any]:
    """What :func:`recalibrate` can expect on objects it did not calibrate on: ``folds``-fold
    cross-validation by object over the val objects of ``data_dir``. The val objects are dealt into
    ``folds`` groups (shuffled with ``seed``); each group's grasps are answered under a calibration
    fitted on the other groups, and all the answers are scored as ``estimator evaluate`` scores them.
    Writes nothing; the test objects are not read.

    Returns ``folds``, ``seed``, ``objects``, ``grasps``, ``level``, ``metrics`` (the model method's
    :func:`~estimator.evaluation.metrics.summarise` figures: felt error, dangerous misses, coverage, widths, ...) and,
    per band of peak force (``force_band_edges_n``), ``band_n`` and ``band_coverage``.

    Raises
    ------
    EstimatorError
        As :func:`recalibrate`, or ``folds`` is not from 2 to the number of val objects.
    """
    settings = load_settings() if settings is None else settings
    predictor, parts, logits, _ = _load(Path(model_dir), Path(data_dir), ("val",))
    val, val_logits = parts["val"], logits["val"]
    objects = np.array([r["object"] for r in val.rows])
    names = sorted(set(objects))
    if not 2 <= folds <= len(names):
        default = "; 5 is the number --cross-validate takes without FOLDS" if folds == 5 else ""
        raise EstimatorError(f"--cross-validate FOLDS {folds}: expected 2 to {len(names)} (the number of val objects "
                             f"of {data_dir}: every fold needs one){default}"
                             + ("; cross-validation needs at least 2 val objects" if len(names) < 2 else ""))
    order = np.random.default_rng(seed).permutation(len(names))
    fold_of = {names[i]: k % folds for k, i in enumerate(order)}
    fold = np.array([fold_of[o] for o in objects])
    method, rows = predictor.variant.method, [None] * len(val)
    for k in range(folds):
        out = fold == k
        calibration = _fit_conformal_on(predictor, val.subset(~out), val_logits[~out], settings)
        scored = scored_rows(val.subset(out), val_logits[out], method, calibration)
        answers = (r for r in scored if r["method"] == method)
        for i, row in zip(np.flatnonzero(out), answers, strict=True):
            rows[i] = row
    edges = tuple(calibration["force_band_edges_n"])
    display = display_range_pa(settings)

    def score(mask: np.ndarray) -> dict[str, Any]:
        return summarise([r for r, m in zip(rows, mask, strict=True) if m], [method], display_range_pa=display,
                         interval_levels={method: calibration["level"]})[method]

    bands = force_band(val.peak_forces_n, edges)
    per_band = [score(bands == b) for b in range(len(edges) + 1)]
    return {"folds": folds, "seed": seed, "objects": len(names), "grasps": len(val), "method": method,
            "level": calibration["level"], "metrics": score(np.ones(len(val), dtype=bool)),
            "force_band_edges_n": list(edges), "band_n": [m["n"] for m in per_band],
            "band_coverage": [m["interval_coverage"] for m in per_band]}
