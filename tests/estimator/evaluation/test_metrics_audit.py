"""The reported figures at their edges: the within-2x slack, point values, coverage, the paper's table."""

from __future__ import annotations

import math
import re

import pytest

from estimator.evaluation.metrics import (
    E_MAX_PA,
    E_MIN_PA,
    PAPER,
    felt_log10_error,
    felt_log10_offset,
    felt_within,
    point_value,
    summarise,
)

SOFT, RIGID = 5e3, 6.75e6  # the shipped display: the rigid end is the sensor's resolution limit
DISPLAY = (SOFT, RIGID)
FELT_KEYS = ("felt_log10_error", "felt_within_2x", "dangerous_misses", "shown_unknown", "rigid_shown_rigid",
             "interval_width_decades_median", "soft_felt_log10_error", "soft_felt_within_2x",
             "soft_interval_width_decades_median")


def row(truth, state, e_pa=None, low=None, high=None, method="series", material="rubber", shape="sphere"):
    return {"path": "x.grasp", "object": "o", "material": material, "shape": shape, "truth_pa": truth,
            "method": method, "state": state, "e_pa": e_pa, "low_pa": low, "high_pa": high, "reason": "r"}


def one(rows, display=DISPLAY, method="series"):
    return summarise(rows, [method], display_range_pa=display)[method]


@pytest.mark.parametrize("error, within", [
    (0.0, True),
    (math.log10(2), True),
    (math.log10(2) + 5e-10, True),  # float slack of the log scale and back
    (math.log10(2) + 1e-9, True),  # the slack's own edge counts
    (math.log10(2) + 1e-6, False),
    (math.log10(2.04), False),  # 2 %  past a factor 2 is a miss, not slack
    (math.log10(2.1), False),
])
def test_felt_within_is_a_factor_2_and_a_nano_decade_of_slack(error, within):
    assert felt_within(error) is within


@pytest.mark.parametrize("state, e_pa, point", [
    ("ok", 3e5, 3e5),
    ("lower_bound", 1e8, 1e10),  # geometric middle of 100 MPa and 1 TPa
    ("upper_bound", 1e5, 1e4),  # geometric middle of 100 kPa and 1 kPa
    ("lower_bound", E_MAX_PA, E_MAX_PA),
    ("lower_bound", 2 * E_MAX_PA, 2 * E_MAX_PA),  # beyond the limit: the bound itself
    ("upper_bound", E_MIN_PA, E_MIN_PA),
    ("upper_bound", E_MIN_PA / 2, E_MIN_PA / 2),
])
def test_point_value_of_each_state(state, e_pa, point):
    assert point_value(state, e_pa) == pytest.approx(point, rel=1e-12)


def test_the_point_figures_use_the_point_value_and_ok_only_leaves_bounds_out():
    rows = [row(1e10, "lower_bound", 1e8, 1e8, None), row(1e4, "upper_bound", 1e5, None, 1e5),
            row(1e5, "ok", 1e6, 5e5, 2e6)]
    m = one(rows)
    assert m["log10_error"] == pytest.approx((2 + 1 + 1) / 3)
    assert m["point_log10_error"] == pytest.approx((0 + 0 + 1) / 3)
    assert m["within_10x"] == pytest.approx(2 / 3) and m["point_within_10x"] == 1.0  # one decade off is within 10x
    assert m["ok_only"] == {"n": 1, "log10_error": pytest.approx(1.0), "within_10x": 1.0}


def test_felt_log10_offset_is_signed_and_against_the_clipped_label():
    assert felt_log10_offset(1e5, 2e11, display_range_pa=DISPLAY) == pytest.approx(math.log10(1e5 / RIGID))
    assert felt_log10_offset(1e5, 2e11, display_range_pa=DISPLAY) < 0  # a rigid object felt softer
    assert felt_log10_offset(1e4, 1e2, display_range_pa=DISPLAY) == pytest.approx(math.log10(1e4 / SOFT))
    assert felt_log10_offset(4e5, 1e5, display_range_pa=DISPLAY) == pytest.approx(math.log10(4))
    assert felt_log10_error(2.5e4, 1e5, display_range_pa=DISPLAY) == pytest.approx(math.log10(4))


