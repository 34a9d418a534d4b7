"""The demo's closing felt figures where a miss is dangerous only one way round: a soft object felt at the
display's rigid end, a rigid one felt soft, and neither for one felt right."""

from __future__ import annotations

from support.outcomes import outcome

from teleop.system.demo_table import felt_figures, felt_summary, felt_text

RANGE = (5e3, 6.75e6)


def test_a_soft_object_felt_at_the_rigid_end_is_a_dangerous_miss():
    figures = felt_figures([(5e3, RANGE[1])], RANGE, grasps=1)
    assert (figures["dangerous_misses"], figures["within_2x"]) == (1, 0)


def test_a_rigid_object_felt_soft_is_a_dangerous_miss_and_one_felt_rigid_is_right():
    assert felt_figures([(2e11, 2e4)], RANGE, grasps=1)["dangerous_misses"] == 1
    right = felt_figures([(2e11, RANGE[1]), (5e3, 5e3)], RANGE, grasps=3)
    assert right == {"grasps": 3, "rendered": 2, "not_rendered": 1, "mean_error_decades": 0.0, "within_2x": 2,
                     "dangerous_misses": 0}


def test_the_summary_of_a_foam_rendered_rigid_says_the_dangerous_miss():
    foam = outcome("foam", 5e3, {"E_pa": 1e9, "interval_pa": [1e9, None], "state": "lower_bound"}, 0.1, 100.0,
                   display_range=RANGE)
    figures = felt_summary([foam])
    assert figures["dangerous_misses"] == 1 and figures["within_2x"] == 0
    assert felt_text(figures).endswith("0 of 1 within a factor 2, 1 dangerous misses")
