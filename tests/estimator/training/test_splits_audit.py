"""A dataset's encoded splits, pinned by a mutation audit: subsets and the live sampling, the peak
force and floors each grasp is calibrated by, empty splits, and the rows and figures a model is scored by."""

from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pytest

from estimator.errors import EstimatorError, SampleError
from estimator.estimate import Estimate
from estimator.inference.distribution import EDGES_LOG10, probabilities, quantile
from estimator.inference.inputs import MEASUREMENT_VERSION, Variant, default_window_m
from estimator.training.conformal import described
from estimator.training.dataset import DATASET_FORMAT
from estimator.training.samples import save_sample
from estimator.training.splits import (
    SplitData,
    auto_policy,
    check_dataset_fits,
    dataset_window,
    load_split_data,
    scored_rows,
    split_metrics,
)
from teleop.settings import load_settings

CENTRES = (EDGES_LOG10[:-1] + EDGES_LOG10[1:]) / 2
CALIBRATION = {"temperature": 1.0, "floor": None, "level": 0.8, "force_band_edges_n": [10.0], "p_rigids": [0.5, 0.5],
               "interval_scales": [1.0, 3.0], "soft_pa": 5e3, "limit_pa": 6.75e6}


def _logits(centres_log10: np.ndarray) -> np.ndarray:
    return np.stack([-((CENTRES - c) ** 2) / (2 * 0.2**2) for c in centres_log10])


def _row(i: int, *, augmentation: int = 0, peak_force_n: float = 25.0, floor_pa: float | None = None,
         obj: str | None = None, gel_scale: float = 1.0) -> dict:
    """A row of a soft grasp ``i`` (its object ``obj``, default one per grasp) whose series fit says 1e5 Pa."""
    estimates = [Estimate.ok("series", 1e5, 5e4, 2e5, "synthetic")]
    if floor_pa is not None:
        estimates.append(Estimate.at_least("no_tactile", floor_pa, "synthetic bound"))
    return {"object": obj or f"o{i}", "material": "foam", "shape": "sphere", "truth_pa": 1e5 * (1 + i),
            "gel_scale": gel_scale, "estimates": tuple(estimates), "frames": 5, "augmentation": augmentation,
            "peak_force_n": peak_force_n}


def _data(rows: list[dict]) -> SplitData:
    label = np.log10([r["truth_pa"] * r["gel_scale"] for r in rows]).astype(np.float32)
    return SplitData({"x": np.arange(len(rows), dtype=np.float32)[:, None]}, label, rows)


def test_a_subset_by_mask_or_by_position_keeps_inputs_labels_and_rows_together():
    data = _data([_row(i) for i in range(5)])
    for index in (np.array([False, True, False, True, True]), np.array([4, 1])):
        part = data.subset(index)
        picked = np.flatnonzero(index) if index.dtype == bool else index
        assert len(part) == picked.size
        assert part.inputs["x"][:, 0].tolist() == picked.tolist()
        assert part.label.tolist() == data.label[picked].tolist()
        assert [r["object"] for r in part.rows] == [f"o{i}" for i in picked]


def test_the_live_samples_are_the_augmentation_0_ones():
    data = _data([_row(i, augmentation=a) for i, a in enumerate([0, 1, 2, 0, 1])])
    assert [r["object"] for r in data.live().rows] == ["o0", "o3"]


def test_a_variant_reads_floors_only_with_the_analytical_estimates():
    data = _data([_row(0, floor_pa=2e4), _row(1)])
    floors = data.floors_for(Variant.parse("depth+analytical", n_frames=3, size_px=(16, 22)))
    assert floors.tolist() == [pytest.approx(np.log10(2e4)), -np.inf]
    assert data.floors_for(Variant.parse("depth", n_frames=3, size_px=(16, 22))) is None


def test_each_grasps_peak_force_is_its_own():
    data = _data([_row(0, peak_force_n=4.0), _row(1, peak_force_n=31.5)])
    assert data.peak_forces_n.tolist() == [4.0, 31.5]


def _dataset(out, samples, *, split: dict) -> None:
    for sample in samples:
        path = out / "train" / sample.object_name / f"{sample.object_name}_g{sample.grasp}_a{sample.augmentation}.npz"
        path.parent.mkdir(parents=True, exist_ok=True)
        save_sample(sample, path)
    (out / "split.json").write_text(json.dumps({"seed": 0, "fractions": [1.0, 0.0, 0.0], **split}))