@pytest.mark.parametrize("estimate, covered", [
    (row(1e5, "ok", 2e5, 1e5, 4e5), True),  # on the low end
    (row(4e5, "ok", 2e5, 1e5, 4e5), True),  # on the high end
    (row(0.99e5, "ok", 2e5, 1e5, 4e5), False),
    (row(1e11, "lower_bound", 1e7, 1e7, None), True),  # open above
    (row(1e6, "lower_bound", 1e7, 1e7, None), False),
    (row(1e2, "upper_bound", 1e5, None, 1e5), True),  # open below
    (row(1e6, "upper_bound", 1e5, None, 1e5), False),
])
def test_interval_coverage_includes_the_ends_and_the_open_side(estimate, covered):
    assert one([estimate])["interval_coverage"] == float(covered)


def test_every_dangerous_miss_is_counted_not_only_the_last():
    rows = [row(2e11, "ok", 5e5, 2.5e5, 1e6), row(2e11, "ok", 2e5, 1e5, 4e5), row(1e5, "ok", 2e5, 1e5, 4e5)]
    m = one(rows)
    assert m["dangerous_misses"] == 2 and m["per_shape"]["sphere"]["dangerous_misses"] == 2


def test_the_groups_come_in_sorted_order():
    rows = [row(1e5, "ok", 2e5, 1e5, 4e5, material=material, shape=shape)
            for material, shape in (("rubber", "sphere"), ("foam", "cube"), ("metal", "cylinder"))]
    m = one(rows)
    assert list(m["per_material"]) == ["foam", "metal", "rubber"]
    assert list(m["per_shape"]) == ["cube", "cylinder", "sphere"]


def test_without_a_display_range_every_display_figure_is_there_and_none():
    m = summarise([row(2e11, "ok", 5e5, 2.5e5, 1e6)], ["series"])["series"]
    for key in FELT_KEYS:
        assert key in m and m[key] is None, key
    assert m["n"] == 1 and m["interval_coverage"] == 0.0


def _ablation_unseen(paper_tex: str) -> list[tuple[float, float]]:
    """The unseen objects' (log10 error, share within a decade) of each row of the paper's
    ablation table, in its order."""
    table = paper_tex[:paper_tex.index(r"\label{table:ablation}")]
    table = table[table.rindex(r"\begin{tabular}"):table.index(r"\end{tabular}", table.rindex(r"\begin{tabular}"))]
    rows = []
    for line in table.splitlines():
        cells = line.strip().removesuffix(r"\\").split("&")
        if len(cells) == 10 and ("checkmark" in line or "times" in line):
            error, share = (re.sub(r"\\textbf\{|\}|\\%", "", c).strip() for c in cells[-2:])
            rows.append((float(error), round(float(share) / 100, 3)))
    return rows


def test_the_papers_table_is_the_ablation_tables_figures(shared_dir):
    rows = _ablation_unseen((shared_dir / "seed" / "paper.tex").read_text())
    assert [(v["log10_error"], v["within_10x"]) for v in PAPER.values() if v is not None] == rows
    assert len(rows) == 11 and PAPER["series"] is None
    assert one([row(1e5, "ok", 2e5, 1e5, 4e5)])["paper"] is None  # series: the paper has none
    assert one([row(1e5, "ok", 2e5, 1e5, 4e5, method="hertz")], method="hertz")["paper"] == PAPER["hertz"]


def test_rows_of_other_methods_and_skipped_records_are_ignored():
    rows = [row(1e5, "ok", 2e5, 1e5, 4e5), row(2e11, "ok", 5e5, 2.5e5, 1e6, method="hertz"),
            {"path": "y.grasp", "object": "o", "skipped": "unlabelled"}]
    m = one(rows)
    assert m["n"] == 1 and m["dangerous_misses"] == 0 and sum(m["states"].values()) == 1
