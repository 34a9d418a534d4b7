"""Readings no gripper produces (estimator.plausible): where a glitch ends and a refusal begins, and when
a falling force is a load cell with its sign reversed."""

from __future__ import annotations

import numpy as np

from estimator.plausible import implausible_forces, implausible_widths, reversed_force

MAX_WIDTH_M, MAX_FORCE_N = 0.08, 30.0


def test_two_force_glitches_are_dropped_and_a_third_refuses_the_grasp():
    force = np.full(100, 5.0)
    force[[10, 50]] = 1e4
    mask, note, refused = implausible_forces(force, max_force_n=MAX_FORCE_N)
    assert not refused and np.flatnonzero(mask).tolist() == [10, 50]
    assert note.startswith("dropped 2 force samples beyond 60 N")
    force[70] = -1e4  # either sign
    mask, reason, refused = implausible_forces(force, max_force_n=MAX_FORCE_N)
    assert refused and int(mask.sum()) == 3 and reason.startswith("3 force samples")


def test_a_negative_width_is_dropped():
    width = np.full(50, 0.04)
    width[7] = -0.05
    mask, note = implausible_widths(width, max_width_m=MAX_WIDTH_M)
    assert np.flatnonzero(mask).tolist() == [7] and note.startswith("dropped 1 width samples")


def test_a_width_beyond_the_opening_is_dropped_only_past_its_slack():
    # The slack is a tenth of the opening: a gripper may read a little past it, not a fifth.
    width = np.full(50, 0.04)
    width[3] = MAX_WIDTH_M * 1.2
    width[4] = MAX_WIDTH_M * 1.05
    mask, _ = implausible_widths(width, max_width_m=MAX_WIDTH_M)
    assert np.flatnonzero(mask).tolist() == [3]


def test_a_record_that_starts_in_contact_and_releases_is_no_reversed_load_cell():
    force = np.r_[np.full(20, 5.0), np.linspace(5.0, 0.0, 30), np.zeros(20)]  # starts squeezed, then released
    assert reversed_force(force, contact_force_n=0.75) == ""


def test_a_force_falling_by_more_than_the_contact_force_reads_as_a_reversed_load_cell():
    force = np.r_[np.zeros(20), np.linspace(0.0, -1.0, 30), np.full(20, -1.0)]  # falls by 1.33 x contact force
    assert "sign reversed" in reversed_force(force, contact_force_n=0.75)
