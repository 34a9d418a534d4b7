"""A dataset's encoded splits (torch-free): labels on the reference gel, the series policy ``auto``
chooses, and the datasets a model refuses."""

from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pytest

from estimator.errors import EstimatorError
from estimator.estimate import Estimate
from estimator.inference.distribution import EDGES_LOG10
from estimator.inference.hybrid import MIN_SERIES_FRAMES
from estimator.inference.inputs import (
    MEASUREMENT_VERSION,
    REFERENCE_GEL_MODULUS_PA,
    Variant,
    default_window_m,
)
from estimator.training.dataset import DATASET_FORMAT
from estimator.training.samples import save_sample
from estimator.training.splits import SplitData, auto_policy, check_dataset_fits, load_split_data

CENTRES = (EDGES_LOG10[:-1] + EDGES_LOG10[1:]) / 2


def _data(rows: list[dict]) -> SplitData:
    return SplitData({}, np.log10([r["truth_pa"] * r["gel_scale"] for r in rows]).astype(np.float32), rows)


def _grasp(truth_log10: float, series_log10: float, width_decades: float, *, frames: int = 5,
           gel_scale: float = 1.0) -> dict:
    """A validation row whose series fit says ``series_log10`` within an interval ``width_decades`` wide."""
    low = 10.0 ** (series_log10 - width_decades / 2)
    series = Estimate("series", 10.0**series_log10, (low, low * 10.0**width_decades), "ok", "")
    return {"object": "o", "truth_pa": 10.0**truth_log10, "gel_scale": gel_scale, "estimates": (series,),
            "frames": frames, "augmentation": 0}


def _logits(centres_log10: np.ndarray) -> np.ndarray:
    return np.stack([-((CENTRES - c) ** 2) / (2 * 0.2**2) for c in centres_log10])


def test_auto_takes_the_series_on_grasps_of_exactly_the_fewest_frames():
    rows = [_grasp(5.0, 5.02, 0.2, frames=MIN_SERIES_FRAMES) for _ in range(10)]
    model = np.full(len(rows), 5.6)  # the model is 0.6 decade off; the series 0.02
    policy = auto_policy(_data(rows), _logits(model))
    assert policy["table"][0]["n"] == 0 and policy["table"][1]["n"] == len(rows)  # 0.1 < 0.2 <= 0.25
    assert policy["max_series_interval_decades"] > 0


def test_auto_stops_at_the_widest_threshold_at_which_the_series_still_err_no_more_than_the_model():
    # Series intervals exactly 1 decade wide are good; those 1.5 decades wide are bad.
    good = [_grasp(5.0, 5.05, 1.0) for _ in range(10)]
    bad = [_grasp(5.0, 6.5, 1.5) for _ in range(10)]
    low, high = good[0]["estimates"][0].interval_pa
    assert math.log10(high / low) == 1.0  # on the threshold, not a rounding error off it
    policy = auto_policy(_data(good + bad), _logits(np.full(20, 5.3)))
    assert policy["max_series_interval_decades"] == 1.0


def test_auto_compares_the_model_and_the_series_on_the_measuring_gel():
    # The model answers on the reference gel (label = log10 E x gel scale); the series on the measuring gel.
    rows = [_grasp(5.0, 5.3, 0.2, gel_scale=4.0) for _ in range(10)]
    model = np.full(len(rows), 5.0 + math.log10(4.0))  # exactly right once back on the measuring gel
    policy = auto_policy(_data(rows), _logits(model))
    assert policy["max_series_interval_decades"] == 0.0  # the series, 0.3 decade off, is never preferred
    assert all(e["model_log10_error"] is None or e["model_log10_error"] < 0.1 for e in policy["table"])


def _one_sample_dataset(out, sample):
    """A dataset of ``sample`` alone, its object in train."""
    path = out / "train" / sample.object_name / f"{sample.object_name}_g0_a0.npz"
    path.parent.mkdir(parents=True)
    save_sample(sample, path)
    (out / "split.json").write_text(json.dumps({"seed": 0, "fractions": [1.0, 0.0, 0.0],
                                                "train": [sample.object_name], "val": [], "test": []}))
    return out


def test_labels_and_floors_of_a_grasp_on_another_gel_are_taken_onto_the_reference_gel(synthetic, tmp_path):
    base = synthetic.sample("plastic_a", 0, 0, rng=np.random.default_rng(0))
    floor = Estimate.at_least("no_tactile", 1e6, "a lower bound: the analytical floor")
    base = dataclasses.replace(base, estimates=(*[e for e in base.estimates if e.method != "no_tactile"], floor))
    variant = Variant.parse("depth+analytical", n_frames=synthetic.N_FRAMES, size_px=synthetic.SIZE)
    loaded = {}
    for name, gel in (("reference", REFERENCE_GEL_MODULUS_PA), ("half", REFERENCE_GEL_MODULUS_PA / 2)):
        data = _one_sample_dataset(tmp_path / name, dataclasses.replace(base, gel_modulus_pa=gel))
        loaded[name] = load_split_data(data, variant, ("train",))["train"]
    ref, half = loaded["reference"], loaded["half"]
    assert ref.gel_scales[0] == 1.0 and half.gel_scales[0] == 2.0
    # A grasp on a gel half as stiff reads like one of an object twice as stiff on the reference gel.
    assert half.label[0] == np.float32(np.log10(base.label_modulus_pa * 2.0))
    assert np.isfinite(ref.floors_log10[0])
    assert half.floors_log10[0] == ref.floors_log10[0] + np.log10(2.0)


def _check_fits(folder, manifest_changes: dict, model_data: dict) -> None:
    """check_dataset_fits for a 3-frame 16x22 px depth model (``model_data`` beside the current measurement
    version) on a dataset whose manifest differs from one that fits by ``manifest_changes`` (None: key absent)."""
    manifest = {"format": DATASET_FORMAT, "version": 1, "n_frames": 3, "size_px": [16, 22],
                "window_m": list(default_window_m()), "measurement_version": MEASUREMENT_VERSION, "depth_binning": 1}
    manifest.update(manifest_changes)
    folder.mkdir(parents=True)
    (folder / "dataset.json").write_text(json.dumps({k: v for k, v in manifest.items() if v is not None}))
    variant = Variant.parse("depth", n_frames=3, size_px=(16, 22), window_m=default_window_m())
    check_dataset_fits(folder, variant, {"measurement_version": MEASUREMENT_VERSION, **model_data})


def test_a_dataset_of_another_image_size_is_refused_naming_both_sizes(tmp_path):
    _check_fits(tmp_path / "same", {}, {"depth_binning": 1})
    with pytest.raises(EstimatorError, match=r"3 frames of \[32, 44\] px per sample, the model reads 3 of \[16, 22\]"):
        _check_fits(tmp_path / "bigger", {"size_px": [32, 44]}, {"depth_binning": 1})


def test_a_dataset_or_model_from_before_depth_binning_was_recorded_counts_as_unbinned(tmp_path):
    _check_fits(tmp_path / "old_dataset", {"depth_binning": None}, {"depth_binning": 1})
    _check_fits(tmp_path / "old_model", {"depth_binning": 1}, {})
    with pytest.raises(EstimatorError, match="depth binned by 2"):
        _check_fits(tmp_path / "binned", {"depth_binning": 2}, {})
