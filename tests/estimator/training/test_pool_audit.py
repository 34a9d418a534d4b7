"""The pooled network, pinned by a mutation audit on untrained members (no training): the linear
opinion pool of the members' own temperature-scaled distributions."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
import torch
from scipy.special import log_softmax, logsumexp

from estimator.errors import EstimatorError
from estimator.inference.inputs import Variant
from estimator.training.model import ComplianceNet
from estimator.training.pool import PooledNet, pool_models

VARIANT = Variant.parse("depth+fw", n_frames=3, size_px=(16, 22))
TEMPERATURES = (0.5, 2.0, 1.3)


def _members(n: int) -> list[ComplianceNet]:
    """``n`` untrained members, each of its own seed, in eval mode."""
    out = []
    for seed in range(n):
        torch.manual_seed(seed)
        out.append(ComplianceNet(VARIANT).eval())
    return out


def _inputs(batch: int = 4) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(0)
    return {name: rng.normal(0, 1, (batch, *shape)).astype(np.float32) for name, shape in VARIANT.input_shapes.items()}


def _run(net: torch.nn.Module, inputs: dict[str, np.ndarray]) -> np.ndarray:
    with torch.no_grad():
        return net(*(torch.from_numpy(v) for v in inputs.values())).numpy().astype(np.float64)


def test_the_pool_is_the_log_mean_of_each_members_own_temperature_scaled_probabilities():
    members, inputs = _members(3), _inputs()
    pooled = PooledNet(members, TEMPERATURES).eval()
    each = np.stack([log_softmax(_run(m, inputs) / t, axis=1) for m, t in zip(members, TEMPERATURES, strict=True)])
    expected = logsumexp(each, axis=0) - np.log(3)
    out = _run(pooled, inputs)
    assert np.allclose(out, expected, atol=1e-5)
    assert np.allclose(np.exp(out).sum(axis=1), 1.0, atol=1e-5)  # the pooled distribution sums to one



def test_one_model_is_refused_before_anything_is_read(tmp_path):
    with pytest.raises(EstimatorError, match="pooling needs at least two models, got 1"):
        pool_models([tmp_path / "model"], tmp_path / "data", tmp_path / "pooled")
    assert not (tmp_path / "pooled").exists()


@pytest.mark.slow  # trains the session's model, as test_pool's refusals
def test_a_member_that_trained_on_the_test_objects_is_not_pooled(trained_model, synthetic_dataset, tmp_path):
    # Its val objects are the others', but it has seen the test objects: the pool's test figures would flatter it.
    twin = tmp_path / "twin"
    shutil.copytree(trained_model, twin)
    meta = json.loads((twin / "metadata.json").read_text())
    objects = meta["data"]["objects"]
    meta["data"]["objects"] = {**objects, "train": sorted([*objects["train"], *objects["test"]]), "test": []}
    (twin / "metadata.json").write_text(json.dumps(meta))
    with pytest.raises(EstimatorError, match="another split of objects"):
        pool_models([trained_model, twin], synthetic_dataset, tmp_path / "pooled")
    assert not (tmp_path / "pooled").exists()


@pytest.mark.slow  # trains the session's model, as test_pool's refusals
def test_a_val_grasp_and_its_augmentations_are_one_grasp_too_few(trained_model, synthetic_dataset, tmp_path):
    twin = tmp_path / "twin"
    shutil.copytree(trained_model, twin)
    data = tmp_path / "data"
    shutil.copytree(synthetic_dataset, data)
    live = sorted((data / "val").rglob("*_a0.npz"))[0]
    kept = {live, live.with_name(live.name.replace("_a0.npz", "_a1.npz"))}
    assert all(path.exists() for path in kept)  # the grasp's live sample and one shifted copy of it
    for path in (data / "val").rglob("*.npz"):
        if path not in kept:
            path.unlink()
    with pytest.raises(EstimatorError, match="1 val samples; pooling needs at least 2"):
        pool_models([trained_model, twin], data, tmp_path / "pooled")


def test_a_folder_holding_another_model_is_refused_before_any_model_is_read(tmp_path):
    out = tmp_path / "pooled"
    out.mkdir()
    (out / "model.onnx").write_bytes(b"an earlier model")
    with pytest.raises(EstimatorError, match=r"--out .*pooled: not empty \(holds model.onnx\)"):
        pool_models([tmp_path / "a", tmp_path / "b"], tmp_path / "data", out)
    assert (out / "model.onnx").read_bytes() == b"an earlier model"
