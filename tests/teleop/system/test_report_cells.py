"""``teleop report``'s cells and page pieces, one grasp at a time: bounds and open interval ends, what
the display rendered (free, unknown, rigid), the felt error of unlabelled and unknown renderings, the
closing felt line, the summary's numeric columns, anchors at the length limit and a grasp's facts."""

from __future__ import annotations

import html
import re

import pytest

from teleop.system.report import (
    DASH,
    INFINITY,
    _anchor,
    _display_cell,
    _felt_cell,
    _felt_line,
    _felt_pa,
    _final_cell,
    _grasp_section,
    _interval_cell,
    _summary,
)
from teleop.system.report_data import DisplayPoint, EstimatePoint, GraspView

RANGE = (5e3, 6.75e6)  # the shipped display's (e_soft_pa, e_rigid_pa)


def _estimate(e_pa, interval, state="ok", *, provisional=False, t_s=1.0, reason="test", method="auto"):
    return EstimatePoint(t_s, e_pa, interval, state, reason, provisional, method)


def _finished(e_pa, interval, state="ok", **view) -> GraspView:
    grasp = GraspView("g", **view)
    grasp.estimates = [_estimate(e_pa, interval, state)]
    return grasp


def _shown(stiffness, e_pa, *, rigid=False, unknown=False, provisional=False, phase="active", t_s=1.0):
    return DisplayPoint(t_s, phase, stiffness, e_pa, rigid, unknown, provisional)


def test_bounds_are_marked_with_their_side():
    assert _final_cell(_finished(6.75e6, (6.75e6, None), "lower_bound")) == "\u2265 6.75e+06 Pa"
    assert _final_cell(_finished(1e4, (None, 1e4), "upper_bound")) == "\u2264 1e+04 Pa"
    assert _final_cell(_finished(2e6, (1e6, 4e6))) == "2e+06 Pa"
    assert _final_cell(_finished(None, (None, None), "insufficient_data")) == DASH
    assert _final_cell(GraspView("g")) == "no final estimate"


def test_open_interval_ends_read_zero_and_infinity_and_no_interval_a_dash():
    assert _interval_cell(_finished(6.75e6, (6.75e6, None), "lower_bound")) == f"[6.75e+06, {INFINITY}] Pa"
    assert _interval_cell(_finished(1e4, (None, 1e4), "upper_bound")) == "[0, 1e+04] Pa"
    assert _interval_cell(_finished(1.23456e6, (1e6, 4e6))) == "[1e+06, 4e+06] Pa"
    assert _interval_cell(_finished(None, (None, None), "insufficient_data")) == DASH
    assert _interval_cell(GraspView("g")) == DASH


def test_the_display_cell_says_free_unknown_rigid_or_the_fraction_and_its_modulus():
    grasp = GraspView("g")
    assert _display_cell(grasp, False, RANGE) == "not recorded"
    assert _display_cell(grasp, True, RANGE) == "nothing for this grasp"
    grasp.display = [_shown(0.0, None)]  # free: stiffness 0, no modulus
    assert _display_cell(grasp, True, RANGE) == "0.00 of range"
    grasp.display = [_shown(0.625, 2.1e5)]
    assert _display_cell(grasp, True, RANGE) == "0.62 of range (~2.1e+05 Pa)"
    grasp.display = [_shown(1.0, 6.75e6, rigid=True, unknown=True)]  # unknown wins over rigid
    assert _display_cell(grasp, True, RANGE) == "unknown (free)"


def test_what_the_display_rendered_is_felt_at_its_modulus_its_soft_end_when_free_and_never_when_unknown():
    grasp = _finished(2e5, (1e5, 4e5), label_pa=1e5)
    assert _felt_pa(grasp, True, RANGE) is None and _felt_cell(grasp, True, RANGE) == "not rendered"
    grasp.display = [_shown(0.0, None)]
    assert _felt_pa(grasp, True, RANGE) == RANGE[0]  # free: the display's soft end
    grasp.display = [_shown(0.5, 2e5)]
    assert _felt_pa(grasp, True, RANGE) == 2e5
    grasp.display = [_shown(1.0, 6.75e6, rigid=True, unknown=True)]
    assert _felt_pa(grasp, True, RANGE) is None
    assert _felt_cell(grasp, True, RANGE) == "shown unknown"


