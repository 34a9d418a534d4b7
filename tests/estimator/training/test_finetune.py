"""Fine-tuning: the network rebuilt from ONNX, adapted to a few grasps, honest about what it saw."""

from __future__ import annotations

import json
import shutil
from dataclasses import replace

import numpy as np
import pytest

from estimator.cli import main
from estimator.errors import EstimatorError, ModelError
from estimator.inference.distribution import CENSOR_PA, probabilities, quantile
from estimator.inference.infer import CompliancePredictor, default_model_dir
from estimator.inference.inputs import Variant
from estimator.training import finetune as finetune_module
from estimator.training.export import network_from_onnx
from estimator.training.finetune import check_by_object, fine_tune
from estimator.training.recipe import TrainConfig
from estimator.training.samples import load_sample, sample_paths, save_sample
from estimator.training.splits import load_split_data
from teleop.settings import default_settings_path, load_settings

QUICK = TrainConfig(epochs=12, batch_size=8, lr=2e-3, seed=0)


def _variant(trained_model) -> Variant:
    return CompliancePredictor(trained_model).variant


def _relabelled(source, out, factor: float, only=None):
    """A copy of dataset ``source`` whose labels are ``factor`` times the originals (a rig that reads
    differently), of the objects in ``only`` (all when None)."""
    for path in sample_paths(source):
        sample = load_sample(path)
        if only is not None and sample.object_name not in only:
            continue
        target = out / path.relative_to(source)
        target.parent.mkdir(parents=True, exist_ok=True)
        save_sample(replace(sample, label_modulus_pa=sample.label_modulus_pa * factor), target)
    for name in ("dataset.json", "split.json"):
        (out / name).write_text((source / name).read_text())
    return out


def _mean_error_decades(model_dir, data_dir, splits=("train", "val", "test")) -> float:
    """Mean |median - label| (decades) over the samples of ``splits`` labelled below the censoring
    modulus (the rigid labels are censored there, so a tenfold label says nothing new about them)."""
    predictor = CompliancePredictor(model_dir)
    errors = []
    for name, part in load_split_data(data_dir, predictor.variant).items():
        if name not in splits:
            continue
        keep = part.label < np.log10(CENSOR_PA)
        if keep.any():
            probs = probabilities(predictor.predict_logits(part.inputs))[keep]
            errors.append(np.abs(quantile(probs, 0.5) - part.label[keep]))
    return float(np.mean(np.concatenate(errors)))


@pytest.mark.slow
def test_the_network_rebuilt_from_onnx_computes_what_the_file_does(trained_model, synthetic_dataset):
    variant = _variant(trained_model)
    batch = load_split_data(synthetic_dataset, variant)["val"].inputs
    model = network_from_onnx(trained_model / "model.onnx", variant, check=batch)
    assert not model.training
    other = Variant.parse("depth+fw", n_frames=variant.n_frames, size_px=variant.size_px, window_m=variant.window_m)
    with pytest.raises(ModelError, match="another variant"):  # the file has the analytical tower
        network_from_onnx(trained_model / "model.onnx", other, check={n: batch[n] for n in other.input_shapes})


@pytest.mark.slow
def test_fine_tuning_moves_the_model_towards_the_new_rigs_labels(trained_model, synthetic, tmp_path):
    new_rig = _relabelled(synthetic.write_dataset(tmp_path / "d", seed=3), tmp_path / "new_rig", factor=10.0)
    before = _mean_error_decades(trained_model, new_rig)
    meta = fine_tune(trained_model, new_rig, tmp_path / "tuned", config=QUICK, progress=False)
    after = _mean_error_decades(tmp_path / "tuned", new_rig)
    assert after < 0.7 * before  # labels a decade off what the model learned: it follows them
    tuned = meta["fine_tuning"]
    assert tuned["objects"] == sorted(synthetic.OBJECTS) and tuned["grasps"] == 2 * len(synthetic.OBJECTS)
    assert len(tuned["history"]) == QUICK.epochs and tuned["base"] == str(trained_model)
    # Every fine-tuning object counts as trained on, so `evaluate --unseen-by` keeps it out.
    assert meta["data"]["objects"]["train"] == sorted(synthetic.OBJECTS)
    assert meta["data"]["objects"]["val"] == meta["data"]["objects"]["test"] == []
    base = json.loads((trained_model / "metadata.json").read_text())
    assert meta["calibration"] == base["calibration"] and meta["variant"] == base["variant"]
    assert CompliancePredictor(tmp_path / "tuned").metadata.interval_level == 0.9


