"""What the display renders, scored: felt error, dangerous misses, interval widths as shown."""

from __future__ import annotations

import math

import pytest

from estimator.evaluation.metrics import (
    RIGID_TRUTH_PA,
    SOFT_SUBSET_MAX_PA,
    SOFT_TRUTH_PA,
    dangerous_miss,
    felt_pa,
    summarise,
)
from haptics.mapping import map_estimate, modulus_from_fraction
from haptics.settings import display_settings
from teleop.settings import load_settings

SOFT, RIGID = 5e3, 6.75e6  # the shipped display: the rigid end is the sensor's resolution limit
DISPLAY = (SOFT, RIGID)
FULL = math.log10(RIGID / SOFT)


def row(truth, state, e_pa=None, low=None, high=None, method="series", material="rubber", shape="sphere"):
    return {"path": "x.grasp", "object": "o", "material": material, "shape": shape, "truth_pa": truth,
            "method": method, "state": state, "e_pa": e_pa, "low_pa": low, "high_pa": high, "reason": "r"}


def one(rows, display=DISPLAY, method="series"):
    return summarise(rows, [method], display_range_pa=display)[method]


def test_an_estimate_twice_the_label_is_felt_log10_2_off_and_within_2x():
    m = one([row(1e5, "ok", 2e5, 1e5, 4e5)])
    assert m["felt_log10_error"] == pytest.approx(math.log10(2))
    assert m["felt_within_2x"] == 1.0
    assert m["dangerous_misses"] == 0
    three = one([row(1e5, "ok", 3e5, 1e5, 4e5)])
    assert three["felt_within_2x"] == 0.0 and three["felt_log10_error"] == pytest.approx(math.log10(3))


def test_a_lower_bound_at_the_rigid_end_feels_exactly_like_steel_can():
    m = one([row(2e11, "lower_bound", RIGID, RIGID, None, material="metal")])
    assert m["felt_log10_error"] == pytest.approx(0.0, abs=1e-12)  # steel clipped to the rigid end
    assert m["log10_error"] == pytest.approx(math.log10(2e11 / RIGID))  # the raw error is large
    assert m["felt_within_2x"] == 1.0 and m["dangerous_misses"] == 0


def test_a_rigid_object_felt_soft_is_a_dangerous_miss():
    m = one([row(2e11, "ok", 5e5, 2.5e5, 1e6)])
    assert m["dangerous_misses"] == 1
    assert m["felt_log10_error"] == pytest.approx(math.log10(RIGID / 5e5))
    assert one([row(2e11, "ok", 2e6, 1e6, 4e6)])["dangerous_misses"] == 0  # 2 MPa: not below 1 MPa


def test_rigid_shown_rigid_counts_the_rigid_objects_rendered_at_the_rigid_end():
    rigid_rows = [row(2e11, "lower_bound", RIGID, RIGID, None), row(1e9, "ok", 5e7, 2e7, 1e9),
                  row(2e11, "ok", 2e6, 1e6, 4e6), row(1e9, "ok", RIGID * 0.999999999, RIGID / 2, None)]
    m = one([*rigid_rows, row(5e5, "lower_bound", RIGID, RIGID, None)])  # a soft one shown rigid is not counted
    assert m["rigid_shown_rigid"] == pytest.approx(3 / 4)
    assert one([row(5e5, "ok", 5e5, 2.5e5, 1e6)])["rigid_shown_rigid"] is None


def test_a_soft_object_felt_rigid_is_a_dangerous_miss_even_below_10_mpa():
    # The rigid end (6.75 MPa) is below 10 MPa, so rendered rigid counts as "at or above 10 MPa".
    assert one([row(5e5, "lower_bound", RIGID, RIGID, None)])["dangerous_misses"] == 1
    assert one([row(5e5, "ok", 5e6, 2.5e6, 6e6)])["dangerous_misses"] == 0  # not rigid on this display
    wide = (SOFT, 1e9)
    assert one([row(5e5, "ok", 2e7, 1e7, 4e7)], wide)["dangerous_misses"] == 1
    assert one([row(5e5, "ok", 5e6, 2.5e6, 1e7)], wide)["dangerous_misses"] == 0
    assert one([row(2e6, "ok", 2e7, 1e7, 4e7)], wide)["dangerous_misses"] == 0  # 2 MPa is not soft


def test_dangerous_miss_thresholds():
    assert dangerous_miss(RIGID_TRUTH_PA, 0.99e6, e_rigid_pa=1e9)
    assert not dangerous_miss(RIGID_TRUTH_PA * 0.99, 1e4, e_rigid_pa=1e9)
    assert not dangerous_miss(RIGID_TRUTH_PA, 1e6, e_rigid_pa=1e9)
    assert dangerous_miss(SOFT_TRUTH_PA, 1e7, e_rigid_pa=1e9)
    assert not dangerous_miss(SOFT_TRUTH_PA * 1.01, 1e7, e_rigid_pa=1e9)
    assert dangerous_miss(SOFT_TRUTH_PA, RIGID, e_rigid_pa=RIGID)
    assert not dangerous_miss(SOFT_TRUTH_PA, RIGID * 0.99, e_rigid_pa=RIGID)
    # A display whose rigid end is below 1 MPa renders a rigid object at that end: no miss.
    assert not dangerous_miss(2e11, 5e5, e_rigid_pa=5e5)


