"""``estimator evaluate`` and ``estimator estimate`` with learned methods, on simulated grasps and tiny models."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

from estimator.cli import main
from estimator.inference.hybrid import HybridEstimator
from estimator.inference.infer import default_model_dir, load_predictor
from estimator.inference.inputs import Variant
from teleop.record import read_record
from teleop.settings import load_settings


def _train(dataset, out, variant: str, synthetic):
    from estimator.training.recipe import TrainConfig
    from estimator.training.train import train_model

    train_model(dataset, out, variant=Variant.parse(variant, n_frames=synthetic.N_FRAMES, size_px=synthetic.SIZE),
                config=TrainConfig(epochs=2, patience=2, batch_size=8, seed=3), progress=False)
    return out


@pytest.fixture(scope="module")
def cnn_model(synthetic_dataset, tmp_path_factory, synthetic):
    """A CNN-alone model (no analytical inputs), trained for two epochs."""
    return _train(synthetic_dataset, tmp_path_factory.mktemp("cnn"), "depth+fw", synthetic)


@pytest.fixture(scope="module")
def hybrid_without_fw(synthetic_dataset, tmp_path_factory, synthetic):
    """A second hybrid (without force and width), trained for two epochs."""
    return _train(synthetic_dataset, tmp_path_factory.mktemp("hybrid_nofw"), "depth+analytical", synthetic)


def last_json(capsys) -> dict:
    return json.loads(capsys.readouterr().out.strip().splitlines()[-1])


def error_line(capsys) -> str:
    """The error a command printed: one line after any progress bar, no traceback."""
    err = capsys.readouterr().err
    assert "Traceback" not in err
    return err.strip().splitlines()[-1]


def check_estimate(out: dict, method: str) -> None:
    assert out["method"] == method and out["state"] in {"ok", "lower_bound", "upper_bound", "insufficient_data"}
    assert isinstance(out["reason"], str) and out["latency_ms"] > 0
    if out["state"] != "insufficient_data":
        low, high = out["interval_pa"]
        assert math.isfinite(out["E_pa"]) and out["E_pa"] > 0
        assert (low is None or low <= out["E_pa"]) and (high is None or out["E_pa"] <= high)


# --------------------------------------------------------------------------- evaluate


@pytest.mark.slow
def test_evaluate_scores_analytical_cnn_hybrid_and_auto_in_the_papers_order(
        sim_grasps, trained_model, cnn_model, tmp_path, capsys):
    records, calibration = sim_grasps
    png = tmp_path / "eval.png"
    assert main(["evaluate", str(records), "--model", str(trained_model), "--model", str(cnn_model),
                 "--calibration", str(calibration), "--plot", str(png), "--json"]) == 0
    result = last_json(capsys)
    methods = result["methods"]
    assert list(methods) == ["no_tactile", "elastic", "hertz", "series", "cnn", "hybrid", "auto"]
    assert result["labelled"] == 4 and set(result["models"]) == {str(trained_model), str(cnn_model)}
    for name in ("cnn", "hybrid", "auto"):
        m = methods[name]
        assert sum(m["states"].values()) == 4  # one estimate per record, refusals counted
        assert {"n", "log10_error", "within_10x", "states", "per_material", "per_shape", "paper",
                "interval_coverage", "ok_only", "point_log10_error"} <= set(m)
        assert m["n"] == 0 or (m["log10_error"] >= 0 and 0 <= m["within_10x"] <= 1)
        assert sum(sum(g["states"].values()) for g in m["per_material"].values()) == 4
    assert methods["hybrid"]["variant"] == "depth+fw+analytical" and methods["hybrid"]["model"] == str(trained_model)
    assert methods["hybrid"]["paper"] == {"log10_error": 0.98, "within_10x": 0.636}
    assert methods["cnn"]["variant"] == "depth+fw" and methods["cnn"]["paper"] is None  # no depth CNN row
    assert sum(methods["auto"]["answered_by"].values()) == 4
    assert png.read_bytes()[:4] == b"\x89PNG"

    # The estimate command gives what evaluate scored, record by record.
    by_path = {p.name: p for p in records.glob("*.grasp")}
    name = sorted(by_path)[0]
    assert main(["estimate", str(by_path[name]), "--method", "hybrid", "--model", str(trained_model),
                 "--calibration", str(calibration), "--json"]) == 0
    single = last_json(capsys)
    check_estimate(single, "hybrid")
    assert main(["evaluate", str(records), "--methods", "hybrid", "--model", str(trained_model),
                 "--calibration", str(calibration), "--json"]) == 0
    again = last_json(capsys)["methods"]
    assert list(again) == ["hybrid"]
    assert again["hybrid"]["log10_error"] == pytest.approx(methods["hybrid"]["log10_error"])


@pytest.mark.slow
def test_two_hybrids_are_named_by_variant_and_workers_agree(sim_grasps, trained_model, hybrid_without_fw, capsys):
    records, calibration = sim_grasps
    argv = ["evaluate", str(records), "--methods", "hybrid", "auto", "series", "--model", str(trained_model),
            "--model", str(hybrid_without_fw), "--calibration", str(calibration), "--json"]
    assert main(argv) == 0
    one = last_json(capsys)["methods"]
    assert list(one) == ["series", "hybrid[depth+fw+analytical]", "hybrid[depth+analytical]",
                         "auto[depth+fw+analytical]", "auto[depth+analytical]"]
    assert one["hybrid[depth+analytical]"]["paper"] == {"log10_error": 1.04, "within_10x": 0.594}
    assert main([*argv, "--workers", "2"]) == 0
    two = last_json(capsys)["methods"]
    for name in one:
        assert two[name]["states"] == one[name]["states"]
        assert two[name]["log10_error"] == pytest.approx(one[name]["log10_error"])


def _metadata(model, objects, **extra):
    model.mkdir(exist_ok=True)
    (model / "metadata.json").write_text(json.dumps({"data": {"objects": objects}, **extra}))
    return model


@pytest.mark.slow
def test_unseen_by_excludes_exactly_the_objects_the_model_trained_on(sim_grasps, tmp_path, capsys):
    # Session records under catalogue names: an object the published table never held is unseen; the
    # model's train and val objects (and those it was fine-tuned on) are not, whatever split lists the rest.
    records, _ = sim_grasps
    model = _metadata(tmp_path / "model", {"train": ["stress_ball", "acrylic_hex"], "val": ["rubber_duck"],
                                           "test": ["steel_ball_bearing"]})
    assert main(["evaluate", str(records), "--methods", "no_tactile", "--unseen-by", str(model), "--json"]) == 0
    result = last_json(capsys)
    assert result["labelled"] == 2 and result["skipped"] == {"trained on": 2}
    assert result["unseen_by"]["objects"] == ["silicone_ball_shore00_30", "steel_ball_bearing"]
    assert result["unseen_by"]["trained_on"] == ["acrylic_hex", "rubber_duck", "stress_ball"]
    causes = {Path(s["path"]).name: s["cause"] for s in result["skipped_records"]}
    assert causes == {"rubber_duck.grasp": f"excluded by --unseen-by: {model} trained on rubber_duck",
                      "stress_ball.grasp": f"excluded by --unseen-by: {model} trained on stress_ball"}

    # A fine-tuned model: its fine-tuning objects count as trained on, even where data.objects omits them.
    tuned = _metadata(tmp_path / "tuned", {"train": ["stress_ball"], "val": [], "test": []},
                      fine_tuning={"objects": ["silicone_ball_shore00_30"]})
    assert main(["evaluate", str(records), "--methods", "no_tactile", "--unseen-by", str(tuned), "--json"]) == 0
    assert last_json(capsys)["unseen_by"]["objects"] == ["rubber_duck", "steel_ball_bearing"]
    # Two models: only objects neither trained on; the table names each skipped record and its cause.
    assert main(["evaluate", str(records), "--methods", "no_tactile", "--unseen-by", str(model),
                 "--unseen-by", str(tuned)]) == 0
    out = capsys.readouterr().out
    assert "scored 1 records of 4" in out and "skipped 3 of 4 records:" in out
    assert f"silicone_ball_shore00_30.grasp: excluded by --unseen-by: {tuned} trained on" in out

    names = sorted(p.stem for p in records.glob("*.grasp"))
    everything = _metadata(tmp_path / "all", {"train": names, "val": [], "test": []})
    assert main(["evaluate", str(records), "--methods", "no_tactile", "--unseen-by", str(everything)]) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err and "no record scored, all 4 skipped (4 of objects" in err
    assert "rubber_duck.grasp: excluded by --unseen-by" in err  # listed before the error
    assert main(["evaluate", str(records), "--methods", "no_tactile", "--unseen-by", str(tmp_path / "nope")]) == 2
    assert "does not exist" in error_line(capsys)


def test_a_learned_method_no_model_gives_is_a_one_line_error(sim_grasps, trained_model, capsys):
    records, _ = sim_grasps
    assert main(["evaluate", str(records), "--methods", "cnn", "--model", str(trained_model)]) == 2
    err = error_line(capsys)
    assert "cnn" in err and "--model" in err
    assert main(["evaluate", str(records), "--methods", "hybrid", "--model", str(trained_model),
                 "--model", str(trained_model)]) == 2
    assert "more than once" in error_line(capsys)


# --------------------------------------------------------------------------- estimate


@pytest.mark.parametrize("method", ["cnn", "auto"])
def test_estimate_prints_a_learned_estimate(sim_grasps, trained_model, cnn_model, method, capsys):
    records, calibration = sim_grasps
    model = cnn_model if method == "cnn" else trained_model
    assert main(["estimate", str(records / "rubber_duck.grasp"), "--method", method, "--model", str(model),
                 "--calibration", str(calibration), "--json"]) == 0
    check_estimate(last_json(capsys), method)


def test_estimate_refuses_a_model_of_the_other_kind_and_options_it_cannot_honour(sim_grasps, trained_model,
                                                                                 cnn_model, capsys):
    grasp = str(sim_grasps[0] / "rubber_duck.grasp")
    for argv, words in (
        (["--method", "cnn", "--model", str(trained_model)], ("cnn", "without analytical")),
        (["--method", "hybrid", "--model", str(cnn_model)], ("hybrid", "with analytical")),
        (["--method", "hybrid", "--model", str(trained_model), "--camera-lag"], ("--camera-lag",)),
        (["--method", "series", "--model", str(trained_model)], ("--model", "series")),
    ):
        assert main(["estimate", grasp, *argv]) == 2
        err = error_line(capsys)
        assert all(w in err for w in words), err


@pytest.mark.slow
def test_estimate_without_model_uses_the_shipped_model(sim_grasps, capsys, missing_data):
    if not (default_model_dir() / "metadata.json").is_file():
        missing_data("no shipped model")
    records, calibration = sim_grasps
    grasp = records / "stress_ball.grasp"
    assert main(["estimate", str(grasp), "--method", "hybrid", "--calibration", str(calibration), "--json"]) == 0
    out = last_json(capsys)
    check_estimate(out, "hybrid")
    settings = load_settings()
    direct = HybridEstimator(load_predictor(settings=settings), settings=settings,
                             calibration=calibration).estimate(read_record(grasp))
    assert out["state"] == direct.state and out["E_pa"] == pytest.approx(direct.e_pa)


def test_evaluate_prints_the_table_with_the_papers_figures(sim_grasps, trained_model, capsys):
    records, calibration = sim_grasps
    assert main(["evaluate", str(records), "--methods", "hertz", "hybrid", "--model", str(trained_model),
                 "--calibration", str(calibration)]) == 0
    lines = capsys.readouterr().out.splitlines()
    header = next(i for i, line in enumerate(lines) if line.startswith("method"))
    hertz, hybrid = lines[header + 1], lines[header + 2]
    assert hertz.startswith("hertz") and "1.68/28.9%" in hertz
    assert hybrid.startswith("hybrid") and "depth+fw+analytical" in hybrid and "0.98/63.6%" in hybrid
