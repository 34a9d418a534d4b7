"""Pooling models: one ONNX file that computes the members' linear opinion pool, calibrated."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
from scipy.special import logsumexp

from estimator.cli import main
from estimator.errors import EstimatorError
from estimator.inference.distribution import probabilities
from estimator.inference.infer import CompliancePredictor
from estimator.inference.inputs import Variant
from estimator.training.finetune import fine_tune
from estimator.training.pool import pool_models
from estimator.training.recipe import TrainConfig
from estimator.training.splits import load_split_data
from estimator.training.train import train_model


@pytest.fixture(scope="module")
def other_seed(trained_model, synthetic_dataset, tmp_path_factory):
    """The shared test model's recipe with another seed."""
    variant = CompliancePredictor(trained_model).variant
    out = tmp_path_factory.mktemp("other_seed")
    train_model(synthetic_dataset, out, variant=variant, config=TrainConfig(epochs=4, patience=4, batch_size=8, seed=2),
                progress=False)
    return out


def test_the_pooled_model_computes_the_members_linear_pool(trained_model, other_seed, synthetic_dataset, tmp_path):
    meta = pool_models([trained_model, other_seed], synthetic_dataset, tmp_path / "pooled")
    members = [CompliancePredictor(d) for d in (trained_model, other_seed)]
    pooled = CompliancePredictor(tmp_path / "pooled")
    val = load_split_data(synthetic_dataset, pooled.variant, ("val",))["val"].live()
    expected = logsumexp(np.stack([np.log(probabilities(m.predict_logits(val.inputs), temperature=m.metadata.temperature))
                                   for m in members]), axis=0) - np.log(2)
    assert np.allclose(pooled.predict_logits(val.inputs), expected, atol=1e-4)
    assert [m["dir"] for m in meta["ensemble"]["members"]] == [str(trained_model), str(other_seed)]
    assert [m["training"]["seed"] for m in meta["ensemble"]["members"]] == [1, 2] and "training" not in meta
    assert meta["calibration"]["n"] == len(val) and "recalibrated" not in meta
    assert json.loads((tmp_path / "pooled" / "metadata.json").read_text()) == meta


@pytest.mark.slow
def test_models_that_cannot_be_pooled_are_refused(trained_model, other_seed, synthetic_dataset, tmp_path):
    with pytest.raises(EstimatorError, match="at least two"):
        pool_models([trained_model], synthetic_dataset, tmp_path / "one")
    variant = CompliancePredictor(trained_model).variant
    cnn = tmp_path / "cnn"
    train_model(synthetic_dataset, cnn, variant=Variant.parse("depth+fw", n_frames=variant.n_frames,
                                                                size_px=variant.size_px),
                config=TrainConfig(epochs=1, patience=1, batch_size=8, seed=0), progress=False)
    with pytest.raises(EstimatorError, match=r"--model .*cnn: reads depth\+fw \(3 frames.*first --model .* reads "
                                             r"depth\+fw\+analytical \(") as refused:
        pool_models([trained_model, cnn], synthetic_dataset, tmp_path / "mixed")
    assert "Variant(" not in str(refused.value)
    smoothed = tmp_path / "smoothed"
    shutil.copytree(other_seed, smoothed)
    meta = json.loads((smoothed / "metadata.json").read_text())
    meta["data"]["calibration_smoothing_px"] = [2.0]
    (smoothed / "metadata.json").write_text(json.dumps(meta))
    with pytest.raises(EstimatorError, match="smoothing by 2 px"):
        pool_models([trained_model, smoothed], synthetic_dataset, tmp_path / "unlike")
    pool_models([trained_model, other_seed], synthetic_dataset, tmp_path / "pooled")
    with pytest.raises(EstimatorError, match="pooled again"):
        pool_models([tmp_path / "pooled", trained_model], synthetic_dataset, tmp_path / "twice")
    assert not any((tmp_path / name).exists() for name in ("one", "mixed", "unlike", "twice"))


@pytest.mark.slow
def test_a_pooled_model_fine_tunes_as_one_network(trained_model, other_seed, synthetic, synthetic_dataset, tmp_path):
    pool_models([trained_model, other_seed], synthetic_dataset, tmp_path / "pooled")
    data = synthetic.write_dataset(tmp_path / "d", seed=3)
    meta = fine_tune(tmp_path / "pooled", data, tmp_path / "tuned", config=TrainConfig(epochs=2, batch_size=8, lr=2e-3),
                     progress=False)
    assert meta["ensemble"] == json.loads((tmp_path / "pooled" / "metadata.json").read_text())["ensemble"]
    before, after = CompliancePredictor(tmp_path / "pooled"), CompliancePredictor(tmp_path / "tuned")
    inputs = load_split_data(data, before.variant, ("val",))["val"].inputs
    assert not np.allclose(before.predict_logits(inputs), after.predict_logits(inputs), atol=1e-3)