def test_refusals_are_left_out_of_the_felt_figures():
    rows = [row(1e5, "ok", 2e5, 1e5, 4e5), row(2e11, "insufficient_data")]
    m = one(rows)
    assert m["n"] == 1 and m["felt_log10_error"] == pytest.approx(math.log10(2)) and m["dangerous_misses"] == 0
    assert felt_pa(rows[1], display_range_pa=DISPLAY) is None
    refused = one([row(2e11, "insufficient_data")])
    assert refused["felt_log10_error"] is None and refused["felt_within_2x"] is None
    assert refused["dangerous_misses"] == 0 and refused["interval_width_decades_median"] is None


def test_an_estimate_the_display_shows_as_unknown_is_left_out_of_the_felt_figures():
    # Intervals over the display's whole range place the object nowhere: shown unknown, as a refusal.
    whole = [row(2e11, "ok", 6.75e6, 1e2, 1e12), row(8e5, "ok", 6.75e6, 8e2, 1e12),
             row(2e11, "upper_bound", 1e9, None, 1e9), row(2e11, "lower_bound", 3e3, 3e3, None)]
    placed = row(1e5, "ok", 2e5, 1e5, 4e5)
    assert all(felt_pa(r, display_range_pa=DISPLAY) is None for r in whole)
    m = one([*whole, placed])
    assert m["n"] == 5 and m["shown_unknown"] == 4 and m["dangerous_misses"] == 0
    assert m["felt_log10_error"] == pytest.approx(math.log10(2))
    # A rigid object shown unknown is not shown rigid; the widths are as the display shows them.
    assert m["rigid_shown_rigid"] == 0.0 and m["interval_width_decades_median"] == pytest.approx(FULL)
    # Counted before: the soft cylinder felt rigid was a dangerous miss.
    assert one([placed])["shown_unknown"] == 0


def test_felt_is_what_the_display_mapping_renders():
    from haptics.mapping import EstimateUpdate

    for r in (row(1e5, "ok", 2e5, 1e5, 4e5), row(1e6, "upper_bound", 3e3, None, 3e3),
              row(1e6, "upper_bound", 3e6, None, 3e6), row(1e9, "lower_bound", 2e7, 2e7, None)):
        percept = map_estimate(EstimateUpdate(r["e_pa"], (r["low_pa"], r["high_pa"]), r["state"]),
                               e_soft_pa=SOFT, e_rigid_pa=RIGID)
        felt = felt_pa(r, display_range_pa=DISPLAY)
        assert felt == modulus_from_fraction(percept.stiffness, e_soft_pa=SOFT, e_rigid_pa=RIGID)
        assert SOFT <= felt <= RIGID
    assert felt_pa(row(1e6, "upper_bound", 3e3, None, 3e3), display_range_pa=DISPLAY) == SOFT
    assert felt_pa(row(1e9, "lower_bound", 2e7, 2e7, None), display_range_pa=DISPLAY) == RIGID


def test_interval_widths_are_clipped_to_the_display_range():
    rows = [
        row(1e5, "ok", 2e5, 1e5, 4e5),  # log10(4)
        row(1e5, "ok", 2e5, 1e3, 1e8),  # clipped: the whole range
        row(1e5, "upper_bound", 3e6, None, 3e6),  # open below: from the soft end
        row(2e11, "lower_bound", 2e7, 2e7, None),  # beyond the rigid end: nothing to show
        row(1e5, "insufficient_data"),  # left out
    ]
    m = one(rows)
    widths = sorted([math.log10(4), FULL, math.log10(3e6 / SOFT), 0.0])
    assert m["interval_width_decades_median"] == pytest.approx((widths[1] + widths[2]) / 2)
    assert one(rows[1:2])["interval_width_decades_median"] == pytest.approx(FULL)
    assert one(rows[3:4])["interval_width_decades_median"] == 0.0
    # The soft subset: labels at or below 3 MPa.
    assert m["soft_interval_width_decades_median"] == pytest.approx(math.log10(3e6 / SOFT))
    assert one(rows[3:4])["soft_interval_width_decades_median"] is None
    assert one([row(SOFT_SUBSET_MAX_PA, "ok", 2e6, 1e6, 4e6)])["soft_interval_width_decades_median"] is not None
    assert one([row(1.01 * SOFT_SUBSET_MAX_PA, "ok", 2e6, 1e6, 4e6)])["soft_interval_width_decades_median"] is None


