"""Recalibration without retraining, and calibration that scores what the estimator answers."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
from support.extras import estimator_without_torch

from estimator.cli import main
from estimator.errors import EstimatorError
from estimator.inference.distribution import CENSOR_PA, floor_log_weights, probabilities
from estimator.inference.infer import CompliancePredictor
from estimator.inference.inputs import analytical_floor
from estimator.training import recalibrate as recalibrate_module
from estimator.training.conformal import described
from estimator.training.recalibrate import cross_validate, recalibrate
from estimator.training.splits import load_split_data
from teleop.settings import load_settings


def test_calibration_scores_exactly_what_the_estimator_answers_on_any_gel(trained_model, synthetic_dataset):
    predictor = CompliancePredictor(trained_model)
    val = load_split_data(synthetic_dataset, predictor.variant, ("val",))["val"].live()
    logits = predictor.predict_logits(val.inputs)
    calibration = predictor.metadata.raw["calibration"]
    limit_pa = load_settings().resolution_limit_pa
    states = set()
    for gel_scale in (0.4, 1.0, 2.5):  # a stiffer gel, the reference one, a softer one
        floors = np.array([analytical_floor(r["estimates"], scale=gel_scale)[0] for r in val.rows])
        scored = described(logits, {**calibration, "limit_pa": limit_pa}, np.full(len(val), gel_scale),
                            val.peak_forces_n, floors)
        # As predict_distribution gives them to describe: floored at the analytical lower bounds.
        weights = floor_log_weights(floors, leak=predictor.metadata.floor_leak)
        for probs, said, force_n in zip(probabilities(logits, temperature=predictor.metadata.temperature,
                                                      log_weights=weights), scored, val.peak_forces_n, strict=True):
            assert predictor.describe(probs, limit_pa=limit_pa, peak_force_n=force_n, gel_scale=gel_scale) == said
            if said.state == "lower_bound":  # at the settings' limit, whatever the gel
                assert said.e_pa == pytest.approx(min(limit_pa, CENSOR_PA / gel_scale))
            states.add(said.state)
    assert "ok" in states and "lower_bound" in states


def _copy(model, tmp_path):
    return shutil.copytree(model, tmp_path / "model")


def test_recalibrating_on_the_models_own_data_reproduces_its_calibration(trained_model, synthetic_dataset,
                                                                         tmp_path):
    model = _copy(trained_model, tmp_path)
    before = json.loads((model / "metadata.json").read_text())
    meta = recalibrate(model, synthetic_dataset)
    after = meta["calibration"]
    val = load_split_data(synthetic_dataset, CompliancePredictor(model).variant, ("val",))["val"].live()
    # onnxruntime's logits are torch's to 1e-4: the same data give the same calibration.
    assert after["n"] == len(val) and after["p_rigids"] == before["calibration"]["p_rigids"]
    assert after["temperature"] == pytest.approx(before["calibration"]["temperature"], rel=1e-3)
    assert after["interval_scales"] == pytest.approx(before["calibration"]["interval_scales"], rel=1e-3)
    assert meta["recalibrated"]["previous"] == before["calibration"]
    assert meta["recalibrated"]["data"] == str(synthetic_dataset)
    assert set(meta["metrics"]) == {"val", "test"} and meta["metrics"]["val"]["objects"] > 0
    assert json.loads((model / "metadata.json").read_text()) == meta
    assert list(CompliancePredictor(model).metadata.interval_scales) == after["interval_scales"]


def test_a_dataset_whose_val_or_test_objects_the_model_trained_on_is_refused(trained_model, synthetic, tmp_path):
    other = synthetic.write_dataset(tmp_path / "other", seed=5)
    with pytest.raises(EstimatorError, match="trained on"):
        recalibrate(trained_model, other, out_dir=tmp_path / "out")
    assert not (tmp_path / "out").exists()


def test_the_command_writes_a_recalibrated_copy(trained_model, synthetic_dataset, tmp_path, capsys):
    out = tmp_path / "recalibrated"
    assert main(["recalibrate", "--model", str(trained_model), "--data", str(synthetic_dataset), "--out", str(out),
                 "--json"]) == 0
    printed = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert printed["out"] == str(out) and printed["calibration"]["n"] > 0
    assert (out / "model.onnx").read_bytes() == (trained_model / "model.onnx").read_bytes()
    assert json.loads((out / "metadata.json").read_text())["calibration"] == printed["calibration"]


def test_recalibrating_needs_no_torch(trained_model, synthetic_dataset, tmp_path):
    # It refits through onnxruntime: the 'train' extra is not needed.
    out = tmp_path / "recalibrated"
    result = estimator_without_torch("recalibrate", "--model", str(trained_model), "--data", str(synthetic_dataset),
                                     "--out", str(out), "--json")
    assert result.returncode == 0, result.stderr
    assert json.loads(result.stdout.strip().splitlines()[-1])["calibration"]["n"] > 0


def test_cross_validation_answers_each_object_under_a_calibration_fitted_without_it(trained_model, synthetic_dataset,
                                                                                    monkeypatch):
    calibrated_on, answered = [], []
    fit, score = recalibrate_module._fit_conformal_on, recalibrate_module.scored_rows

    def spy_fit(predictor, val, logits, settings):
        calibrated_on.append({r["object"] for r in val.rows})
        return fit(predictor, val, logits, settings)

    def spy_score(data, logits, method, calibration):
        answered.append({r["object"] for r in data.rows})
        return score(data, logits, method, calibration)

    monkeypatch.setattr(recalibrate_module, "_fit_conformal_on", spy_fit)
    monkeypatch.setattr(recalibrate_module, "scored_rows", spy_score)
    before = (trained_model / "metadata.json").read_bytes()
    result = cross_validate(trained_model, synthetic_dataset, folds=2)
    val = load_split_data(synthetic_dataset, CompliancePredictor(trained_model).variant, ("val",))["val"].live()
    objects = {r["object"] for r in val.rows}
    assert len(answered) == 2 and set().union(*answered) == objects and not answered[0] & answered[1]
    assert all(seen | mine == objects and not seen & mine for seen, mine in zip(calibrated_on, answered, strict=True))
    assert result["grasps"] == result["metrics"]["n"] == sum(result["band_n"]) == len(val)
    assert result["objects"] == len(objects) and 0 <= result["metrics"]["interval_coverage"] <= 1
    assert (trained_model / "metadata.json").read_bytes() == before  # writes nothing


def test_cross_validation_needs_two_folds_to_one_per_val_object(trained_model, synthetic_dataset):
    for folds in (1, 10_000):
        with pytest.raises(EstimatorError, match=f"--cross-validate FOLDS {folds}: expected 2 to"):
            cross_validate(trained_model, synthetic_dataset, folds=folds)


def test_too_many_folds_names_the_option_and_that_five_is_its_default(trained_model, synthetic_dataset):
    n_val = len(json.loads((synthetic_dataset / "split.json").read_text())["val"])
    assert n_val < 5
    with pytest.raises(EstimatorError, match=rf"--cross-validate FOLDS 5: expected 2 to {n_val} .*5 is the number "
                                             "--cross-validate takes without FOLDS"):
        cross_validate(trained_model, synthetic_dataset, folds=5)


def _as_fine_tuned(trained_model, tmp_path, moved):
    """A copy of the model whose metadata says fine-tuning trained it on ``moved`` (as fine-tune writes it)."""
    from estimator.training.finetune import _objects_after

    model = tmp_path / "tuned"
    shutil.copytree(trained_model, model)
    meta = json.loads((model / "metadata.json").read_text())
    meta["data"]["objects"] = _objects_after(meta["data"]["objects"], set(moved))
    meta["fine_tuning"] = {"base": str(trained_model), "data": "more-grasps", "objects": sorted(moved)}
    (model / "metadata.json").write_text(json.dumps(meta))
    return model


def test_a_fine_tuned_model_recalibrates_on_its_base_dataset_leaving_out_what_it_trained_on(
        trained_model, synthetic_dataset, tmp_path):
    split = json.loads((synthetic_dataset / "split.json").read_text())
    moved = [split["val"][0], split["test"][0]]
    model = _as_fine_tuned(trained_model, tmp_path, moved)
    meta = recalibrate(model, synthetic_dataset, out_dir=tmp_path / "out")
    assert meta["recalibrated"]["left_out"] == sorted(moved)
    assert meta["metrics"]["val"]["objects"] == len(split["val"]) - 1
    assert meta["metrics"]["test"]["objects"] == len(split["test"]) - 1
    assert cross_validate(model, synthetic_dataset, folds=2)["objects"] == len(split["val"]) - 1


def test_a_model_fine_tuned_twice_leaves_out_what_every_step_trained_on(trained_model, synthetic_dataset, tmp_path):
    split = json.loads((synthetic_dataset / "split.json").read_text())
    model = _as_fine_tuned(trained_model, tmp_path, [split["val"][0], split["test"][0]])
    meta = json.loads((model / "metadata.json").read_text())
    # The second step's own record names its objects; the first step's, under `earlier`, the other.
    meta["fine_tuning"] = {"base": "once-tuned", "data": "more-grasps", "objects": [split["test"][0]],
                           "earlier": [{"base": str(trained_model), "data": "first-grasps",
                                        "objects": [split["val"][0]]}]}
    (model / "metadata.json").write_text(json.dumps(meta))
    meta = recalibrate(model, synthetic_dataset, out_dir=tmp_path / "out")
    assert meta["recalibrated"]["left_out"] == sorted([split["val"][0], split["test"][0]])
    assert meta["metrics"]["val"]["objects"] == len(split["val"]) - 1


def test_a_fine_tuned_model_on_a_dataset_it_did_not_come_from_names_the_fine_tuning(
        trained_model, synthetic, tmp_path):
    other = synthetic.write_dataset(tmp_path / "other", seed=5)
    model = _as_fine_tuned(trained_model, tmp_path, [])
    with pytest.raises(EstimatorError, match="the model was fine-tuned .*more-grasps.*base model"):
        recalibrate(model, other, out_dir=tmp_path / "out")
    assert not (tmp_path / "out").exists()


def test_the_command_cross_validates_without_writing(trained_model, synthetic_dataset, tmp_path, capsys):
    before = (trained_model / "metadata.json").read_bytes()
    args = ["recalibrate", "--model", str(trained_model), "--data", str(synthetic_dataset), "--cross-validate", "2"]
    assert main(args) == 0
    shown = capsys.readouterr().out
    assert "2-fold cross-validation by object" in shown and "dangerous" in shown and "coverage" in shown
    assert main([*args, "--json"]) == 0
    printed = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert printed == json.loads(json.dumps(cross_validate(trained_model, synthetic_dataset, folds=2)))
    assert main([*args, "--out", str(tmp_path / "x")]) != 0
    assert "--out" in capsys.readouterr().err and not (tmp_path / "x").exists()
    assert (trained_model / "metadata.json").read_bytes() == before