def test_without_the_display_recorded_the_felt_modulus_is_the_mappings_of_the_final_estimate():
    from estimator.evaluation.metrics import felt_pa

    grasp = _finished(2e6, (1e6, 3e6), label_pa=3e6)
    expected = felt_pa({"state": "ok", "e_pa": 2e6, "low_pa": 1e6, "high_pa": 3e6}, display_range_pa=RANGE)
    assert _felt_pa(grasp, False, RANGE) == pytest.approx(expected)
    assert _felt_pa(_finished(None, (None, None), "insufficient_data", label_pa=3e6), False, RANGE) is None
    assert _felt_cell(_finished(None, (None, None), "insufficient_data", label_pa=3e6), False, RANGE) == DASH


def test_an_unlabelled_grasp_has_no_felt_error_and_is_not_counted_in_the_felt_line():
    unlabelled = _finished(2e6, (1e6, 4e6))
    unlabelled.display = [_shown(0.5, 2e6)]
    labelled = _finished(2e6, (1e6, 4e6), label_pa=2e6)
    labelled.display = [_shown(0.5, 2e6)]
    assert _felt_cell(unlabelled, True, RANGE) == DASH
    assert _felt_cell(labelled, True, RANGE) == "+0.00"
    line = html.unescape(_felt_line([unlabelled, labelled], True, RANGE))
    assert line == ("<p>Felt (display against the label on its range): mean error 0.00 decades, "
                    "1 of 1 within a factor 2, 0 dangerous misses.</p>")
    assert _felt_line([unlabelled], True, RANGE) == ""  # nothing labelled: no line at all


def test_the_summarys_numeric_columns_are_right_aligned():
    grasp = _finished(2e6, (1e6, 4e6), label_pa=2e6, object_name="duck")
    grasp.display = [_shown(0.5, 2e6)]
    (row,) = re.findall(r"<tbody><tr>(.*?)</tr>", _summary([grasp], True, RANGE))
    cells = re.findall(r"<td([^>]*)>", row)
    assert [k for k, attrs in enumerate(cells) if 'class="num"' in attrs] == [2, 3, 7]


def test_an_id_of_exactly_the_anchor_limit_stays_as_it_is_and_one_more_character_is_hashed():
    at_limit, over = "a" * 64, "a" * 65
    assert _anchor(GraspView(at_limit)) == f"grasp-{at_limit}"
    assert _anchor(GraspView(over)).startswith(f"grasp-{at_limit}.") and over not in _anchor(GraspView(over))


def _facts(section: str) -> dict[str, str]:
    return {html.unescape(k): html.unescape(v)
            for k, v in re.findall(r"<tr><th>(.*?)</th><td[^>]*>(.*?)</td></tr>", section)}


def test_a_grasps_facts_count_provisional_estimates_and_give_the_final_method_and_reason():
    grasp = GraspView("g", object_name="duck", label_pa=3e6, label_source="catalogue")
    grasp.estimates = [_estimate(2e6, (1e6, 5e6), provisional=True, method="series"),
                       _estimate(2.5e6, (1e6, 5e6), provisional=True, method="series"),
                       _estimate(3e6, (1.5e6, 6e6), reason="converged on the label", method="fused")]
    facts = _facts(_grasp_section(grasp, {}, recorded=False, display_range=RANGE))
    assert facts["estimates"] == "3 (2 provisional)"
    assert facts["final estimate"] == "3e+06 Pa (fused)"
    assert facts["reason"] == "converged on the label"
    assert facts["final state"] == "ok" and facts["label E"] == "3e+06 Pa (catalogue)"
    assert facts["display rendered"] == "not recorded"


def test_a_grasp_without_frames_says_why_and_its_timeline_caption_says_what_the_display_rendered():
    bare = GraspView("g", reason="the log stops before the grasp's end event")
    section = html.unescape(_grasp_section(bare, {}, recorded=True, display_range=RANGE))
    assert "No frames, force or width to show: the log stops before the grasp's end event." in section
    assert _facts(section)["reason"] == DASH and _facts(section)["final state"] == "no final estimate"
    shown = GraspView("g")
    shown.display = [_shown(0.4, 3e6)]
    figures = {"grasp-g-timeline.png": (1300, 900)}
    caption = html.unescape(_grasp_section(shown, figures, recorded=True, display_range=RANGE))
    assert "the bottom panel (fraction of its range)" in caption
    unshown = html.unescape(_grasp_section(GraspView("g"), figures, recorded=True, display_range=RANGE))
    assert "What the display rendered: nothing for this grasp." in unshown and "bottom panel" not in unshown
    assert "No frames" not in unshown