def test_a_sample_is_loaded_with_its_peak_force_and_its_material_or_unknown(synthetic, tmp_path):
    base = synthetic.sample("foam_a", 0, 0, rng=np.random.default_rng(0))
    # The force peaks mid-grasp: the peak is neither the last frame's nor the mean.
    sample = dataclasses.replace(base, force_n=np.array([2.0, 30.0, 10.0]), material="")
    _dataset(tmp_path, [sample], split={"train": ["foam_a"], "val": [], "test": []})
    variant = Variant.parse("depth", n_frames=synthetic.N_FRAMES, size_px=synthetic.SIZE)
    data = load_split_data(tmp_path, variant)
    (row,) = data["train"].rows
    assert row["peak_force_n"] == 30.0 and data["train"].peak_forces_n.tolist() == [30.0]
    assert row["material"] == "unknown"
    # A split without samples (no folder) is empty, its inputs shaped as the variant reads them.
    for name in ("val", "test"):
        assert len(data[name]) == 0 and data[name].rows == []
        assert {k: v.shape for k, v in data[name].inputs.items()} == {
            k: (0, *s) for k, s in variant.input_shapes.items()}


def test_a_sample_without_a_label_is_refused_naming_its_file(synthetic, tmp_path):
    base = synthetic.sample("foam_a", 0, 0, rng=np.random.default_rng(0))
    _dataset(tmp_path, [dataclasses.replace(base, label_modulus_pa=None)],
             split={"train": ["foam_a"], "val": [], "test": []})
    with pytest.raises(SampleError, match=r"foam_a_g0_a0\.npz: sample has no label_modulus_pa"):
        load_split_data(tmp_path, Variant.parse("depth", n_frames=synthetic.N_FRAMES, size_px=synthetic.SIZE))


def test_the_scored_rows_are_the_models_answers_and_each_analytical_estimate():
    # The second grasp on a gel half as stiff: its truth is scored on that gel, as its answer.
    rows = [_row(0, peak_force_n=5.0), _row(1, peak_force_n=25.0, gel_scale=2.0)]
    data = _data(rows)
    logits = _logits(np.array([5.0, 5.3]))
    scored = scored_rows(data, logits, "hybrid", CALIBRATION)
    said = described(logits, CALIBRATION, data.gel_scales, data.peak_forces_n)
    models = [r for r in scored if r["method"] == "hybrid"]
    assert [(r["state"], r["e_pa"], r["low_pa"], r["high_pa"]) for r in models] == [
        (d.state, d.e_pa, d.low_pa, d.high_pa) for d in said]
    assert models[0]["high_pa"] / models[0]["low_pa"] < models[1]["high_pa"] / models[1]["low_pa"]  # 1 vs 3 spreads
    assert [r["truth_pa"] for r in models] == [1e5, 2e5]
    series = [r for r in scored if r["method"] == "series"]
    assert [(r["e_pa"], r["low_pa"], r["high_pa"], r["truth_pa"]) for r in series] == [(1e5, 5e4, 2e5, 1e5),
                                                                                        (1e5, 5e4, 2e5, 2e5)]


def test_the_scored_rows_of_a_hybrid_answer_under_its_floor():
    data = _data([_row(0, floor_pa=2e5), _row(1, floor_pa=2e5)])
    logits = _logits(np.array([5.0, 5.0]))
    floored = {**CALIBRATION, "floor": {"methods": ["no_tactile", "series"], "leak": 0.01}}
    models = [r for r in scored_rows(data, logits, "hybrid", floored) if r["method"] == "hybrid"]
    bare = [r for r in scored_rows(data, logits, "hybrid", CALIBRATION) if r["method"] == "hybrid"]
    assert all(m["e_pa"] > 2e5 > b["e_pa"] for m, b in zip(models, bare, strict=True))


