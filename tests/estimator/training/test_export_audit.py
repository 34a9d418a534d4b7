"""ONNX export and rebuild: disagreement measured both ways, damaged files and missing weights named."""

from __future__ import annotations

import copy
import importlib.util
from pathlib import Path

import numpy as np
import pytest
import torch

from estimator.errors import ModelError
from estimator.training import export as export_module
from estimator.training.model import ComplianceNet

# The export tests' variant and inputs.
_spec = importlib.util.spec_from_file_location("_export_tests", Path(__file__).with_name("test_export.py"))
_export_tests = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(_export_tests)
VARIANT, _inputs = _export_tests.VARIANT, _export_tests._inputs


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    torch.manual_seed(0)
    model = ComplianceNet(VARIANT).eval()
    with torch.no_grad():  # as after training: untouched batch norms would be exported as no-ops, no folded bias
        for module in model.modules():
            if isinstance(module, torch.nn.BatchNorm2d):
                for tensor in (module.weight, module.bias, module.running_mean):
                    tensor.uniform_(-0.5, 0.5)
                module.running_var.uniform_(0.5, 2.0)
    path = export_module.export_onnx(model, tmp_path_factory.mktemp("onnx") / "model.onnx", example=_inputs())
    return model, path


def test_a_torch_network_answering_above_the_file_is_a_disagreement_too(exported):
    model, path = exported
    above = copy.deepcopy(model)
    with torch.no_grad():
        above.estimation[1].bias += 1.0  # every logit one higher than the file's
    assert export_module.max_disagreement(above, path, _inputs(seed=2)) == pytest.approx(1.0, abs=1e-4)
    with pytest.raises(ModelError, match="differs from onnxruntime by 1"):
        export_module.check_rebuilt(above, path, _inputs(seed=2))


def test_the_network_rebuilt_from_the_file_answers_as_the_original_in_eval_mode(exported):
    model, path = exported
    rebuilt = export_module.network_from_onnx(path, VARIANT, check=_inputs(seed=3))
    assert not rebuilt.training
    feed = [torch.from_numpy(v) for v in _inputs(n=6, seed=4).values()]
    with torch.no_grad():
        np.testing.assert_allclose(rebuilt(*feed).numpy(), model(*feed).numpy(), atol=1e-5)


def test_a_file_that_is_not_onnx_is_a_model_error_naming_it(tmp_path):
    bad = tmp_path / "model.onnx"
    bad.write_bytes(b"\x00not a protobuf\xff" * 8)
    with pytest.raises(ModelError, match=f"^{bad}: not a readable ONNX file"):
        export_module.onnx_weights(bad)
    with pytest.raises(ModelError, match="not a readable ONNX file"):
        export_module.network_from_onnx(bad, VARIANT, check=_inputs())


def test_a_missing_weight_or_folded_bias_is_a_model_error_naming_it(exported):
    _, path = exported
    weights = export_module.onnx_weights(path)
    name = next(n for n in weights if n.startswith("estimation.") and n.endswith(".bias"))
    without = {k: v for k, v in weights.items() if k != name}
    with pytest.raises(ModelError, match=rf"^x.onnx: {name} of variant depth should be .*the file has none"):
        export_module.load_exported_weights(ComplianceNet(VARIANT), without, source="x.onnx")
    folded = next(n for n in weights if n.endswith(".0.weight_bias"))
    without = {k: v for k, v in weights.items() if k != folded}
    with pytest.raises(ModelError, match=rf"^x.onnx: no folded batch-norm bias {folded} for "):
        export_module.load_exported_weights(ComplianceNet(VARIANT), without, source="x.onnx")


def test_a_rebuilt_network_whose_disagreement_is_nan_is_not_taken(exported, monkeypatch):
    model, path = exported
    monkeypatch.setattr(export_module, "max_disagreement", lambda *args, **kwargs: float("nan"))
    with pytest.raises(ModelError, match="differs from onnxruntime by nan"):
        export_module.check_rebuilt(model, path, _inputs())
