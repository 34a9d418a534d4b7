"""``estimator.evaluation.evaluate``: what each scored row holds, which records are held out or
skipped and why, and what the measurement is asked for (audit: a figure that could change silently)."""

from __future__ import annotations

import dataclasses
from types import SimpleNamespace

import numpy as np
import pytest

from estimator.errors import CalibrationError, PerceptionError
from estimator.estimate import Estimate
from estimator.evaluation import evaluate as evaluate_module
from estimator.evaluation.evaluate import (
    ModelMethod,
    _records_dir,
    ablation_order,
    evaluate_record,
    evaluate_records,
    model_methods,
    result_row,
)
from estimator.inference.inputs import Variant
from teleop.catalogue import load_catalogue
from teleop.record import read_record, write_record
from teleop.settings import load_settings
from teleop.sim.grasp import simulate_grasp


@pytest.fixture(scope="module")
def grape(tmp_path_factory):
    """(a labelled grape record's path, one of the same grasp with a label but no modulus, settings)."""
    settings = load_settings()
    obj = next(o for o in load_catalogue() if o.name == "grape")
    record, _ = simulate_grasp(obj, settings=settings, rng=np.random.default_rng(0))
    folder = tmp_path_factory.mktemp("evaluate_audit")
    path = write_record(record, folder / "grape.grasp")
    no_modulus = write_record(dataclasses.replace(record, label=dataclasses.replace(record.label, modulus_pa=None)),
                              folder / "nomodulus.grasp")
    return path, no_modulus, settings


def test_a_row_carries_the_label_and_the_estimates_interval_in_order(grape):
    path, _, _ = grape
    label = read_record(path).label
    row = result_row(path, label, "series", Estimate.ok("series", 2e5, 1e5, 4e5, "fit"))
    assert (row["truth_pa"], row["e_pa"], row["low_pa"], row["high_pa"]) == (label.modulus_pa, 2e5, 1e5, 4e5)
    assert (row["object"], row["material"], row["shape"]) == (label.object_name, label.material, label.shape)
    assert (row["method"], row["state"], row["reason"], row["path"]) == ("series", "ok", "fit", str(path))


def test_records_of_a_trained_on_object_are_held_out_and_the_others_scored(grape):
    path, no_modulus, settings = grape
    name = read_record(path).label.object_name
    kw = dict(settings=settings, methods=["no_tactile"], calibration=None)
    assert evaluate_record(path, exclude=frozenset({name}), **kw) == [
        {"path": str(path), "skipped": f"trained on: {name}", "object": name}]
    [row] = evaluate_record(path, exclude=frozenset({"another_object"}), **kw)
    assert row["method"] == "no_tactile" and row["object"] == name
    assert evaluate_records([path], exclude=frozenset({name}), progress=False, **kw)[0]["skipped"] == (
        f"trained on: {name}")
    assert evaluate_record(no_modulus, **kw) == [
        {"path": str(no_modulus), "skipped": f"unlabelled: {name} has no modulus", "object": name}]


def test_evaluate_records_corrects_the_width_lag_by_default_and_passes_the_choice_on(grape):
    path, _, settings = grape
    kw = dict(settings=settings, methods=["no_tactile"], calibration=None)
    corrected = evaluate_record(path, correct_width_lag=True, **kw)[0]["e_pa"]
    stamped = evaluate_record(path, correct_width_lag=False, **kw)[0]["e_pa"]
    assert corrected != pytest.approx(stamped, rel=0.05)
    assert evaluate_records([path], progress=False, **kw)[0]["e_pa"] == pytest.approx(corrected)
    assert evaluate_records([path], progress=False, correct_width_lag=False, **kw)[0]["e_pa"] == pytest.approx(stamped)


def _fake_measurement(monkeypatch, *, fail: Exception | None = None) -> list[dict]:
    """Replace the calibration loader and the measurement: records what ``measure_grasp`` is asked."""
    asked: list[dict] = []

    def measure(record, **kwargs):
        asked.append(kwargs)
        if fail is not None:
            raise fail
        return SimpleNamespace()

    monkeypatch.setattr(evaluate_module, "_calibration", lambda path: ("calibration", path))
    monkeypatch.setattr(evaluate_module, "measure_grasp", measure)
    monkeypatch.setattr(evaluate_module, "estimate_grasp",
                        lambda measurements, method, settings: Estimate.ok(method, 2e5, 1e5, 4e5))
    return asked


def test_one_tactile_method_among_others_reads_the_calibration_and_the_lag_choices_are_passed(grape, monkeypatch):
    path, _, settings = grape
    asked = _fake_measurement(monkeypatch)
    rows = evaluate_record(path, settings=settings, methods=["no_tactile", "series"], calibration=None,
                           correct_camera_lag=True, correct_width_lag=False)
    assert [r["method"] for r in rows] == ["no_tactile", "series"]
    [kw] = asked
    assert kw["tactile"] is True and kw["calibration"][0] == "calibration"
    assert (kw["correct_camera_lag"], kw["correct_width_lag"]) == (True, False)
    asked.clear()
    evaluate_record(path, settings=settings, methods=["no_tactile"], calibration=None)
    assert asked[0]["tactile"] is False and asked[0]["calibration"] is None
    assert (asked[0]["correct_camera_lag"], asked[0]["correct_width_lag"]) == (False, True)


