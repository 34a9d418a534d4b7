"""Evaluation metrics: how estimates, bounds and refusals count."""

from __future__ import annotations

import json
import math
from pathlib import Path
from types import SimpleNamespace

import pytest

from estimator.errors import ModelError
from estimator.evaluation.evaluate import (
    PAPER,
    ablation_table,
    answered_by,
    model_methods,
    plot,
    summarise,
)
from estimator.inference.inputs import Variant
from estimator.inference.provenance import held_out_objects, load_split, trained_objects


def row(method, truth, state, e_pa=None, low=None, high=None, material="rubber", shape="sphere"):
    return {"path": "x.grasp", "object": "o", "material": material, "shape": shape, "truth_pa": truth,
            "method": method, "state": state, "e_pa": e_pa, "low_pa": low, "high_pa": high, "reason": "r"}


ROWS = [
    row("series", 1e6, "ok", 2e6, 1e6, 4e6),  # 0.30 decades, covered
    row("series", 1e6, "ok", 1e8, 5e7, 2e8, material="wood"),  # 2 decades, not covered
    row("series", 200e9, "lower_bound", 2e7, 2e7, None, material="metal", shape="box"),  # bound value counts
    row("series", 1e5, "insufficient_data"),  # a refusal: missing
    row("hertz", 1e6, "upper_bound", 3e6, None, 3e6),
]


def test_bounds_count_with_their_value_and_refusals_are_missing():
    series = summarise(ROWS, ["series", "hertz"])["series"]
    errors = [math.log10(2), 2.0, math.log10(200e9 / 2e7)]
    assert series["n"] == 3
    assert series["log10_error"] == pytest.approx(sum(errors) / 3)
    assert series["within_10x"] == pytest.approx(1 / 3)
    assert series["interval_coverage"] == pytest.approx(2 / 3)
    assert series["states"] == {"ok": 2, "lower_bound": 1, "upper_bound": 0, "insufficient_data": 1}


def test_metrics_per_material_and_shape():
    series = summarise(ROWS, ["series"])["series"]
    assert set(series["per_material"]) == {"rubber", "wood", "metal"}
    assert series["per_material"]["rubber"]["n"] == 1
    assert series["per_material"]["rubber"]["states"]["insufficient_data"] == 1
    assert series["per_shape"]["box"]["log10_error"] == pytest.approx(math.log10(1e4))


def test_only_refusals_give_no_error_figure():
    summary = summarise([row("elastic", 1e6, "insufficient_data")], ["elastic"])["elastic"]
    assert summary["n"] == 0 and summary["log10_error"] is None and summary["within_10x"] is None


def test_paper_figures_sit_beside_each_method():
    summary = summarise(ROWS, ["no_tactile", "elastic", "hertz", "series"])
    assert summary["no_tactile"]["paper"] == {"log10_error": 2.13, "within_10x": 0.182}
    assert summary["elastic"]["paper"] == PAPER["elastic"] == {"log10_error": 1.90, "within_10x": 0.273}
    assert summary["hertz"]["paper"]["within_10x"] == 0.289
    assert summary["series"]["paper"] is None
    assert summary["no_tactile"]["n"] == 0


def test_plot_writes_a_png(tmp_path):
    path = tmp_path / "p.png"
    plot(ROWS, ["series", "hertz"], path)
    assert path.read_bytes()[:4] == b"\x89PNG"


def test_bounds_have_a_documented_point_value_and_ok_only_figures():
    series = summarise(ROWS, ["series", "hertz"])["series"]
    point = math.sqrt(2e7 * 1e12)  # geometric middle of the lower bound and E_MAX_PA
    errors = [math.log10(2), 2.0, abs(math.log10(point / 200e9))]
    assert series["point_log10_error"] == pytest.approx(sum(errors) / 3)
    assert series["point_within_10x"] == pytest.approx(1 / 3)  # 4.5 GPa is 1.65 decades below steel
    assert series["ok_only"] == {"n": 2, "log10_error": pytest.approx((math.log10(2) + 2.0) / 2),
                                "within_10x": pytest.approx(0.5)}
    hertz = summarise(ROWS, ["hertz"])["hertz"]
    assert hertz["point_log10_error"] == pytest.approx(abs(math.log10(math.sqrt(3e6 * 1e3) / 1e6)))
    assert hertz["ok_only"]["n"] == 0 and hertz["ok_only"]["log10_error"] is None


# --------------------------------------------------------------------------- learned methods


def predictor(variant: str, model_dir: str, *, n_frames: int = 3, size_px=(64, 88)):
    """What model_methods reads of a CompliancePredictor: its variant, directory and fingerprint check."""
    return SimpleNamespace(variant=Variant.parse(variant, n_frames=n_frames, size_px=size_px),
                           model_dir=Path(model_dir), measurement_code_matches=True)


