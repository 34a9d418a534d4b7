"""ONNX export agrees with torch; inference runs on onnxruntime alone and checks what it loads."""

from __future__ import annotations

import dataclasses
import json
import shutil
import subprocess
import sys
import textwrap

import numpy as np
import pytest
import torch

from estimator.errors import ModelError
from estimator.estimate import Estimate
from estimator.inference.distribution import N_BINS, cdf_at, probabilities, quantile
from estimator.inference.infer import CompliancePredictor, ModelMetadata, load_predictor
from estimator.inference.inputs import Variant, encode, gel_scale
from estimator.inference.reference import mismatches
from estimator.settings import estimator_settings
from estimator.training.export import export_onnx, max_disagreement
from estimator.training.model import ComplianceNet


def _random_batch(variant: Variant, batch: int, seed: int = 0) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(seed)
    return {n: rng.normal(0, 1, (batch, *s)).astype(np.float32) for n, s in variant.input_shapes.items()}


@pytest.mark.slow
@pytest.mark.parametrize("name", ["depth+fw+analytical", "rgb+markers"])
def test_torch_and_onnxruntime_agree_to_1e4_for_any_batch(tmp_path, name):
    variant = Variant.parse(name, n_frames=3, size_px=(32, 44))
    torch.manual_seed(0)
    model = ComplianceNet(variant).eval()
    path = export_onnx(model, tmp_path / "model.onnx", example=_random_batch(variant, 2))
    for batch in (1, 7):
        assert max_disagreement(model, path, _random_batch(variant, batch, seed=batch)) <= 1e-4


@pytest.mark.slow
def test_trained_model_loads_and_predicts(trained_model, synthetic):
    predictor = CompliancePredictor(trained_model)
    assert predictor.variant.name == "depth+fw+analytical"
    samples = [synthetic.sample(n, 0, 0, rng=np.random.default_rng(i)) for i, n in enumerate(("foam_a", "metal_a"))]
    probs = predictor.predict_distribution(samples)
    assert probs.shape == (2, N_BINS) and np.allclose(probs.sum(axis=1), 1.0) and np.all(probs >= 0)
    median = quantile(probs, 0.5)
    assert np.all(np.isfinite(median)) and np.all((median >= 3) & (median <= 12))
    logits = predictor.predict_logits(encode(predictor.variant, samples))
    assert logits.shape == (2, N_BINS)
    said = predictor.describe(probs[0], limit_pa=1e12, peak_force_n=20.0)
    assert said.state in ("ok", "upper_bound") and 0 < said.e_pa < 1e12
    # On a gel half the reference's, the same distribution means half the modulus, and the limit
    # (in the measuring gel's moduli) is taken on the reference gel at twice its value.
    reference = predictor.describe(probs[1], limit_pa=2e6, peak_force_n=20.0)
    halved = predictor.describe(probs[1], limit_pa=1e6, peak_force_n=20.0, gel_scale=2.0)
    assert halved.state == reference.state and halved.e_pa == pytest.approx(reference.e_pa / 2)
    assert halved.p_above_limit == reference.p_above_limit
    assert predictor.interval_level == pytest.approx(0.9)
    with pytest.raises(ModelError, match="model input 'frames'"):
        predictor.predict_logits({**encode(predictor.variant, samples), "frames": np.zeros((2, 3, 1, 8, 8))})
    with pytest.raises(ModelError, match="model inputs"):
        predictor.predict_logits({"frames": np.zeros((2, 3, 1, 16, 22))})


@pytest.mark.slow
def test_inference_never_imports_torch(trained_model):
    script = textwrap.dedent(f"""
        import sys
        import numpy as np
        from estimator.inference.hybrid import HybridEstimator
        from estimator.inference.infer import CompliancePredictor
        from estimator.inference.inputs import encode
        predictor = CompliancePredictor({str(trained_model)!r})
        batch = {{n: np.zeros((2, *s), np.float32) for n, s in predictor.variant.input_shapes.items()}}
        out = predictor.predict_logits(batch)
        assert out.shape == (2, 90), out.shape
        import estimator.evaluation.bench_cli, estimator.training.dataset_cli  # the run-time commands' modules too
        print("torch" in sys.modules)
    """)
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120, check=False)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "False"


