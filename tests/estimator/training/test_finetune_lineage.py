"""What a fine-tuned model's metadata says of where it came from: true, complete and readable anywhere."""

from __future__ import annotations

import json
import os
import shutil

import pytest

from estimator.errors import EstimatorError
from estimator.inference.infer import CompliancePredictor
from estimator.training.finetune import _lineage, fine_tune
from estimator.training.recalibrate import fine_tuned_objects, recalibrate
from estimator.training.recipe import TrainConfig
from estimator.training.samples import load_sample, sample_paths
from estimator.training.splits import load_split_data

ONE_EPOCH = TrainConfig(epochs=1, batch_size=8, lr=1e-3, seed=0)


def _of(synthetic, out, only):
    """A dataset of the synthetic grasps of the objects in ``only`` (a few labelled grasps of a rig)."""
    source = synthetic.write_dataset(out.with_name(out.name + "_all"), seed=3)
    for path in sample_paths(source):
        if load_sample(path).object_name in only:
            target = out / path.relative_to(source)
            target.parent.mkdir(parents=True, exist_ok=True)
            shutil.copy(path, target)
    for name in ("dataset.json", "split.json"):
        shutil.copy(source / name, out / name)
    return out


def _split(dataset):
    return json.loads((dataset / "split.json").read_text())


def test_a_replay_whose_val_objects_the_base_trained_on_is_refused_before_training(
        trained_model, synthetic, synthetic_dataset, tmp_path):
    # The base model's own training objects, one of them split into val: calibrating on it would
    # describe intervals on an object the network has seen.
    replay = shutil.copytree(synthetic_dataset, tmp_path / "replay")
    split = _split(replay)
    moved, kept = split["train"][:2]
    (replay / "train" / moved).rename(replay / "val" / moved)
    split["train"].remove(moved)
    split["val"].append(moved)
    (replay / "split.json").write_text(json.dumps(split))
    data = _of(synthetic, tmp_path / "d", {kept})
    with pytest.raises(EstimatorError, match=rf"replay: val or test objects the model trained on \({moved}\)"):
        fine_tune(trained_model, data, tmp_path / "out", config=ONE_EPOCH, replay=replay, progress=False)
    assert not (tmp_path / "out").exists()


def test_the_metadata_says_what_was_done_with_paths_that_hold_from_anywhere(
        trained_model, synthetic, synthetic_dataset, tmp_path, monkeypatch):
    recalibrate(trained_model, synthetic_dataset, out_dir=tmp_path / "base")  # a base with a `recalibrated` record
    _of(synthetic, tmp_path / "d", {_split(synthetic_dataset)["train"][0]})
    monkeypatch.chdir(tmp_path)
    replay = os.path.relpath(synthetic_dataset, tmp_path)
    meta = fine_tune("base", "d", "out", config=ONE_EPOCH, replay=replay, progress=False)
    # The calibration was refitted on the replay's val objects: the base's record of its own is gone.
    assert "recalibrated" not in meta
    assert meta["calibration"]["chosen_on"] == f"val of {synthetic_dataset.resolve()}"
    tuned = meta["fine_tuning"]
    assert tuned["base"] == str((tmp_path / "base").resolve()) and tuned["data"] == str((tmp_path / "d").resolve())
    assert tuned["replay"]["data"] == str(synthetic_dataset.resolve())
    assert tuned["config"]["patience"] is None  # every epoch ran: no early stopping
    assert json.loads((tmp_path / "out" / "metadata.json").read_text()) == meta


def test_a_model_fine_tuned_twice_names_every_object_either_step_trained_on(
        trained_model, synthetic, synthetic_dataset, tmp_path):
    split = _split(synthetic_dataset)
    first, second = split["val"][0], split["test"][0]
    fine_tune(trained_model, _of(synthetic, tmp_path / "d1", {first}), tmp_path / "one", config=ONE_EPOCH,
              progress=False)
    meta = fine_tune(tmp_path / "one", _of(synthetic, tmp_path / "d2", {second}), tmp_path / "two",
                     config=ONE_EPOCH, replay=synthetic_dataset, progress=False)
    tuned = meta["fine_tuning"]
    assert tuned["objects"] == [second] and [step["objects"] for step in tuned["earlier"]] == [[first]]
    assert tuned["earlier"][0]["base"] == str(trained_model.resolve())
    # The replay's val objects the first step trained on are not calibrated on either.
    val = load_split_data(synthetic_dataset, CompliancePredictor(trained_model).variant, ("val",))["val"].live()
    assert meta["calibration"]["n"] == sum(r["object"] != first for r in val.rows)
    recalibrated = recalibrate(tmp_path / "two", synthetic_dataset, out_dir=tmp_path / "re")
    assert recalibrated["recalibrated"]["left_out"] == sorted([first, second])


def test_a_third_fine_tuning_keeps_every_earlier_step():
    # From the third step on, the first step's objects must stay in the lineage, or `evaluate --unseen-by`
    # and recalibrate would count them unseen.
    base = {"fine_tuning": {"objects": ["b"], "data": "/d2", "earlier": [{"objects": ["a"], "data": "/d1"}]}}
    earlier = _lineage(base)
    assert earlier == [{"objects": ["a"], "data": "/d1"}, {"objects": ["b"], "data": "/d2"}]
    assert fine_tuned_objects({"fine_tuning": {"objects": ["c"], "earlier": earlier}}) == {"a", "b", "c"}


def test_replay_recalibrates_without_the_val_objects_this_fine_tuning_trains_on(
        trained_model, synthetic, synthetic_dataset, tmp_path):
    tuned_on = _split(synthetic_dataset)["val"][0]
    meta = fine_tune(trained_model, _of(synthetic, tmp_path / "d", {tuned_on}), tmp_path / "out", config=ONE_EPOCH,
                     replay=synthetic_dataset, progress=False)
    val = load_split_data(synthetic_dataset, CompliancePredictor(trained_model).variant, ("val",))["val"].live()
    assert 0 < meta["calibration"]["n"] == sum(r["object"] != tuned_on for r in val.rows) < len(val)
