"""Recalibration's batches, refusals, record and cross-validation folds."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
from support.rig_settings import rig_settings

from estimator.errors import EstimatorError
from estimator.inference.infer import CompliancePredictor
from estimator.training import recalibrate as recalibrate_module
from estimator.training.recalibrate import cross_validate, recalibrate
from estimator.training.splits import load_split_data
from teleop.settings import load_settings


def _split(dataset):
    return json.loads((dataset / "split.json").read_text())


def _as_fine_tuned(trained_model, tmp_path, moved):
    """A copy of the model whose metadata says fine-tuning trained it on ``moved`` (as fine-tune writes it)."""
    from estimator.training.finetune import _objects_after

    model = shutil.copytree(trained_model, tmp_path / "tuned")
    meta = json.loads((model / "metadata.json").read_text())
    meta["data"]["objects"] = _objects_after(meta["data"]["objects"], set(moved))
    meta["fine_tuning"] = {"base": str(trained_model), "data": "more-grasps", "objects": sorted(moved)}
    (model / "metadata.json").write_text(json.dumps(meta))
    return model


def test_logits_in_batches_answer_every_sample(trained_model, synthetic_dataset, monkeypatch):
    predictor = CompliancePredictor(trained_model)
    val = load_split_data(synthetic_dataset, predictor.variant, ("val",))["val"]
    five = val.subset(np.arange(5))
    monkeypatch.setattr(recalibrate_module, "_BATCH", 2)
    np.testing.assert_allclose(recalibrate_module._logits(predictor, five), predictor.predict_logits(five.inputs),
                               atol=1e-6)


def test_a_model_fine_tuned_on_every_val_object_has_none_to_calibrate_on_and_says_why(
        trained_model, synthetic_dataset, tmp_path):
    val_objects = _split(synthetic_dataset)["val"]
    model = _as_fine_tuned(trained_model, tmp_path, val_objects)
    with pytest.raises(EstimatorError, match=rf"no val samples to calibrate on once the objects its fine-tuning "
                                             rf"trained on \({', '.join(sorted(val_objects))}\) are left out$"):
        recalibrate(model, synthetic_dataset, out_dir=tmp_path / "out")
    assert not (tmp_path / "out").exists()


def test_a_first_calibration_keeps_no_record_of_replacing_one(trained_model, synthetic_dataset, tmp_path):
    meta = recalibrate(trained_model, synthetic_dataset, out_dir=tmp_path / "out", record=False)
    assert "recalibrated" not in meta
    assert "recalibrated" not in json.loads((tmp_path / "out" / "metadata.json").read_text())


def test_the_settings_resolution_limit_is_the_one_calibrated_at(trained_model, synthetic_dataset, tmp_path):
    settings = load_settings(rig_settings(tmp_path, {"sensors.left.depth_resolution_m": 6e-5}))
    assert settings.resolution_limit_pa != load_settings().resolution_limit_pa
    meta = recalibrate(trained_model, synthetic_dataset, out_dir=tmp_path / "out", settings=settings)
    assert meta["calibration"]["limit_pa"] == pytest.approx(settings.resolution_limit_pa)
    assert meta["recalibrated"]["settings"] == str(settings.source)


def _folds_answered(trained_model, synthetic_dataset, monkeypatch, **kwargs):
    answered = []
    score = recalibrate_module.scored_rows
    monkeypatch.setattr(recalibrate_module, "scored_rows", lambda data, *args: answered.append(
        frozenset(r["object"] for r in data.rows)) or score(data, *args))
    result = cross_validate(trained_model, synthetic_dataset, **kwargs)
    monkeypatch.setattr(recalibrate_module, "scored_rows", score)
    return answered, result


def test_as_many_folds_as_val_objects_answer_one_object_each(trained_model, synthetic_dataset, monkeypatch):
    n_val = len(_split(synthetic_dataset)["val"])
    answered, result = _folds_answered(trained_model, synthetic_dataset, monkeypatch, folds=n_val)
    assert sorted(len(objects) for objects in answered) == [1] * n_val and len(set(answered)) == n_val
    assert result["folds"] == result["objects"] == n_val


def test_the_seed_deals_the_val_objects_into_folds(trained_model, synthetic_dataset, monkeypatch):
    assert len(_split(synthetic_dataset)["val"]) >= 3  # two folds of them can be dealt more than one way
    dealt = set()
    for seed in range(6):
        answered, result = _folds_answered(trained_model, synthetic_dataset, monkeypatch, folds=2, seed=seed)
        assert result["seed"] == seed
        dealt.add(frozenset(answered))
    assert len(dealt) > 1


def test_the_bands_coverage_adds_up_to_the_whole(trained_model, synthetic_dataset):
    result = cross_validate(trained_model, synthetic_dataset, folds=2)
    covered = [(c, n) for c, n in zip(result["band_coverage"], result["band_n"], strict=True) if n]
    assert all(0.0 <= c <= 1.0 for c, _ in covered)
    assert sum(c * n for c, n in covered) / sum(n for _, n in covered) == pytest.approx(
        result["metrics"]["interval_coverage"])