def _copy(model_dir, tmp_path):
    dest = tmp_path / "model"
    shutil.copytree(model_dir, dest)
    return dest, json.loads((dest / "metadata.json").read_text())


@pytest.mark.parametrize(("change", "expected"), [
    (lambda m: m.update(version=9), "metadata version 9"),
    (lambda m: m.update(format="other"), "not a compliance-teleop.model"),
    (lambda m: m["scales"].update(force_scale_n=25.0), "trained with input scales"),
    (lambda m: m["variant"].update(name="rgb+fw+analytical"), "do not match variant"),
    (lambda m: m["calibration"].update(interval_scales=[0.0, 1.0, 1.0]), "one interval scale > 0 and one"),
    (lambda m: m["calibration"].update(interval_scales=[1.0, 1.0]), "one interval scale > 0 and one"),
    (lambda m: m["calibration"].update(force_band_edges_n=[20.0, 10.0]), "rising force_band_edges_n"),
    (lambda m: m["calibration"].update(p_rigids=[0.9, 1.0, 0.5]), "0 < p_rigid < 1 per force band"),
    (lambda m: m["calibration"].update(floor={"methods": ["series"], "leak": 0.0}), "leaking 0-1"),
    (lambda m: m["calibration"].update(temperature=-1.0), "temperature > 0"),
    (lambda m: m.pop("calibration"), "missing or malformed"),
])
@pytest.mark.slow
def test_metadata_that_does_not_fit_is_refused(trained_model, tmp_path, change, expected):
    dest, meta = _copy(trained_model, tmp_path)
    change(meta)
    (dest / "metadata.json").write_text(json.dumps(meta))
    with pytest.raises(ModelError, match=expected):
        CompliancePredictor(dest)


@pytest.mark.slow
def test_a_hybrid_distribution_keeps_a_leak_of_its_mass_below_the_analytical_lower_bounds(trained_model, synthetic):
    predictor = CompliancePredictor(trained_model)
    leak = predictor.metadata.floor_leak
    assert predictor.metadata.floor_methods == ("no_tactile", "series") and 0 < leak < 0.1
    sample = synthetic.sample("foam_a", 0, 0, rng=np.random.default_rng(0))
    k = gel_scale(sample.gel_modulus_pa)
    bounded = dataclasses.replace(sample, estimates=(  # a bound at a bin edge (1 GPa) on the reference gel
        *(e for e in sample.estimates if e.method != "series"), Estimate.at_least("series", 1e9 / k, "stiff")))
    floor_log10, method = predictor.floor(bounded)
    assert method == "series" and floor_log10 == pytest.approx(9.0)
    floored = cdf_at(predictor.predict_distribution([bounded]), floor_log10)[0]
    # Without a floor in its calibration the model's own distribution stands...
    predictor.metadata = dataclasses.replace(predictor.metadata, floor_methods=())
    own = predictor.predict_distribution([bounded])
    logits = predictor.predict_logits(encode(predictor.variant, [bounded]))
    assert np.allclose(own, probabilities(logits, temperature=predictor.metadata.temperature))
    # ...and the floor multiplies the odds of E below it by the leak.
    below = cdf_at(own, floor_log10)[0]
    assert floored / (1 - floored) == pytest.approx(leak * below / (1 - below), rel=1e-6)


