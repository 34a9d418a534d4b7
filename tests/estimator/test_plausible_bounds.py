"""Where estimator.plausible draws its lines: a width within its slack of the opening (either side) is kept and
one past it dropped, a force at exactly the limit is a force, the notes name what was dropped; a refusal for a
record that states no gripper says whose limit it was; a load cell reads as reversed from its own reading at rest
(the first REST_SAMPLES, non-finite readings ignored), by exactly the contact force or more."""

from __future__ import annotations

import numpy as np

from estimator.plausible import (
    REST_SAMPLES,
    SCALE_QUESTION,
    WIDTH_SLACK_SHARE,
    implausible_forces,
    implausible_widths,
    reversed_force,
    unstated_gripper,
)

MAX_WIDTH_M, MAX_FORCE_N, CONTACT_N = 0.08, 30.0, 0.75


# --------------------------------------------------------------------------- widths


def test_a_width_within_its_slack_either_side_is_kept():
    slack = WIDTH_SLACK_SHARE * MAX_WIDTH_M
    width = np.full(50, 0.04)
    width[[1, 2, 3, 4]] = -0.5 * slack, -slack, MAX_WIDTH_M + slack, MAX_WIDTH_M * 1.09
    mask, note = implausible_widths(width, max_width_m=MAX_WIDTH_M)
    assert not mask.any() and note == ""


def test_a_width_a_little_past_its_slack_is_dropped():
    width = np.full(50, 0.04)
    width[[5, 6]] = MAX_WIDTH_M * 1.12, -MAX_WIDTH_M * 0.12
    mask, _ = implausible_widths(width, max_width_m=MAX_WIDTH_M)
    assert np.flatnonzero(mask).tolist() == [5, 6]


def test_the_width_note_gives_the_range_of_the_dropped_widths_alone():
    width = np.full(50, 0.04)
    width[[8, 9]] = 0.5, 0.25
    _, note = implausible_widths(width, max_width_m=MAX_WIDTH_M)
    assert "dropped 2 width samples outside the gripper's 0-0.08 m opening (from 0.25 to 0.5 m" in note


# --------------------------------------------------------------------------- forces


def test_a_force_at_exactly_the_limit_is_a_force():
    force = np.full(100, 5.0)
    force[[10, 20, 30]] = 2.0 * MAX_FORCE_N, -2.0 * MAX_FORCE_N, 2.0 * MAX_FORCE_N
    mask, note, refused = implausible_forces(force, max_force_n=MAX_FORCE_N)
    assert not mask.any() and note == "" and not refused


def test_a_refusal_names_the_largest_force_of_either_sign():
    force = np.full(100, 5.0)
    force[[10, 20, 30]] = 100.0, -5000.0, 200.0
    _, reason, refused = implausible_forces(force, max_force_n=MAX_FORCE_N)
    assert refused and reason.startswith("3 force samples (5000 N at most) beyond 60 N") and reason.endswith(
        SCALE_QUESTION)


def test_a_refusal_for_a_record_that_states_no_gripper_says_whose_limit_it_was():
    force = np.full(100, 5.0)
    force[[10, 20, 30]] = 1e4
    _, reason, _ = implausible_forces(force, max_force_n=MAX_FORCE_N)
    told = unstated_gripper(reason)
    assert told.startswith(reason.removesuffix(SCALE_QUESTION)) and told.endswith(SCALE_QUESTION)
    assert "the limit is the settings' gripper's (the record states none): is that the grasp's gripper" in told
    other = "dropped 1 force samples beyond 60 N, 2 times the gripper's maximum grasp force (a glitch)"
    assert unstated_gripper(other) == other and unstated_gripper("") == ""


# --------------------------------------------------------------------------- a reversed load cell


def falling(rest_n: float, low_n: float, *, peak_n: float | None = None) -> np.ndarray:
    """At ``rest_n`` for the first samples, then down to ``low_n`` (after rising to ``peak_n`` when given)."""
    rise = [] if peak_n is None else [peak_n]
    return np.r_[np.full(REST_SAMPLES + 5, rest_n), rise, np.linspace(rest_n, low_n, 20), np.full(10, low_n)]


def test_a_fall_of_exactly_the_contact_force_reads_as_reversed():
    assert "sign reversed" in reversed_force(falling(0.0, -CONTACT_N), contact_force_n=CONTACT_N)


def test_a_rise_of_exactly_the_contact_force_is_contact_not_a_reversed_cell():
    assert reversed_force(falling(0.0, -1.0, peak_n=CONTACT_N), contact_force_n=CONTACT_N) == ""


def test_a_record_resting_at_exactly_the_contact_force_starts_in_contact():
    assert reversed_force(falling(CONTACT_N, -1.0), contact_force_n=CONTACT_N) == ""


def test_an_untared_cell_is_judged_from_its_reading_at_rest():
    # At rest 0.5 N (untared, below the contact force), falling by 1 N: reversed.
    assert "sign reversed" in reversed_force(falling(0.5, -0.5), contact_force_n=CONTACT_N)
    # At rest -1 N, rising by 1 N to 0 N (contact: by the contact force from rest, below it absolutely).
    assert reversed_force(falling(-1.0, -2.0, peak_n=0.0), contact_force_n=CONTACT_N) == ""


def test_the_reading_at_rest_is_the_median_of_the_first_rest_samples():
    # The first REST_SAMPLES: 4 at 0 N and 6 at -0.5 N, median -0.5 N; then -1 N, a fall of 0.5 N from rest only.
    force = np.r_[np.zeros(4), np.full(REST_SAMPLES - 4, -0.5), np.full(30, -1.0)]
    assert reversed_force(force, contact_force_n=CONTACT_N) == ""


def test_non_finite_forces_are_ignored():
    force = falling(0.0, -1.0)
    force[[3, 30]] = np.nan, np.inf
    assert "sign reversed" in reversed_force(force, contact_force_n=CONTACT_N)
    assert reversed_force(np.array([np.nan, np.inf]), contact_force_n=CONTACT_N) == ""
    assert reversed_force(np.zeros(0), contact_force_n=CONTACT_N) == ""
