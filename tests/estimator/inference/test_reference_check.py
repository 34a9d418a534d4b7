"""The shipped model's recorded reference inputs hold on this code, and an input that moved or changed
length is named (onnxruntime only: the shipped-model check in test_export_infer.py needs torch)."""

from __future__ import annotations

import copy

from estimator.inference.infer import CompliancePredictor, default_model_dir
from estimator.inference.reference import mismatches
from teleop.settings import load_settings


def test_the_shipped_models_reference_inputs_hold_and_a_moved_input_is_named():
    predictor = CompliancePredictor(default_model_dir())
    settings = load_settings()
    recorded = predictor.metadata.raw["reference"]["inputs"]

    def named(inputs: dict) -> list[str]:
        return [m.split(":")[0] for m in mismatches(inputs, predictor.variant, settings=settings)]

    assert named(recorded) == []
    moved = copy.deepcopy(recorded)
    moved["frames_abs_sum"] = [v * 1.02 for v in moved["frames_abs_sum"]]
    assert named(moved) == ["frames_abs_sum"]
    shorter = copy.deepcopy(recorded)
    shorter["frames_peak"] = shorter["frames_peak"][:-1]
    assert named(shorter) == ["frames_peak"]