@pytest.mark.slow
def test_each_force_band_reads_its_own_calibration_and_an_older_model_has_one_for_all(trained_model, tmp_path):
    dest, meta = _copy(trained_model, tmp_path)
    meta["calibration"].update(force_band_edges_n=[10.0, 20.0], interval_scales=[4.0, 2.0, 1.5],
                               p_rigids=[0.98, 0.9, 0.5])
    (dest / "metadata.json").write_text(json.dumps(meta))
    metadata = CompliancePredictor(dest).metadata
    forces = (3.0, 10.0, 19.0, 20.0, 80.0)
    assert [metadata.interval_scale_at(f) for f in forces] == [4.0, 2.0, 2.0, 1.5, 1.5]
    assert [metadata.p_rigid_at(f) for f in forces] == [0.98, 0.9, 0.9, 0.5, 0.5]
    for key in ("force_band_edges_n", "interval_scales", "p_rigids", "floor"):
        del meta["calibration"][key]
    meta["calibration"].update(interval_scale=1.7, p_rigid=0.8)
    (dest / "metadata.json").write_text(json.dumps(meta))
    metadata = CompliancePredictor(dest).metadata
    assert metadata.interval_scales == (1.7,) and metadata.interval_scale_at(3.0) == metadata.interval_scale_at(80.0)
    assert metadata.p_rigids == (0.8,) and metadata.floor_methods == ()


@pytest.mark.slow
def test_missing_or_broken_files_are_refused(trained_model, tmp_path):
    with pytest.raises(ModelError, match="is not a model folder: it has no model.onnx and no metadata.json"):
        CompliancePredictor(tmp_path)
    with pytest.raises(ModelError, match="does not exist"):
        CompliancePredictor(tmp_path / "nowhere")
    dest, meta = _copy(trained_model, tmp_path)
    (dest / "metadata.json").write_text("{ not json")
    with pytest.raises(ModelError, match="not a readable model metadata"):
        CompliancePredictor(dest)
    (dest / "metadata.json").write_text(json.dumps(meta))
    (dest / "model.onnx").write_bytes(b"not onnx")
    with pytest.raises(ModelError, match="onnxruntime cannot load it"):
        CompliancePredictor(dest)
    with pytest.raises(ModelError, match="threads"):
        CompliancePredictor(trained_model, threads=0)


@pytest.mark.slow
def test_a_model_knows_whether_this_code_measured_its_inputs(trained_model, tmp_path, caplog):
    assert CompliancePredictor(trained_model).measurement_code_matches
    dest, meta = _copy(trained_model, tmp_path)
    meta["data"]["measurement_version"] = 0
    (dest / "metadata.json").write_text(json.dumps(meta))
    with caplog.at_level("WARNING"):
        stale = CompliancePredictor(dest)
    assert not stale.measurement_code_matches and "retrain it" in caplog.text


@pytest.mark.slow
def test_a_model_is_refused_where_the_settings_measure_depth_on_another_grid(trained_model, tmp_path):
    from dataclasses import replace

    from estimator.inference.hybrid import HybridEstimator
    from teleop.settings import load_settings

    settings = load_settings()
    predictor = CompliancePredictor(trained_model)
    assert predictor.depth_binning == estimator_settings(settings).depth_binning == 2
    HybridEstimator(predictor, settings=settings)
    full_grid = settings.with_section(replace(estimator_settings(settings), depth_binning=1))
    with pytest.raises(ModelError, match="binned by 2.*depth_binning = 1.*retrain"):
        HybridEstimator(predictor, settings=full_grid)
    # A model from before the setting was trained on the full grid.
    dest, meta = _copy(trained_model, tmp_path)
    del meta["data"]["depth_binning"]
    (dest / "metadata.json").write_text(json.dumps(meta))
    assert CompliancePredictor(dest).depth_binning == 1
    HybridEstimator(CompliancePredictor(dest), settings=full_grid)


@pytest.mark.slow
def test_settings_name_the_model(trained_model):
    from dataclasses import replace

    from teleop.settings import load_settings

    settings = load_settings()
    settings = settings.with_section(replace(estimator_settings(settings), model_path=str(trained_model / "model.onnx")))
    assert load_predictor(settings=settings).model_dir == trained_model
    assert ModelMetadata.from_json(json.loads((trained_model / "metadata.json").read_text()), "x").variant.n_frames == 3