def test_a_perception_failure_skips_the_record_as_unreadable_naming_its_object(grape, monkeypatch):
    path, _, settings = grape
    _fake_measurement(monkeypatch, fail=PerceptionError("frame 3 does not decode"))
    name = read_record(path).label.object_name
    assert evaluate_record(path, settings=settings, methods=["series"], calibration=None) == [
        {"path": str(path), "skipped": "unreadable: frame 3 does not decode", "object": name}]


def test_a_records_own_calibration_that_does_not_load_skips_it_but_a_given_one_stops_the_run(grape, monkeypatch):
    path, _, settings = grape
    _fake_measurement(monkeypatch, fail=CalibrationError("not a calibration archive"))
    name = read_record(path).label.object_name
    assert evaluate_record(path, settings=settings, methods=["series"], calibration=None) == [
        {"path": str(path), "skipped": "calibration unusable: not a calibration archive", "object": name}]
    given = path.with_name("given.npz")
    given.write_bytes(b"x")
    with pytest.raises(CalibrationError, match="not a calibration archive"):
        evaluate_record(path, settings=settings, methods=["series"], calibration=str(given))


def test_each_model_entry_is_asked_for_its_own_mode_and_markers_count_for_a_missing_calibration(grape, monkeypatch):
    path, _, settings = grape
    modes = []
    estimator = SimpleNamespace(estimate=lambda record, mode: modes.append(mode) or Estimate.ok("h", 2e5, 1e5, 4e5))
    monkeypatch.setattr(evaluate_module, "_hybrid_estimator", lambda model_dir, settings, calibration: estimator)
    variant = Variant.parse("rgb+markers+fw+analytical", n_frames=3, size_px=(16, 22))
    models = [ModelMethod("hybrid", "hybrid", "m", variant), ModelMethod("auto", "auto", "m", variant)]
    rows = evaluate_record(path, settings=settings, methods=[], calibration=None, models=models)
    assert [r["method"] for r in rows] == ["hybrid", "auto"] and modes == ["model", "auto"]

    asked = []

    def missing(record, finger, calibration, *, markers=False):
        asked.append(markers)
        return "calibration missing: gone"

    def unusable(record, mode):
        raise CalibrationError("gone")

    monkeypatch.setattr(evaluate_module, "missing_calibration", missing)
    estimator.estimate = unusable
    [row] = evaluate_record(path, settings=settings, methods=[], calibration=None, models=models)
    assert row["skipped"] == "calibration missing: gone" and asked == [True]


def test_the_records_directory_of_one_record_is_its_folder():
    assert _records_dir(["/data/eval/g1.grasp"]) == "/data/eval"
    assert _records_dir(["/data/eval/a/g1.grasp", "/data/eval/b/g2.grasp"]) == "/data/eval"
    assert _records_dir([]) is None


def test_the_plot_spans_the_plotted_methods_values_only(monkeypatch, tmp_path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    monkeypatch.setattr(plt, "close", lambda *args, **kwargs: None)
    label = SimpleNamespace(object_name="o", material="rubber", shape="sphere", modulus_pa=1e6)
    rows = [result_row("/r/a.grasp", label, "series", Estimate.ok("series", 2e6, 1e6, 4e6)),
            result_row("/r/b.grasp", SimpleNamespace(**{**vars(label), "modulus_pa": 1e11}), "hertz",
                       Estimate.ok("hertz", 1e11, 5e10, 2e11))]
    evaluate_module.plot(rows, ["series"], tmp_path / "p.png")
    fig = plt.gcf()
    assert fig.axes[0].get_xlim() == pytest.approx((1e6 / 3, 2e6 * 3))  # the hertz row is not drawn
    plt.close(fig)


def test_within_an_image_markers_come_before_none_and_force_and_width_before_none():
    def predictor(variant):
        return SimpleNamespace(variant=Variant.parse(variant, n_frames=3, size_px=(16, 22)), model_dir=variant,
                               measurement_code_matches=True)

    models = model_methods([predictor(v) for v in ("rgb+analytical", "rgb+fw+analytical",
                                                   "rgb+markers+analytical", "rgb+markers+fw+analytical")],
                           methods=["hybrid"])
    names = sorted((e.name for e in models), key=lambda n: ablation_order(n, models))
    assert names == ["hybrid[rgb+markers+fw+analytical]", "hybrid[rgb+markers+analytical]",
                     "hybrid[rgb+fw+analytical]", "hybrid[rgb+analytical]"]


def test_evaluate_records_keeps_every_methods_row_of_every_record(grape, monkeypatch):
    path, _, settings = grape
    _fake_measurement(monkeypatch)
    rows = evaluate_records([path, path], settings=settings, methods=["no_tactile", "series"], calibration=None,
                            progress=False)
    assert [r["method"] for r in rows] == ["no_tactile", "series"] * 2
