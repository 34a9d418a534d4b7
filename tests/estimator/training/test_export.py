"""Exporting a network to ONNX and reading it back: a file that computes otherwise than torch, or
weights that do not fit the network, are a ModelError naming what differs."""

from __future__ import annotations

import numpy as np
import pytest

from estimator.errors import ModelError
from estimator.inference.inputs import Variant
from estimator.training import export as export_module
from estimator.training.model import ComplianceNet

VARIANT = Variant.parse("depth", n_frames=3, size_px=(16, 22))


def _inputs(n=4, seed=0):
    rng = np.random.default_rng(seed)
    return {name: rng.normal(size=(n, *shape)).astype(np.float32) for name, shape in VARIANT.input_shapes.items()}


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    import torch

    torch.manual_seed(0)
    model = ComplianceNet(VARIANT).eval()
    path = export_module.export_onnx(model, tmp_path_factory.mktemp("onnx") / "model.onnx", example=_inputs())
    return model, path


@pytest.mark.parametrize("worst", [1e-3, float("nan")])
def test_an_export_that_disagrees_with_torch_past_1e_4_or_by_nan_is_refused(exported, tmp_path, monkeypatch, worst):
    model, _ = exported
    monkeypatch.setattr(export_module, "max_disagreement", lambda *args, **kwargs: worst)
    with pytest.raises(ModelError, match="onnxruntime and torch differ by"):
        export_module.export_onnx(model, tmp_path / "model.onnx", example=_inputs())


def test_a_network_with_other_weights_than_the_file_is_not_taken_as_rebuilt(exported):
    # Fine-tuning must start from the network the file holds.
    import torch

    model, path = exported
    assert export_module.check_rebuilt(model, path, _inputs(seed=1)) is model
    torch.manual_seed(123)
    with pytest.raises(ModelError, match="rebuilt from its weights differs from onnxruntime"):
        export_module.check_rebuilt(ComplianceNet(VARIANT), path, _inputs(seed=1))


def test_weights_of_another_shape_name_the_parameter_as_a_model_error(exported):
    _, path = exported
    weights = export_module.onnx_weights(path)
    name = next(n for n, v in weights.items() if v.ndim == 4)
    weights[name] = np.zeros((*weights[name].shape[:-1], weights[name].shape[-1] + 1), np.float32)
    with pytest.raises(ModelError, match=f"{name} of variant depth should be"):
        export_module.load_exported_weights(ComplianceNet(VARIANT), weights, source="x.onnx")
