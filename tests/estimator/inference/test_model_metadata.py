"""What a loaded model reads from its folder (on the shipped models: onnxruntime only, no torch): the
interval scale of the grasp's force band, an id that changes with any file's name, a settings'
model_path naming its model.onnx, the analytical floor weighing the distribution, and unbinned depth
for a model from before depth binning."""

from __future__ import annotations

import json
import shutil
from dataclasses import replace
from pathlib import Path

import numpy as np

from estimator.inference.infer import (
    CompliancePredictor,
    ModelMetadata,
    default_model_dir,
    load_predictor,
    model_id,
    read_metadata,
)
from estimator.settings import estimator_settings
from teleop.settings import Settings

MODELS = Path(__file__).resolve().parents[3] / "estimator" / "models"


def test_the_interval_scale_is_that_of_the_grasps_force_band():
    path, data = read_metadata(MODELS / "default")
    meta = ModelMetadata.from_json(data, str(path))
    edges, scales = meta.force_band_edges_n, meta.interval_scales
    assert len(set(scales)) == len(scales) > 1
    assert meta.interval_scale_at(edges[0] / 2) == scales[0]
    assert meta.interval_scale_at(edges[-1] * 2) == scales[-1]
    assert meta.p_rigid_at(edges[-1] * 2) == meta.p_rigids[-1]


def test_a_model_id_changes_when_a_file_is_renamed(tmp_path):
    a, b = tmp_path / "a" / "m", tmp_path / "b" / "m"
    for folder, extra in ((a, "x.onnx"), (b, "y.onnx")):  # the same bytes under another name
        shutil.copytree(MODELS / "default", folder)
        shutil.copyfile(folder / "model.onnx", folder / extra)
    assert model_id(a) != model_id(b)


def test_the_settings_model_path_may_name_the_model_onnx():
    settings = Settings()
    path = str(default_model_dir() / "model.onnx")
    settings = settings.with_section(replace(estimator_settings(settings), model_path=path))
    assert load_predictor(settings=settings).model_dir == default_model_dir()


def test_the_analytical_floor_weighs_the_distribution(monkeypatch):
    from estimator.inference import infer
    from estimator.inference.distribution import EDGES_LOG10

    predictor = CompliancePredictor(MODELS / "default")
    assert predictor.metadata.floor_methods
    shapes = predictor.variant.input_shapes
    monkeypatch.setattr(infer, "encode", lambda _variant, items: {n: np.zeros((len(items), *s), np.float32)
                                                                  for n, s in shapes.items()})
    floor_log10 = 6.0
    monkeypatch.setattr(predictor, "floor", lambda _item: (floor_log10, "series"))
    floored = predictor.predict_distribution([object()])[0]
    predictor.metadata = replace(predictor.metadata, floor_methods=())
    free = predictor.predict_distribution([object()])[0]
    below = np.asarray(EDGES_LOG10)[1:] <= floor_log10
    assert floored[below].sum() < free[below].sum() - 0.1  # mass moved above the floor


def test_a_model_from_before_depth_binning_reads_unbinned_depth(tmp_path):
    folder = tmp_path / "m"
    shutil.copytree(MODELS / "default", folder)
    meta = json.loads((folder / "metadata.json").read_text())
    meta.get("data", {}).pop("depth_binning", None)
    (folder / "metadata.json").write_text(json.dumps(meta))
    assert CompliancePredictor(folder).depth_binning == 1