@pytest.mark.parametrize("name", ["default", "cnn-depth-fw", "hybrid-depth-analytical"])
def test_the_shipped_models_were_trained_on_what_this_code_measures(name, missing_data):
    from estimator.inference.infer import default_model_dir
    from teleop.settings import load_settings

    model_dir = default_model_dir().parent / name
    if not (model_dir / "metadata.json").is_file():
        missing_data(f"no shipped model {name}")
    predictor = CompliancePredictor(model_dir)
    settings = load_settings()
    # A change to the measurement (or the depth grid) needs the shipped models retrained.
    assert predictor.measurement_code_matches, f"retrain {model_dir}: the measurement version changed"
    assert predictor.depth_binning == estimator_settings(settings).depth_binning
    # ... and a change that alters the inputs must raise the measurement version.
    recorded = predictor.metadata.raw["reference"]["inputs"]
    moved = mismatches(recorded, predictor.variant, settings=settings)
    assert not moved, (f"{model_dir}: the inputs on the reference record moved without a new "
                       f"MEASUREMENT_VERSION (raise it and retrain): {moved}")


@pytest.mark.slow
def test_the_reference_check_sees_inputs_that_moved(trained_model):
    from dataclasses import replace

    from teleop.settings import load_settings

    settings = load_settings()
    predictor = CompliancePredictor(trained_model)
    recorded = predictor.metadata.raw["reference"]["inputs"]
    assert mismatches(recorded, predictor.variant, settings=settings) == []
    # Another object Poisson ratio changes every analytical fit, and nothing else.
    other = replace(settings, sensing=replace(settings.sensing, object_poisson=0.2))
    moved = mismatches(recorded, predictor.variant, settings=other)
    assert moved and all(m.startswith("analytical") for m in moved)
    # Depth on the full grid changes the depth maps.
    full = settings.with_section(replace(estimator_settings(settings), depth_binning=1))
    assert any(m.startswith("frames") for m in mismatches(recorded, predictor.variant, settings=full))


def test_a_model_from_before_the_series_rename_loads_and_answers_as_the_shipped_one(sim_grasps, tmp_path,
                                                                                    missing_data):
    from estimator.inference.hybrid import HybridEstimator
    from estimator.inference.infer import default_model_dir
    from teleop.record import read_record
    from teleop.settings import load_settings

    if not (default_model_dir() / "metadata.json").is_file():
        missing_data("no shipped model")
    # The shipped model as it was trained, before the series fit was renamed from "split".
    dest, meta = _copy(default_model_dir(), tmp_path)
    old = {"series": "split", "max_series_interval_decades": "max_split_interval_decades",
           "series_log10_error": "split_log10_error"}

    def back(mapping):
        return {old.get(k, k): v for k, v in mapping.items()}

    for methods in (meta["scales"]["analytical_methods"], meta["calibration"]["floor"]["methods"],
                    meta["recalibrated"]["previous"]["floor"]["methods"]):
        methods[methods.index("series")] = "split"
    meta["metrics"] = {part: back(figures) for part, figures in meta["metrics"].items()}
    meta["auto"] = back(meta["auto"])
    meta["auto"]["table"] = [back(row) for row in meta["auto"]["table"]]
    (dest / "metadata.json").write_text(json.dumps(meta, indent=1))
    assert "series" not in (dest / "metadata.json").read_text()

    shipped, legacy = CompliancePredictor(default_model_dir()), CompliancePredictor(dest)
    assert legacy.metadata.raw == shipped.metadata.raw and legacy.metadata.floor_methods == ("no_tactile", "series")
    records, calibration = sim_grasps
    record, settings = read_record(records / "steel_ball_bearing.grasp"), load_settings()
    for mode in ("model", "auto"):
        first, second = (HybridEstimator(p, settings=settings, calibration=calibration).estimate(record, mode=mode)
                         for p in (shipped, legacy))
        assert dataclasses.replace(first, latency_s=0.0) == dataclasses.replace(second, latency_s=0.0)
