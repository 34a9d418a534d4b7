"""Evaluation metrics: how estimates, bounds and refusals count."""

from __future__ import annotations

import math

import pytest

from estimator.evaluate import PAPER, plot, summarise


def row(method, truth, state, e_pa=None, low=None, high=None, material="rubber", shape="sphere"):
    return {"path": "x.grasp", "object": "o", "material": material, "shape": shape, "truth_pa": truth,
            "method": method, "state": state, "e_pa": e_pa, "low_pa": low, "high_pa": high, "reason": "r"}


ROWS = [
    row("split", 1e6, "ok", 2e6, 1e6, 4e6),  # 0.30 decades, covered
    row("split", 1e6, "ok", 1e8, 5e7, 2e8, material="wood"),  # 2 decades, not covered
    row("split", 200e9, "lower_bound", 2e7, 2e7, None, material="metal", shape="box"),  # bound value counts
    row("split", 1e5, "insufficient_data"),  # a refusal: missing
    row("hertz", 1e6, "upper_bound", 3e6, None, 3e6),
]


def test_bounds_count_with_their_value_and_refusals_are_missing():
    split = summarise(ROWS, ["split", "hertz"])["split"]
    errors = [math.log10(2), 2.0, math.log10(200e9 / 2e7)]
    assert split["n"] == 3
    assert split["log10_error"] == pytest.approx(sum(errors) / 3)
    assert split["within_10x"] == pytest.approx(1 / 3)
    assert split["interval_coverage"] == pytest.approx(2 / 3)
    assert split["states"] == {"ok": 2, "lower_bound": 1, "upper_bound": 0, "insufficient_data": 1}


def test_metrics_per_material_and_shape():
    split = summarise(ROWS, ["split"])["split"]
    assert set(split["per_material"]) == {"rubber", "wood", "metal"}
    assert split["per_material"]["rubber"]["n"] == 1
    assert split["per_material"]["rubber"]["states"]["insufficient_data"] == 1
    assert split["per_shape"]["box"]["log10_error"] == pytest.approx(math.log10(1e4))


def test_only_refusals_give_no_error_figure():
    summary = summarise([row("elastic", 1e6, "insufficient_data")], ["elastic"])["elastic"]
    assert summary["n"] == 0 and summary["log10_error"] is None and summary["within_10x"] is None


def test_paper_figures_sit_beside_each_method():
    summary = summarise(ROWS, ["no_tactile", "elastic", "hertz", "split"])
    assert summary["no_tactile"]["paper"] == {"log10_error": 2.13, "within_10x": 0.182}
    assert summary["elastic"]["paper"] == PAPER["elastic"] == {"log10_error": 1.90, "within_10x": 0.273}
    assert summary["hertz"]["paper"]["within_10x"] == 0.289
    assert summary["split"]["paper"] is None
    assert summary["no_tactile"]["n"] == 0


def test_plot_writes_a_png(tmp_path):
    path = tmp_path / "p.png"
    plot(ROWS, ["split", "hertz"], path)
    assert path.read_bytes()[:4] == b"\x89PNG"


def test_bounds_have_a_documented_point_value_and_ok_only_figures():
    split = summarise(ROWS, ["split", "hertz"])["split"]
    point = math.sqrt(2e7 * 1e12)  # geometric middle of the lower bound and E_MAX_PA
    errors = [math.log10(2), 2.0, abs(math.log10(point / 200e9))]
    assert split["point_log10_error"] == pytest.approx(sum(errors) / 3)
    assert split["point_within_10x"] == pytest.approx(1 / 3)  # 4.5 GPa is 1.65 decades below steel
    assert split["ok_only"] == {"n": 2, "log10_error": pytest.approx((math.log10(2) + 2.0) / 2),
                                "within_10x": pytest.approx(0.5)}
    hertz = summarise(ROWS, ["hertz"])["hertz"]
    assert hertz["point_log10_error"] == pytest.approx(abs(math.log10(math.sqrt(3e6 * 1e3) / 1e6)))
    assert hertz["ok_only"]["n"] == 0 and hertz["ok_only"]["log10_error"] is None
