"""A damaged or foreign model folder is refused with a ModelError, not loaded to answer: a malformed
calibration, another metadata version, an ONNX graph with other outputs or inputs than its metadata
names, an output that is not finite (on the shipped models: onnxruntime only, no torch)."""

from __future__ import annotations

import copy
import shutil
from pathlib import Path

import numpy as np
import pytest

from estimator.errors import ModelError
from estimator.inference.infer import CompliancePredictor, ModelMetadata, read_metadata

MODELS = Path(__file__).resolve().parents[3] / "estimator" / "models"


def shipped_metadata() -> dict:
    return read_metadata(MODELS / "default")[1]


def metadata_from(data: dict) -> ModelMetadata:
    return ModelMetadata.from_json(data, "metadata.json")


def test_the_shipped_metadata_loads():
    assert metadata_from(shipped_metadata()).interval_level == pytest.approx(0.9)


@pytest.mark.parametrize(("field", "value"), [
    ("temperature", 0.0),
    ("temperature", -1.0),
    ("force_band_edges_n", [20.0, 10.0]),  # bands not rising
    ("force_band_edges_n", [10.0, 10.0]),
    ("floor", {"methods": ["no_such_fit"], "leak": 0.01}),  # a floor of a fit this code does not have
])
def test_a_malformed_calibration_is_refused(field, value):
    data = copy.deepcopy(shipped_metadata())
    data["calibration"][field] = value
    with pytest.raises(ModelError, match="calibration"):
        metadata_from(data)


def test_a_model_of_another_metadata_version_is_refused():
    data = copy.deepcopy(shipped_metadata())
    data["version"] -= 1
    with pytest.raises(ModelError, match="metadata version"):
        metadata_from(data)


def test_a_model_whose_onnx_gives_another_output_is_refused(tmp_path, monkeypatch):
    from estimator.inference import infer

    folder = tmp_path / "m"
    shutil.copytree(MODELS / "default", folder)
    monkeypatch.setattr(infer, "OUTPUT_NAME", "something_else")  # what this code expects the graph to give
    with pytest.raises(ModelError, match="outputs"):
        CompliancePredictor(folder)


def test_a_folder_whose_onnx_reads_other_inputs_than_its_metadata_is_refused(tmp_path):
    folder = tmp_path / "m"
    shutil.copytree(MODELS / "default", folder)
    shutil.copyfile(MODELS / "cnn-depth-fw" / "model.onnx", folder / "model.onnx")  # another variant's graph
    with pytest.raises(ModelError, match="differ from its metadata"):
        CompliancePredictor(folder)


def test_a_non_finite_model_output_is_refused():
    predictor = CompliancePredictor(MODELS / "default")
    batch = {name: np.zeros((1, *shape), np.float32) for name, shape in predictor.variant.input_shapes.items()}
    bad = predictor.predict_logits(batch).copy()
    bad[0, 0] = np.nan

    class NaNSession:
        def run(self, *_args, **_kwargs):
            return [bad]

    predictor.session = NaNSession()
    with pytest.raises(ModelError, match="not finite"):
        predictor.predict_logits(batch)