@pytest.mark.slow
def test_replay_keeps_what_the_model_knew_and_recalibrates(trained_model, synthetic, synthetic_dataset, tmp_path):
    trained_on = json.loads((trained_model / "metadata.json").read_text())["data"]["objects"]["train"]
    new_rig = _relabelled(synthetic.write_dataset(tmp_path / "d", seed=3), tmp_path / "new_rig", factor=10.0,
                          only=trained_on)
    plain = fine_tune(trained_model, new_rig, tmp_path / "plain", config=QUICK, progress=False)
    meta = fine_tune(trained_model, new_rig, tmp_path / "replayed", config=QUICK, replay=synthetic_dataset,
                     replay_ratio=4, progress=False)
    # Objects the base model held out, under their own labels: rehearsal forgets less of them.
    forgot = {name: _mean_error_decades(tmp_path / name, synthetic_dataset, splits=("val", "test"))
              for name in ("plain", "replayed")}
    assert forgot["replayed"] < forgot["plain"]
    assert _mean_error_decades(tmp_path / "replayed", new_rig) < _mean_error_decades(trained_model, new_rig)
    val = load_split_data(synthetic_dataset, _variant(trained_model))["val"].live()
    calibration = meta["calibration"]
    assert calibration["chosen_on"] == f"val of {synthetic_dataset}" and calibration["n"] == len(val)
    assert calibration != plain["calibration"] and 0.0 <= calibration["coverage"] <= 1.0
    assert meta["fine_tuning"]["replay"] == {"data": str(synthetic_dataset), "ratio": 4}
    assert list(CompliancePredictor(tmp_path / "replayed").metadata.interval_scales) == calibration["interval_scales"]


@pytest.mark.slow
def test_leaving_one_object_out_says_whether_fine_tuning_helps_on_unseen_objects(trained_model, synthetic, tmp_path):
    # A rig that reads every object a decade stiffer: what the other objects teach carries over.
    new_rig = _relabelled(synthetic.write_dataset(tmp_path / "d", seed=3), tmp_path / "new_rig", factor=10.0)
    check = check_by_object(trained_model, new_rig, settings=load_settings(), config=QUICK, progress=False)
    assert set(check["per_object"]) == set(synthetic.OBJECTS)
    assert check["base"]["n"] == check["fine_tuned"]["n"] == 2 * len(synthetic.OBJECTS)  # live samples only
    # Fine-tuned without it, each object's grasps are felt closer to the new rig's labels than before.
    assert check["fine_tuned"]["felt_log10_error"] < check["base"]["felt_log10_error"]
    for which in ("base", "fine_tuned"):  # two grasps of each object: the mean of the objects' figures
        per_object = [v[which] for v in check["per_object"].values()]
        assert check[which]["felt_log10_error"] == pytest.approx(np.mean(per_object))
    assert not list(tmp_path.glob("**/model.onnx"))  # nothing written
    one = _relabelled(new_rig, tmp_path / "one", factor=1.0, only={"foam_a"})
    with pytest.raises(EstimatorError, match="1 object"):
        check_by_object(trained_model, one, settings=load_settings(), config=QUICK, progress=False)


def test_a_replay_dataset_of_other_training_objects_is_refused(trained_model, synthetic, tmp_path):
    trained_on = json.loads((trained_model / "metadata.json").read_text())["data"]["objects"]["train"]
    data = synthetic.write_dataset(tmp_path / "d", seed=4)
    other = synthetic.write_dataset(tmp_path / "other", seed=5)
    split = json.loads((other / "split.json").read_text())
    assert set(split["train"]) != set(trained_on)  # seed 5 splits the objects otherwise
    with pytest.raises(EstimatorError, match="did not train on"):
        fine_tune(trained_model, data, tmp_path / "out", config=QUICK, replay=other, progress=False)
    with pytest.raises(EstimatorError, match="replay_ratio"):
        fine_tune(trained_model, data, tmp_path / "out", config=QUICK, replay=other, replay_ratio=0.0,
                  progress=False)
    assert not (tmp_path / "out").exists()


