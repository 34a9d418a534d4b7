"""``teleop demo --json``'s ``summary``: the figures of the closing table's felt line, from one computation."""

from __future__ import annotations

import json
import re

import pytest
from support.outcomes import outcome

from haptics.settings import display_settings
from teleop.settings import load_settings
from teleop.system.demo_table import closing_table, felt_summary

FELT = re.compile(r"felt \(display against the label on its range\): mean error (?P<mean>-?\d+\.\d\d) decades, "
                  r"(?P<within>\d+) of (?P<grasps>\d+) within a factor 2, (?P<misses>\d+) dangerous misses"
                  r"(?:, (?P<unrendered>\d+) not rendered)?")
NONE = re.compile(r"the display rendered none of (?P<grasps>\d+) grasps")


def _stated(line: str) -> dict:
    """The figures ``line`` states, as the summary gives them (the mean to the line's two places)."""
    if (none := NONE.fullmatch(line)) is not None:
        grasps = int(none["grasps"])
        return {"grasps": grasps, "rendered": 0, "not_rendered": grasps, "mean_error_decades": None,
                "within_2x": None, "dangerous_misses": None}
    felt = FELT.fullmatch(line)
    assert felt is not None, line
    grasps, unrendered = int(felt["grasps"]), int(felt["unrendered"] or 0)
    return {"grasps": grasps, "rendered": grasps - unrendered, "not_rendered": unrendered,
            "mean_error_decades": felt["mean"], "within_2x": int(felt["within"]),
            "dangerous_misses": int(felt["misses"])}


def _shown(summary: dict) -> dict:
    """``summary`` through JSON (``allow_nan=False``, as the demo prints it), its mean to two places."""
    read = json.loads(json.dumps(summary, allow_nan=False))
    mean = read["mean_error_decades"]
    return {**read, "mean_error_decades": None if mean is None else f"{mean:.2f}"}


@pytest.fixture(scope="module")
def shipped() -> tuple[float, float]:
    settings = load_settings()
    return display_settings(settings).e_soft_pa, settings.resolution_limit_pa


def test_the_summary_states_what_the_felt_line_says(shipped):
    soft, limit = shipped
    # A metal at the sensor's resolution limit, shown rigid: exact.
    steel = outcome("steel", 2e11, {"E_pa": limit, "interval_pa": [limit, None], "state": "lower_bound"}, 0.05,
                    120.0, display_range=shipped)
    # A metal the display rendered a tenth of the way up its range: felt soft, a dangerous miss.
    missed = outcome("bearing", 2e11, {"E_pa": limit, "interval_pa": [limit, None], "state": "lower_bound"}, 0.05,
                     120.0, display_range=shipped)
    missed.renderer_report = {"latency_ms": 120.0, "display_fraction": 0.1, "rigid": False, "unknown": False}
    # A soft object halfway up the range, and a refusal (shown unknown: not rendered).
    duck = outcome("duck", 1e6, {"E_pa": 8e5, "interval_pa": [5e5, 1.3e6], "state": "ok"}, 0.1, 150.0,
                   display_range=shipped)
    duck.renderer_report = {"latency_ms": 150.0, "display_fraction": 0.5, "rigid": False, "unknown": False}
    refused = outcome("foam", 5e3, {"E_pa": None, "interval_pa": [None, None], "state": "insufficient_data"},
                      None, None, display_range=shipped)
    outcomes = [steel, missed, duck, refused]
    summary = felt_summary(outcomes)
    line = closing_table(outcomes).splitlines()[-2]
    assert _shown(summary) == _stated(line)
    # What it says, worked out here: only the rigid steel is within a factor 2, the soft-felt metal is
    # the one dangerous miss.
    errors = [o.felt_log10_error for o in outcomes[:3]]
    assert summary == {"grasps": 4, "rendered": 3, "not_rendered": 1,
                       "mean_error_decades": pytest.approx(sum(errors) / 3), "within_2x": 1, "dangerous_misses": 1}
    assert steel.felt_log10_error == 0.0 and soft < missed.display_e_pa < 1e6


def test_a_summary_of_no_rendering_has_nulls_where_the_line_states_nothing(shipped):
    refused = outcome("foam", 5e3, {"E_pa": None, "interval_pa": [None, None], "state": "insufficient_data"},
                      None, None, display_range=shipped)
    lost = outcome("duck", 1e6, None, None, None, display_range=shipped)  # no final estimate at all
    summary = felt_summary([refused, lost])
    assert closing_table([refused, lost]).splitlines()[-2] == "the display rendered none of 2 grasps"
    assert _shown(summary) == _stated("the display rendered none of 2 grasps") == summary
    assert summary["mean_error_decades"] is None and summary["dangerous_misses"] is None
