"""A model loads when this code's input scales are those it was trained with; the list of analytical
fits counts only for a model that reads them, and a refusal names only the scales that differ."""

from __future__ import annotations

from pathlib import Path

import pytest

from estimator.errors import ModelError
from estimator.inference import inputs
from estimator.inference.infer import CompliancePredictor, ModelMetadata, read_metadata

MODELS = Path(__file__).resolve().parents[3] / "estimator" / "models"


def _metadata(name: str) -> ModelMetadata:
    path, data = read_metadata(MODELS / name)
    return ModelMetadata.from_json(data, str(path))


@pytest.fixture
def new_fit(monkeypatch):
    """This code with one analytical fit more than the shipped models were trained with."""
    monkeypatch.setattr(inputs, "ANALYTICAL_METHODS", (*inputs.ANALYTICAL_METHODS, "fake_fit"))


def test_a_cnn_alone_loads_with_a_new_fit(new_fit):
    assert not _metadata("cnn-depth-fw").variant.analytical
    assert CompliancePredictor(MODELS / "cnn-depth-fw").variant.name == "depth+fw"


@pytest.mark.parametrize("name", ["default", "hybrid-depth-analytical"])
def test_a_hybrid_refuses_a_new_fit_naming_only_that_scale(new_fit, name):
    with pytest.raises(ModelError) as refused:
        _metadata(name)
    message = str(refused.value)
    assert ("analytical_methods ['no_tactile', 'elastic', 'hertz', 'series'] (this code: "
            "['no_tactile', 'elastic', 'hertz', 'series', 'fake_fit'])") in message
    assert "force_scale_n" not in message and "retrain the model" in message


def test_any_model_refuses_another_scale_naming_only_it(monkeypatch):
    trained = inputs.FORCE_SCALE_N
    monkeypatch.setattr(inputs, "FORCE_SCALE_N", trained * 2)
    with pytest.raises(ModelError) as refused:
        _metadata("cnn-depth-fw")
    differ = str(refused.value).split("differ from this code's: ", 1)[1]
    assert differ == f"force_scale_n {trained!r} (this code: {trained * 2!r}); retrain the model"