def test_models_trained_on_another_split_of_objects_are_not_pooled(trained_model, other_seed, synthetic_dataset,
                                                                    tmp_path):
    # A member that trained on the val objects would be calibrated on grasps it has seen: the pool's
    # validation figures would flatter it.
    elsewhere = tmp_path / "elsewhere"
    shutil.copytree(other_seed, elsewhere)
    meta = json.loads((elsewhere / "metadata.json").read_text())
    objects = meta["data"]["objects"]
    meta["data"]["objects"] = {**objects, "train": sorted([*objects["train"], *objects["val"]]), "val": []}
    (elsewhere / "metadata.json").write_text(json.dumps(meta))
    with pytest.raises(EstimatorError, match="another split of objects"):
        pool_models([trained_model, elsewhere], synthetic_dataset, tmp_path / "pooled")
    assert not (tmp_path / "pooled").exists()


def test_a_dataset_with_one_val_grasp_is_refused_before_any_export(trained_model, other_seed, synthetic_dataset,
                                                                   tmp_path):
    data = tmp_path / "data"
    shutil.copytree(synthetic_dataset, data)
    kept = sorted((data / "val").rglob("*_a0.npz"))[0]  # one grasp's live sample; its augmentations go too
    for path in (data / "val").rglob("*.npz"):
        if path != kept:
            path.unlink()
    with pytest.raises(EstimatorError, match="1 val samples; pooling needs at least 2"):
        pool_models([trained_model, other_seed], data, tmp_path / "pooled")
    assert not (tmp_path / "pooled").exists()


def test_a_model_given_twice_is_refused_however_spelled(tmp_path, capsys):
    model = tmp_path / "model"
    model.mkdir()
    (tmp_path / "other").mkdir()
    out = tmp_path / "pooled"
    assert main(["pool", "--model", str(model), "--model", str(tmp_path / "other" / ".." / "model"),
                 "--data", str(tmp_path / "data"), "--out", str(out)]) == 2
    assert f"model {model.resolve()}: given more than once" in capsys.readouterr().err
    assert not out.exists()


@pytest.mark.slow
def test_the_command_pools_models(trained_model, other_seed, synthetic_dataset, tmp_path, capsys):
    out = tmp_path / "pooled"
    assert main(["pool", "--model", str(trained_model), "--model", str(other_seed), "--data", str(synthetic_dataset),
                 "--out", str(out), "--json"]) == 0
    printed = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert printed["out"] == str(out) and printed["members"] == 2 and printed["calibration"]["n"] > 0
    assert {p.name for p in out.iterdir()} == {"model.onnx", "metadata.json"}


def test_a_full_disk_while_pooling_names_the_folder(trained_model, other_seed, synthetic_dataset, tmp_path, monkeypatch):
    import errno

    from estimator.training import pool as pool_module

    def full(*args, **kwargs):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(pool_module, "export_onnx", full)
    with pytest.raises(EstimatorError, match="cannot write the model into .*pooled: No space left on device"):
        pool_models([trained_model, other_seed], synthetic_dataset, tmp_path / "pooled")
    assert not (tmp_path / "pooled").exists() and not list(tmp_path.glob(".*"))  # nothing half-made left


def test_a_full_disk_while_the_pool_is_recalibrated_names_out_not_the_hidden_build(
        trained_model, other_seed, synthetic_dataset, tmp_path, monkeypatch):
    import errno
    import pathlib

    write_text = pathlib.Path.write_text
    calls = []

    def filling(self, *args, **kwargs):
        calls.append(self)
        if len(calls) >= 2:  # the pool's own metadata is written; recalibrate's then meets a full disk
            raise OSError(errno.ENOSPC, "No space left on device")
        return write_text(self, *args, **kwargs)

    monkeypatch.setattr(pathlib.Path, "write_text", filling)
    out = tmp_path / "pooled"
    with pytest.raises(EstimatorError) as raised:
        pool_models([trained_model, other_seed], synthetic_dataset, out)
    assert str(raised.value).startswith(f"cannot write the model into {out}: No space left on device")
    assert not out.exists() and not list(tmp_path.glob(".*"))