def test_a_replay_dataset_that_trains_on_an_object_the_base_model_held_out_is_refused(
        trained_model, synthetic_dataset, synthetic, tmp_path):
    # The base model's train objects plus one of its val objects: replay would rehearse a held-out object.
    replay = shutil.copytree(synthetic_dataset, tmp_path / "replay")
    split = json.loads((replay / "split.json").read_text())
    moved = split["val"][0]
    shutil.move(replay / "val" / moved, replay / "train" / moved)
    split["train"], split["val"] = sorted([*split["train"], moved]), [o for o in split["val"] if o != moved]
    (replay / "split.json").write_text(json.dumps(split))
    data = synthetic.write_dataset(tmp_path / "d", seed=3)
    with pytest.raises(EstimatorError, match=f"train objects the base model did not train on \\({moved}\\)"):
        fine_tune(trained_model, data, tmp_path / "out", config=TrainConfig(epochs=1, batch_size=8), replay=replay,
                  progress=False)
    assert not (tmp_path / "out").exists()


@pytest.mark.slow
def test_fine_tuning_at_a_negligible_rate_keeps_the_models_answers(trained_model, synthetic, tmp_path):
    # Batch norms stay frozen: their running statistics must not move to the few new grasps'.
    data = synthetic.write_dataset(tmp_path / "d", seed=3)
    fine_tune(trained_model, data, tmp_path / "tuned", config=TrainConfig(epochs=2, batch_size=8, lr=1e-12, seed=0),
              progress=False)
    base, tuned = CompliancePredictor(trained_model), CompliancePredictor(tmp_path / "tuned")
    inputs = load_split_data(data, base.variant)["val"].inputs
    assert np.max(np.abs(tuned.predict_logits(inputs) - base.predict_logits(inputs))) < 1e-3


@pytest.mark.slow
def test_every_epoch_replays_replay_ratio_samples_per_new_one(trained_model, synthetic, synthetic_dataset, tmp_path,
                                                              monkeypatch):
    variant = _variant(trained_model)
    trained_on = set(CompliancePredictor(trained_model).metadata.raw["data"]["objects"]["train"])
    # New grasps of the base model's train objects only, so that the replay's val objects stay in.
    data = synthetic.write_dataset(tmp_path / "d", seed=3)
    only = tmp_path / "only"
    for folder in data.glob("*/*"):
        if folder.is_dir() and folder.name in trained_on:
            shutil.copytree(folder, only / folder.relative_to(data))
    for name in ("dataset.json", "split.json"):
        shutil.copy(data / name, only / name)
    new = sum(len(part) for part in load_split_data(only, variant).values())
    replayable = len(load_split_data(synthetic_dataset, variant)["train"])
    sizes = []
    real = finetune_module.train_epoch
    monkeypatch.setattr(finetune_module, "train_epoch",
                        lambda model, epoch_data, *args: sizes.append(len(epoch_data)) or real(model, epoch_data, *args))
    ratio = 0.5
    fine_tune(trained_model, only, tmp_path / "tuned", config=TrainConfig(epochs=2, batch_size=8, lr=1e-4, seed=0),
              replay=synthetic_dataset, replay_ratio=ratio, progress=False)
    assert sizes == [new + min(replayable, round(ratio * new))] * 2