def test_soft_objects_are_scored_on_their_own():
    # A foam felt 4x too stiff and a rubber felt right; the steel rendered rigid is exact but not soft.
    rows = [row(1e4, "ok", 4e4, 2e4, 8e4), row(1e6, "ok", 1e6, 5e5, 2e6), row(2e11, "lower_bound", 2e7, 2e7, None),
            row(5e4, "insufficient_data")]
    m = one(rows)
    assert m["soft_n"] == 2 and m["soft_felt_within_2x"] == 0.5
    assert m["soft_refused"] == 1  # the refused foam: not in soft_n
    assert m["soft_felt_log10_error"] == pytest.approx(math.log10(4) / 2)
    assert m["felt_log10_error"] == pytest.approx(math.log10(4) / 3)  # the rigid grasp dilutes the overall
    assert m["soft_interval_coverage"] == 0.5  # the foam's interval misses it
    assert one(rows[2:])["soft_felt_log10_error"] is None and one(rows[2:])["soft_interval_coverage"] is None


def test_soft_refusals_are_counted_beside_soft_n():
    # Refused: two soft grasps (one at exactly 3 MPa) and a rigid one; only the soft ones are soft_refused.
    rows = [row(1e4, "ok", 1e4, 5e3, 2e4), row(1e5, "insufficient_data"), row(SOFT_SUBSET_MAX_PA, "insufficient_data"),
            row(2e11, "insufficient_data"), row(1.01 * SOFT_SUBSET_MAX_PA, "insufficient_data")]
    m = one(rows)
    assert m["soft_n"] == 1 and m["soft_refused"] == 2
    assert m["states"]["insufficient_data"] == 4
    assert one(rows[1:2])["soft_n"] == 0 and one(rows[1:2])["soft_refused"] == 1
    assert one([])["soft_refused"] == 0


def test_felt_figures_per_material_and_only_with_a_display_range():
    rows = [row(1e5, "ok", 2e5, 1e5, 4e5), row(2e11, "ok", 5e5, 2.5e5, 1e6, material="metal")]
    m = one(rows)
    assert m["dangerous_misses"] == 1 and m["felt_within_2x"] == 0.5
    assert m["per_material"]["metal"]["dangerous_misses"] == 1
    assert m["per_material"]["rubber"]["felt_log10_error"] == pytest.approx(math.log10(2))
    assert m["per_shape"]["sphere"]["dangerous_misses"] == 1
    assert m["interval_level"] is None  # an analytical method states no coverage
    bare = summarise(rows, ["series"])["series"]
    assert bare["n"] == 2 and bare["log10_error"] == pytest.approx(m["log10_error"])
    for key in ("felt_log10_error", "felt_within_2x", "dangerous_misses", "interval_width_decades_median",
                "soft_interval_width_decades_median"):
        assert bare[key] is None and bare["per_material"]["metal"][key] is None


def test_interval_levels_are_carried_per_method():
    rows = [row(1e5, "ok", 2e5, 1e5, 4e5, method="hybrid"), row(1e5, "ok", 2e5, 1e5, 4e5)]
    summary = summarise(rows, ["series", "hybrid"], display_range_pa=DISPLAY, interval_levels={"hybrid": 0.9})
    assert summary["hybrid"]["interval_level"] == 0.9 and summary["series"]["interval_level"] is None


def test_the_shipped_display_range_resolves_its_rigid_end():
    display = display_settings(load_settings())
    assert display.e_soft_pa < display.e_rigid_pa < 1e8  # the sensor's limit, a few MPa
    m = one([row(2e11, "lower_bound", display.e_rigid_pa, display.e_rigid_pa, None)],
            (display.e_soft_pa, display.e_rigid_pa))
    assert m["felt_log10_error"] == pytest.approx(0.0, abs=1e-12)


def test_within_2x_means_a_factor_2_not_more():
    assert one([row(1e5, "ok", 2.2e5, 1e5, 3e5)])["felt_within_2x"] == 0.0


def test_the_soft_figures_stop_at_their_subset_limit():
    rows = [row(SOFT_SUBSET_MAX_PA, "ok", 3e6, 2e6, 4e6), row(1.07 * SOFT_SUBSET_MAX_PA, "ok", 3.2e6, 2e6, 4e6)]
    assert SOFT_SUBSET_MAX_PA == 3e6 and one(rows)["soft_n"] == 1


def test_a_label_at_the_rigid_threshold_counts_for_rigid_shown_rigid():
    rows = [row(RIGID_TRUTH_PA, "lower_bound", RIGID, RIGID), row(1.2 * RIGID_TRUTH_PA, "ok", 1e5, 5e4, 2e5)]
    assert RIGID_TRUTH_PA == 1e8 and one(rows)["rigid_shown_rigid"] == 0.5


def test_a_label_below_the_soft_end_rendered_there_is_no_felt_error():
    assert one([row(SOFT / 5, "ok", SOFT, SOFT / 2, 2 * SOFT)])["felt_log10_error"] == 0.0


def test_a_label_on_the_intervals_high_end_is_covered():
    assert one([row(2e5, "ok", 1e5, 5e4, 2e5)])["interval_coverage"] == 1.0
