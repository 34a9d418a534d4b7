"""Fine-tuning's data, refusals and record: what is replayed, what is refused, what the metadata says."""

from __future__ import annotations

import json
import math
import shutil

import numpy as np
import pytest
import torch

from estimator.errors import EstimatorError
from estimator.training import finetune as finetune_module
from estimator.training.finetune import _joined, _objects_after, fine_tune
from estimator.training.recipe import TrainConfig
from estimator.training.samples import load_sample, sample_paths
from estimator.training.splits import SplitData

ONE_EPOCH = TrainConfig(epochs=1, batch_size=8, lr=1e-3, seed=0)


def _of(synthetic, out, only, *, keep=None):
    """A dataset of synthetic grasps of the objects in ``only`` (its first ``keep`` samples when given)."""
    source = synthetic.write_dataset(out.with_name(out.name + "_all"), seed=3)
    kept = 0
    for path in sample_paths(source):
        if load_sample(path).object_name in only and (keep is None or kept < keep):
            target = out / path.relative_to(source)
            target.parent.mkdir(parents=True, exist_ok=True)
            shutil.copy(path, target)
            kept += 1
    for name in ("dataset.json", "split.json"):
        shutil.copy(source / name, out / name)
    return out


def _split(dataset):
    return json.loads((dataset / "split.json").read_text())


def test_joining_skips_empty_parts_and_keeps_the_others_in_order():
    a = SplitData({"x": np.arange(2.0)[:, None]}, np.array([1.0, 2.0]), [{"i": 0}, {"i": 1}])
    b = SplitData({"x": np.arange(3.0)[:, None] + 10}, np.array([3.0, 4.0, 5.0]), [{"i": 2}, {"i": 3}, {"i": 4}])
    empty = SplitData({}, np.zeros(0, np.float32), [])
    joined = _joined([empty, a, empty, b])
    assert list(joined.inputs) == ["x"] and joined.inputs["x"][:, 0].tolist() == [0.0, 1.0, 10.0, 11.0, 12.0]
    assert joined.label.tolist() == [1.0, 2.0, 3.0, 4.0, 5.0] and [r["i"] for r in joined.rows] == [0, 1, 2, 3, 4]
    assert len(_joined([empty])) == 0


def test_the_fine_tuning_objects_move_to_train_from_every_other_split():
    objects = _objects_after({"train": ["a"], "val": ["b", "c"], "test": ["d"]}, {"c", "d", "e"})
    assert objects == {"train": ["a", "c", "d", "e"], "val": ["b"], "test": []}


def test_a_replay_leaving_no_val_object_to_recalibrate_on_is_refused_before_training(
        trained_model, synthetic, synthetic_dataset, tmp_path):
    data = _of(synthetic, tmp_path / "d", set(_split(synthetic_dataset)["val"]))  # every val object trains
    with pytest.raises(EstimatorError, match=r": \d+ train and 0 val samples to replay and recalibrate on; both are needed"):
        fine_tune(trained_model, data, tmp_path / "out", config=ONE_EPOCH, replay=synthetic_dataset, progress=False)
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("ratio", [math.inf, math.nan, -1.0])
def test_a_replay_ratio_that_is_not_finite_and_positive_is_refused_naming_it(
        ratio, trained_model, synthetic, synthetic_dataset, tmp_path):
    data = _of(synthetic, tmp_path / "d", {_split(synthetic_dataset)["train"][0]})
    with pytest.raises(EstimatorError, match=r"^replay_ratio .*: expected a finite value > 0$"):
        fine_tune(trained_model, data, tmp_path / "out", config=ONE_EPOCH, replay=synthetic_dataset,
                  replay_ratio=ratio, progress=False)
    assert not (tmp_path / "out").exists()


def test_a_dataset_of_one_sample_is_refused_naming_the_count(trained_model, synthetic, synthetic_dataset, tmp_path):
    data = _of(synthetic, tmp_path / "d", {_split(synthetic_dataset)["train"][0]}, keep=1)
    with pytest.raises(EstimatorError, match=r": 1 samples; fine-tuning needs at least 2$"):
        fine_tune(trained_model, data, tmp_path / "out", config=ONE_EPOCH, progress=False)
    assert not (tmp_path / "out").exists()


@pytest.mark.slow
def test_each_epoch_replays_distinct_samples_and_the_rate_decays_over_the_epochs(
        trained_model, synthetic, synthetic_dataset, tmp_path, monkeypatch):
    data = _of(synthetic, tmp_path / "d", set(_split(synthetic_dataset)["train"]))
    drawn, schedules = [], []
    real = finetune_module.train_epoch
    monkeypatch.setattr(finetune_module, "train_epoch",
                        lambda model, epoch_data, *args: drawn.append([r["path"] for r in epoch_data.rows])
                        or real(model, epoch_data, *args))

    class Spy(torch.optim.lr_scheduler.CosineAnnealingLR):
        def __init__(self, optimiser, T_max):  # noqa: N803 - torch's name
            schedules.append({"T_max": T_max, "steps": 0})
            super().__init__(optimiser, T_max=T_max)

        def step(self, *args, **kwargs):
            if schedules:
                schedules[-1]["steps"] += 1
            return super().step(*args, **kwargs)

    monkeypatch.setattr(torch.optim.lr_scheduler, "CosineAnnealingLR", Spy)
    # Ratio 4: more replayed samples asked for than the replay's train split holds, so all of them are drawn.
    meta = fine_tune(trained_model, data, tmp_path / "out", config=TrainConfig(epochs=2, batch_size=8, lr=1e-4),
                     replay=synthetic_dataset, replay_ratio=4, progress=False)
    new = meta["fine_tuning"]["samples"]
    replayable = len(sample_paths(synthetic_dataset / "train"))
    assert [len(paths) for paths in drawn] == [new + replayable] * 2
    assert all(len(set(paths)) == len(paths) for paths in drawn)  # drawn without replacement
    assert schedules == [{"T_max": 2, "steps": 1 + 2}]  # torch's initial step, then one per epoch


def test_the_record_counts_every_sample_and_drops_the_base_models_figures(
        trained_model, synthetic, synthetic_dataset, tmp_path):
    data = _of(synthetic, tmp_path / "d", set(_split(synthetic_dataset)["train"][:2]))
    meta = fine_tune(trained_model, data, tmp_path / "out", config=ONE_EPOCH, progress=False)
    base = json.loads((trained_model / "metadata.json").read_text())
    assert base["metrics"] and meta["metrics"] == {}  # the base's figures describe another network
    tuned = meta["fine_tuning"]
    assert tuned["samples"] == len(sample_paths(data)) > len(tuned["objects"]) == 2
    assert tuned["config"] == {**ONE_EPOCH.__dict__, "patience": None}
    assert tuned["split_of_data"] == {k: sorted(v) for k, v in _split(data).items() if k in ("train", "val", "test")}


@pytest.mark.slow
def test_the_same_seed_fine_tunes_the_same_network(trained_model, synthetic, synthetic_dataset, tmp_path):
    data = _of(synthetic, tmp_path / "d", set(_split(synthetic_dataset)["train"][:2]))
    runs = [fine_tune(trained_model, data, tmp_path / name, config=ONE_EPOCH, progress=False)["fine_tuning"]
            for name in ("one", "two")]
    assert runs[0]["history"] == runs[1]["history"]