def test_a_dataset_that_does_not_fit_the_model_is_refused(trained_model, synthetic, tmp_path):
    data = synthetic.write_dataset(tmp_path / "d", seed=4)
    manifest = json.loads((data / "dataset.json").read_text())
    (data / "dataset.json").write_text(json.dumps({**manifest, "n_frames": 4}))
    with pytest.raises(EstimatorError, match="4 frames"):
        fine_tune(trained_model, data, tmp_path / "out", config=QUICK, progress=False)
    (data / "dataset.json").write_text(json.dumps({**manifest, "measurement_version": -1}))
    with pytest.raises(EstimatorError, match="rebuild the dataset"):
        fine_tune(trained_model, data, tmp_path / "out", config=QUICK, progress=False)
    (data / "dataset.json").write_text(json.dumps({**manifest, "depth_binning": 3}))
    with pytest.raises(EstimatorError, match="depth binned by 3"):
        fine_tune(trained_model, data, tmp_path / "out", config=QUICK, progress=False)
    (data / "dataset.json").write_text(json.dumps({**manifest, "calibration_smoothing_px": [2.0]}))
    with pytest.raises(EstimatorError, match="smoothing colours by 2 px.*from 0 px.*--smoothing-px 0"):
        fine_tune(trained_model, data, tmp_path / "out", config=QUICK, progress=False)
    (data / "dataset.json").write_text(json.dumps({**manifest, "window_m": [0.01, 0.02]}))
    with pytest.raises(EstimatorError, match="--window"):
        fine_tune(trained_model, data, tmp_path / "out", config=QUICK, progress=False)
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("command", [["fine-tune", "--model"], ["train", "--init"]])
def test_the_base_model_is_never_the_output(command, trained_model, synthetic, tmp_path, capsys):
    data = synthetic.write_dataset(tmp_path / "d", seed=5)
    before = {p.name: p.read_bytes() for p in trained_model.iterdir()}
    spelled_otherwise = trained_model.parent / ".." / trained_model.parent.name / trained_model.name
    assert main([*command, str(trained_model), "--data", str(data), "--out", str(spelled_otherwise),
                 "--epochs", "1"]) == 2
    assert "is the base model; write the fine-tuned one to another folder" in capsys.readouterr().err
    assert {p.name: p.read_bytes() for p in trained_model.iterdir()} == before


@pytest.mark.slow
@pytest.mark.parametrize("command", [["fine-tune", "--model"], ["train", "--init"]])
def test_the_command_fine_tunes_and_says_how_to_score_it(command, trained_model, synthetic, tmp_path, capsys):
    data = synthetic.write_dataset(tmp_path / "d", seed=5)
    assert main([*command, str(trained_model), "--data", str(data), "--out", str(tmp_path / "m"),
                 "--epochs", "2", "--json"]) == 0
    out, err = capsys.readouterr()
    summary = json.loads(out.strip().splitlines()[-1])
    assert "without --replay the model may forget" in err
    assert summary["out"] == str(tmp_path / "m") and summary["grasps"] == 2 * len(synthetic.OBJECTS)
    assert np.isfinite(summary["final_train_loss"])
    assert {p.name for p in (tmp_path / "m").iterdir()} == {"model.onnx", "metadata.json"}
    assert "check" not in summary
    # Either way fine-tuning's recipe (its learning rate and batch), for the epochs asked for.
    tuned = json.loads((tmp_path / "m" / "metadata.json").read_text())["fine_tuning"]
    assert tuned["base"] == str(trained_model) and tuned["replay"] is None
    assert (tuned["config"]["epochs"], tuned["config"]["lr"], tuned["config"]["batch_size"]) == (2, 3e-4, 16)
    assert len(tuned["history"]) == 2


@pytest.mark.slow
def test_the_command_checks_by_leaving_objects_out_when_asked(trained_model, synthetic, tmp_path, capsys):
    data = synthetic.write_dataset(tmp_path / "d", seed=5)
    args = ["fine-tune", "--model", str(trained_model), "--data", str(data), "--out", str(tmp_path / "m"),
            "--epochs", "1", "--check"]
    assert main([*args, "--json"]) == 0
    check = json.loads(capsys.readouterr().out.strip().splitlines()[-1])["check"]
    assert set(check["per_object"]) == set(synthetic.OBJECTS)
    assert {"felt_log10_error", "felt_within_2x", "dangerous_misses", "n"} <= set(check["fine_tuned"])
    assert main([*args, "--overwrite"]) == 0  # m holds the first run's model
    assert "leaving one object out, on 24 grasps: felt error" in capsys.readouterr().out


@pytest.mark.parametrize(("extra", "named"), [
    (["--patience", "3"], "--patience"),
    (["--settings", str(default_settings_path())], "--settings"),
    (["--variant", "depth"], "--variant depth"),
])
def test_train_with_init_refuses_what_fine_tuning_does_not_use(extra, named, tmp_path, capsys):
    # The shipped default reads depth+fw+analytical; each refusal comes before any data is read.
    args = ["train", "--init", str(default_model_dir()), "--data", str(tmp_path / "none"),
            "--out", str(tmp_path / "m"), *extra]
    assert main(args) == 2
    err = capsys.readouterr().err
    assert named in err and "error" in err
    assert not (tmp_path / "m").exists()