def test_each_model_gives_its_method_and_a_hybrid_also_auto():
    entries = model_methods([predictor("depth+fw+analytical", "m/h"), predictor("rgb+markers+fw", "m/c")])
    assert [(e.name, e.method, e.mode, e.model_dir) for e in entries] == [
        ("hybrid", "hybrid", "model", "m/h"), ("auto", "auto", "auto", "m/h"), ("cnn", "cnn", "model", "m/c")]
    only = model_methods([predictor("depth+fw+analytical", "m/h")], methods=["auto"])
    assert [e.name for e in only] == ["auto"]


def test_two_models_of_one_method_are_named_by_variant_then_by_size_then_by_directory():
    entries = model_methods([predictor("depth+analytical", "a"), predictor("depth+markers+fw+analytical", "b")],
                            methods=["hybrid"])
    assert [e.name for e in entries] == ["hybrid[depth+analytical]", "hybrid[depth+markers+fw+analytical]"]
    sized = model_methods([predictor("depth+fw", "a", size_px=(32, 44)), predictor("depth+fw", "b", n_frames=5)])
    assert [e.name for e in sized] == ["cnn[depth+fw 3f 32x44]", "cnn[depth+fw 5f 64x88]"]
    tuned = model_methods([predictor("depth+fw", "a"), predictor("depth+fw", "a_tuned")])
    assert [e.name for e in tuned] == ["cnn[depth+fw a]", "cnn[depth+fw a_tuned]"]
    with pytest.raises(ModelError, match="both give cnn"):
        model_methods([predictor("depth+fw", "a"), predictor("depth+fw", "a")])


def test_the_ablation_table_follows_the_papers_row_order_and_figures():
    models = model_methods([predictor("depth+fw+analytical", "h1"), predictor("rgb+markers+analytical", "h2"),
                            predictor("rgb+markers+fw", "c")])
    rows = [row(e.name, 1e6, "ok", 2e6, 1e6, 4e6) for e in models if e.method != "auto"]
    rows += [row("series", 1e6, "ok", 2e6), row("no_tactile", 1e6, "ok", 2e6),
             {**row("auto[depth+fw+analytical]", 1e6, "ok", 2e6), "reason": "series: narrow interval; fit"},
             row("auto[depth+fw+analytical]", 1e6, "insufficient_data")]
    table = ablation_table(rows, methods=["series", "no_tactile"], models=models)
    assert list(table) == ["no_tactile", "series", "cnn", "hybrid[rgb+markers+analytical]",
                           "hybrid[depth+fw+analytical]", "auto[rgb+markers+analytical]",
                           "auto[depth+fw+analytical]"]
    assert table["cnn"]["paper"] == PAPER["cnn[rgb+markers+fw]"] == {"log10_error": 0.86, "within_10x": 0.646}
    assert table["hybrid[depth+fw+analytical]"]["paper"] == {"log10_error": 0.98, "within_10x": 0.636}
    assert table["no_tactile"]["paper"]["log10_error"] == 2.13 and table["no_tactile"]["inputs"] == "F, w"
    assert table["auto[depth+fw+analytical]"]["paper"] is None
    assert table["auto[depth+fw+analytical]"]["answered_by"] == {"series": 1, "refused": 1}
    hybrid = table["hybrid[depth+fw+analytical]"]
    assert hybrid["model"] == "h1" and hybrid["variant"] == "depth+fw+analytical" and hybrid["size_px"] == [64, 88]
    assert hybrid["log10_error"] == pytest.approx(math.log10(2)) and hybrid["per_material"]["rubber"]["n"] == 1


def test_a_models_interval_level_is_carried_to_its_methods():
    stated = SimpleNamespace(**vars(predictor("depth+fw+analytical", "h")), interval_level=0.9)
    entries = model_methods([stated, predictor("rgb+markers+fw", "c")])  # the CNN's model states none
    assert [(e.name, e.interval_level) for e in entries] == [("hybrid", 0.9), ("auto", 0.9), ("cnn", None)]
    rows = [row(e.name, 1e5, "ok", 2e5, 1e5, 4e5) for e in entries] + [row("series", 1e5, "ok", 2e5, 1e5, 4e5)]
    table = ablation_table(rows, methods=["series"], models=entries, display_range_pa=(5e3, 6.75e6))
    assert {name: m["interval_level"] for name, m in table.items()} == {
        "series": None, "cnn": None, "hybrid": 0.9, "auto": 0.9}
    assert table["hybrid"]["felt_log10_error"] == pytest.approx(math.log10(2))
    assert ablation_table(rows, methods=["series"], models=entries)["hybrid"]["felt_log10_error"] is None


def test_metrics_stay_importable_from_evaluate():
    import estimator.evaluation.evaluate as evaluate
    import estimator.evaluation.metrics as metrics

    for name in ("summarise", "point_value", "PAPER", "E_MAX_PA", "E_MIN_PA"):
        assert getattr(evaluate, name) is getattr(metrics, name)


def test_answered_by_counts_the_branch_in_each_reason_and_refusals():
    rows = [{**row("auto", 1e6, "ok", 1e6), "reason": "model: depth model over 3 frames"},
            {**row("auto", 1e6, "ok", 1e6), "reason": "model: again"},
            {**row("auto", 1e6, "ok", 1e6), "reason": "no_tactile: no tactile sample (x): force and width only"},
            {**row("auto", 1e6, "insufficient_data"), "reason": "every analytical method refuses: x"},
            row("series", 1e6, "ok", 1e6)]
    assert answered_by(rows, "auto") == {"model": 2, "no_tactile": 1, "refused": 1}