def test_the_split_figures_count_objects_not_grasps_and_carry_the_calibrations_level():
    rows = [_row(i, obj=name) for i, name in enumerate(["a", "a", "b"])]
    summary = split_metrics(_data(rows), _logits(np.array([5.0, 5.3, 5.5])), "hybrid", CALIBRATION, load_settings())
    assert summary["objects"] == 2
    assert summary["hybrid"]["interval_level"] == 0.8 and summary["hybrid"]["n"] == 3
    assert all("paper" not in value for key, value in summary.items() if key != "objects")
    assert split_metrics(_data([]), np.zeros((0, CENTRES.size)), "hybrid", CALIBRATION, load_settings()) == {}



def test_auto_takes_the_series_where_it_errs_exactly_as_much_as_the_model():
    logits = _logits(np.array([5.3]))
    median = float(quantile(probabilities(logits), 0.5)[0])
    e_pa = 10.0**median
    while math.log10(e_pa) != median:  # the series says exactly the model's median
        e_pa = math.nextafter(e_pa, math.inf if math.log10(e_pa) < median else 0.0)
    row = {**_row(0), "estimates": (Estimate.ok("series", e_pa, e_pa / 1.05, e_pa * 1.05, "synthetic"),)}
    policy = auto_policy(_data([row, _row(1)]), np.concatenate([logits, _logits(np.array([5.3]))]))
    # 0.04 decade wide: taken at every threshold; the other grasp's series (0.6 decade wide) from 0.75 on.
    assert [e["share"] for e in policy["table"]] == [0.5, 0.5, 0.5, 1.0, 1.0, 1.0, 1.0, 1.0]
    assert policy["table"][0]["series_log10_error"] == policy["table"][0]["model_log10_error"]
    assert policy["max_series_interval_decades"] == 0.5  # the other grasp's series errs more


def _check_fits(folder, manifest_changes: dict, model_data: dict) -> None:
    """check_dataset_fits for a 3-frame 16x22 px depth model of the default window (``model_data`` beside the
    current measurement version) on a dataset whose manifest differs from one that fits by ``manifest_changes``."""
    manifest = {"format": DATASET_FORMAT, "version": 1, "n_frames": 3, "size_px": [16, 22],
                "window_m": list(default_window_m()), "measurement_version": MEASUREMENT_VERSION, "depth_binning": 1,
                **manifest_changes}
    folder.mkdir(parents=True)
    (folder / "dataset.json").write_text(json.dumps(manifest))
    variant = Variant.parse("depth", n_frames=3, size_px=(16, 22), window_m=default_window_m())
    check_dataset_fits(folder, variant, {"measurement_version": MEASUREMENT_VERSION, **model_data})


@pytest.mark.parametrize(("changes", "model_data", "message"), [
    ({"measurement_version": MEASUREMENT_VERSION - 1}, {}, "measured by measurement version"),
    ({"calibration_smoothing_px": [0.0, 2.0]}, {}, r"smoothing colours by 0 and 2 px, the model's training data "
                                                   r"from 0 px"),
    ({"window_m": [default_window_m()[0] * 1.001, default_window_m()[1]]}, {}, "window, the model reads"),
    ({"n_frames": 4}, {}, r"holds 4 frames of \[16, 22\] px per sample, the model reads 3"),
])
def test_a_dataset_measured_otherwise_than_the_model_is_refused(tmp_path, changes, model_data, message):
    with pytest.raises(EstimatorError, match=message):
        _check_fits(tmp_path / "d", changes, model_data)


def test_a_dataset_of_some_of_the_models_smoothings_fits(tmp_path):
    _check_fits(tmp_path / "d", {"calibration_smoothing_px": [2.0]}, {"calibration_smoothing_px": [0.0, 2.0]})


def test_a_datasets_window_is_the_one_its_manifest_records():
    assert dataset_window({"window_m": [0.014, 0.019]}, "d") == (0.014, 0.019)
    assert dataset_window({}, "d") == default_window_m()


def test_auto_reports_no_errors_at_a_threshold_that_takes_no_grasp():
    row = {**_row(0), "estimates": (Estimate.ok("series", 1e5, 1e5 / 10**0.1, 1e5 * 10**0.1, "synthetic"),)}
    first, *rest = auto_policy(_data([row]), _logits(np.array([5.0])))["table"]
    assert (first["n"], first["share"], first["series_log10_error"], first["model_log10_error"]) == (0, 0.0, None, None)
    assert all(e["n"] == 1 and e["series_log10_error"] is not None for e in rest)