def test_replay_without_init_is_refused(tmp_path, capsys):
    assert main(["train", "--data", str(tmp_path / "none"), "--out", str(tmp_path / "m"),
                 "--replay", str(tmp_path)]) == 2
    assert "need --init MODEL_DIR" in capsys.readouterr().err


def test_train_with_init_takes_the_models_variant_spelled_in_any_order(tmp_path, capsys):
    # The shipped default reads depth+fw+analytical: another order of its parts is that variant, so the
    # refusal that follows is the missing dataset's, not --variant's.
    args = ["train", "--init", str(default_model_dir()), "--data", str(tmp_path / "none"),
            "--out", str(tmp_path / "m"), "--variant", "depth+analytical+fw"]
    assert main(args) == 2
    err = capsys.readouterr().err
    assert "--variant" not in err and str(tmp_path / "none") in err
    assert main([*args[:-1], "depth+fw+analytical+fw"]) == 2
    assert "+fw given more than once" in capsys.readouterr().err
    assert not (tmp_path / "m").exists()


def test_a_full_disk_while_fine_tuning_names_the_folder(trained_model, synthetic, tmp_path, monkeypatch):
    import errno

    from estimator.training import finetune as finetune_module

    def full(*args, **kwargs):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(finetune_module, "export_onnx", full)
    data = synthetic.write_dataset(tmp_path / "d", seed=3)
    with pytest.raises(EstimatorError, match="cannot write the model into .*tuned: No space left on device"):
        fine_tune(trained_model, data, tmp_path / "tuned", config=TrainConfig(epochs=1, batch_size=8, seed=0),
                  progress=False)


def test_the_checks_pooled_felt_figures_leave_out_grasps_shown_unknown():
    from estimator.training.finetune import _pooled
    from estimator.training.finetune_cli import check_text

    unknown = {"n": 3, "shown_unknown": 3, "felt_log10_error": None, "felt_within_2x": None, "dangerous_misses": 0}
    felt = [{"n": 2, "shown_unknown": 1, "felt_log10_error": 0.4, "felt_within_2x": 1.0, "dangerous_misses": 0},
            {"n": 3, "shown_unknown": 0, "felt_log10_error": 0.2, "felt_within_2x": 0.0, "dangerous_misses": 1}]
    pooled = _pooled([unknown, *felt])
    assert (pooled["n"], pooled["shown_unknown"], pooled["dangerous_misses"]) == (8, 4, 1)
    # Weighted by the grasps each figure is over (1 and 3), not by n.
    assert pooled["felt_log10_error"] == pytest.approx((0.4 * 1 + 0.2 * 3) / 4)
    assert pooled["felt_within_2x"] == pytest.approx(0.25)
    nothing_felt = _pooled([unknown, unknown])
    assert nothing_felt["felt_log10_error"] is None and nothing_felt["felt_within_2x"] is None
    text = check_text({"base": pooled, "fine_tuned": nothing_felt})
    assert "felt error 0.250 -> - (every grasp shown unknown) decade" in text
    assert "shown unknown 4 -> 6, left out of the felt figures" in text


def test_a_diverging_fine_tuning_stops_naming_lr_and_writes_nothing(trained_model, synthetic, tmp_path):
    data = synthetic.write_dataset(tmp_path / "d", seed=3)
    config = TrainConfig(epochs=2, batch_size=8, lr=1e6, seed=0)
    with pytest.raises(EstimatorError, match=r"^fine-tuning diverged: training loss \S+ at epoch \d \(--lr 1e\+06\): "
                                             "lower --lr$"):
        fine_tune(trained_model, data, tmp_path / "tuned", config=config, progress=False)
    assert not (tmp_path / "tuned").exists()


def test_fine_tuning_takes_a_seed_past_torchs_range(trained_model, synthetic, tmp_path):
    data = synthetic.write_dataset(tmp_path / "d", seed=3)
    meta = fine_tune(trained_model, data, tmp_path / "tuned", config=TrainConfig(epochs=1, batch_size=8, seed=2**64),
                     progress=False)
    assert meta["fine_tuning"]["config"]["seed"] == 2**64