def write_metadata(directory: Path, data: dict) -> Path:
    directory.mkdir(parents=True, exist_ok=True)
    (directory / "metadata.json").write_text(json.dumps({"format": "compliance-teleop.model", "data": data}))
    return directory


def test_a_split_file_reads_back_as_its_three_lists_of_objects(tmp_path):
    path = tmp_path / "split.json"
    path.write_text(json.dumps({"seed": 0, "train": ["a"], "val": ["c"], "test": ["b"]}))
    assert load_split(path) == {"train": ["a"], "val": ["c"], "test": ["b"]}


def test_held_out_objects_come_from_the_metadata_or_the_datasets_split(tmp_path):
    listed = write_metadata(tmp_path / "listed", {"objects": {"train": ["a"], "val": ["b"], "test": ["c", "d"]}})
    assert held_out_objects(listed) == {"c", "d"}
    dataset = tmp_path / "dataset"
    dataset.mkdir()
    (dataset / "split.json").write_text(json.dumps({"train": ["a"], "val": ["b"], "test": ["e"]}))
    counted = write_metadata(tmp_path / "counted", {"dir": str(dataset), "objects": {"train": 1, "test": 1}})
    assert held_out_objects(counted) == {"e"}
    lost = write_metadata(tmp_path / "lost", {"dir": str(tmp_path / "gone"), "objects": {"test": 1}})
    with pytest.raises(ModelError, match="split.json"):
        held_out_objects(lost)
    with pytest.raises(ModelError, match="model folder .* does not exist"):
        held_out_objects(tmp_path / "nothing")


def test_trained_objects_are_train_val_and_fine_tuning_objects(tmp_path):
    listed = write_metadata(tmp_path / "listed", {"objects": {"train": ["a"], "val": ["b"], "test": ["c", "d"]}})
    assert trained_objects(listed) == {"a", "b"}
    tuned = write_metadata(tmp_path / "tuned", {"objects": {"train": ["a"], "val": [], "test": ["c"]}})
    meta = json.loads((tuned / "metadata.json").read_text())
    (tuned / "metadata.json").write_text(json.dumps({**meta, "fine_tuning": {"objects": ["lab_mug", "c"]}}))
    assert trained_objects(tuned) == {"a", "lab_mug", "c"}
    dataset = tmp_path / "dataset"
    dataset.mkdir()
    (dataset / "split.json").write_text(json.dumps({"train": ["a"], "val": ["b"], "test": ["e"]}))
    counted = write_metadata(tmp_path / "counted", {"dir": str(dataset), "objects": {"train": 1, "val": 1}})
    assert trained_objects(counted) == {"a", "b"}
    lost = write_metadata(tmp_path / "lost", {"dir": str(tmp_path / "gone"), "objects": {"train": 1}})
    with pytest.raises(ModelError, match="train and val objects.*split.json"):
        trained_objects(lost)
    with pytest.raises(ModelError, match="model folder .* does not exist"):
        trained_objects(tmp_path / "nothing")
    (tmp_path / "empty").mkdir()
    with pytest.raises(ModelError, match="it has no metadata.json"):
        trained_objects(tmp_path / "empty")
    (tmp_path / "empty" / "metadata.json").write_text("{not json")
    with pytest.raises(ModelError, match="not a readable model metadata"):
        trained_objects(tmp_path / "empty")


@pytest.mark.slow
def test_plot_draws_one_panel_per_method(tmp_path):
    import matplotlib.image

    one, four = tmp_path / "one.png", tmp_path / "four.png"
    plot(ROWS, ["series"], one)
    plot(ROWS + [row("no_tactile", 1e6, "ok", 1e5), row("auto", 1e9, "insufficient_data")],
         ["series", "hertz", "no_tactile", "auto"], four)
    small, big = matplotlib.image.imread(one), matplotlib.image.imread(four)
    assert big.shape[0] > small.shape[0] * 1.5 and big.shape[1] > small.shape[1] * 2.5  # a 2 x 3 grid


@pytest.mark.slow
def test_plot_gives_the_panel_errors_in_decades_and_names_the_records_directory(tmp_path, monkeypatch):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    monkeypatch.setattr(plt, "close", lambda *args, **kwargs: None)
    rows = [{**r, "path": f"/data/eval_records/g{i:03d}.grasp"} for i, r in enumerate(ROWS)]
    plot(rows, ["series", "hertz"], tmp_path / "eval.png", display_range_pa=(5e3, 6.75e6))
    fig = plt.gcf()
    titles = [ax.get_title() for ax in fig.axes if ax.get_visible()]
    for title in titles:
        assert "err " in title and "decades" in title, title
    series = next(t for t in titles if t.startswith("series"))
    assert "felt err" in series and series.count("decades") == 2, series
    assert "/data/eval_records" in fig._suptitle.get_text()
    plt.close(fig)
