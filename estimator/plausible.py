"""What a gripper's force and width readings can be: the ones it cannot produce, and the least
noise a reading carries. :func:`~estimator.load_phase.find_load_phase` drops or refuses the first
and takes the second as its noise floors.

A width below 0 or beyond the gripper's opening by more than :data:`WIDTH_SLACK_SHARE` of it is
a glitch, or not in metres. The gripper stops at its maximum grasp force, so a force beyond
:data:`FORCE_LIMIT_FACTOR` times it (either sign) is a glitch, or not in newtons (a load cell
scaled per gram): up to :data:`FORCE_GLITCHES` such readings are dropped, more refuse the grasp (with a
limit from the reader's settings, for a record that states no gripper, the refusal says so:
:func:`unstated_gripper`).
A force that never reaches the contact force but falls beyond it below zero is a load cell read
with its sign reversed (:func:`reversed_force`), not a grasp without contact.
"""

from __future__ import annotations

import numpy as np

__all__ = ["FORCE_GLITCHES", "FORCE_LIMIT_FACTOR", "MIN_FORCE_NOISE_N", "MIN_WIDTH_NOISE_M", "REST_SAMPLES",
           "SCALE_QUESTION", "WIDTH_SLACK_SHARE", "implausible_forces", "implausible_widths", "reversed_force",
           "unstated_gripper"]

WIDTH_SLACK_SHARE = 0.1
FORCE_LIMIT_FACTOR = 2.0
FORCE_GLITCHES = 2
SCALE_QUESTION = "is the load cell's scale (counts_per_n) in newtons?"  # ends a refusal of implausible forces
# The least noise a force or width reading is taken to carry (below any load cell or gripper simulated or
# seen): exact readings would otherwise give bounds at absurd moduli (1e20 Pa) and intervals of zero width.
MIN_FORCE_NOISE_N = 1e-3
MIN_WIDTH_NOISE_M = 1e-6
REST_SAMPLES = 10  # the first force samples of a grasp, taken before contact: the cell's reading at rest


def implausible_widths(width_m: np.ndarray, *, max_width_m: float) -> tuple[np.ndarray, str]:
    """The widths (m) no gripper opening ``max_width_m`` reads, as a mask, and a note naming them
    ('' when there are none)."""
    slack = WIDTH_SLACK_SHARE * max_width_m
    outside = (width_m < -slack) | (width_m > max_width_m + slack)
    if not outside.any():
        return outside, ""
    return outside, (f"dropped {int(outside.sum())} width samples outside the gripper's 0-{max_width_m:.4g} m "
                     f"opening (from {width_m[outside].min():.4g} to {width_m[outside].max():.4g} m: a glitch, "
                     "or not in metres?)")


def implausible_forces(force_n: np.ndarray, *, max_force_n: float) -> tuple[np.ndarray, str, bool]:
    """The forces (N) a gripper of maximum grasp force ``max_force_n`` cannot apply, as a mask; a
    note naming them ('' when there are none); and whether they are more than glitches, so that
    the grasp is refused (the note is then the reason)."""
    limit = FORCE_LIMIT_FACTOR * max_force_n
    beyond = np.abs(force_n) > limit
    told = f"beyond {limit:.4g} N, {FORCE_LIMIT_FACTOR:g} times the gripper's maximum grasp force"
    if beyond.sum() > FORCE_GLITCHES:
        return beyond, (f"{int(beyond.sum())} force samples ({np.abs(force_n).max():.4g} N at most) {told}: "
                        f"{SCALE_QUESTION}"), True
    return beyond, (f"dropped {int(beyond.sum())} force samples {told} (a glitch)" if beyond.any() else ""), False


def unstated_gripper(reason: str) -> str:
    """``reason``, a refusal of :func:`implausible_forces` whose limit came from the reader's settings as
    the record states no gripper, saying so: the settings' gripper may not be the one that made the record
    (another ``target_force_n``), so the load cell's scale is not the only suspect. Any other reason is
    returned as it is."""
    if not reason.endswith(SCALE_QUESTION):
        return reason
    return (f"{reason.removesuffix(SCALE_QUESTION)}the limit is the settings' gripper's (the record states none): "
            f"is that the grasp's gripper (its target_force_n)? {SCALE_QUESTION}")


def reversed_force(force_n: np.ndarray, *, contact_force_n: float) -> str:
    """Why the forces (N) read as a load cell with its sign reversed, or '': from their reading at rest
    (the median of the first :data:`REST_SAMPLES`), they fall by ``contact_force_n`` or more and never
    rise by as much. A cell offset at rest (untared) is no reversed one, nor is a record that starts in
    contact (its first samples at or above ``contact_force_n``). Non-finite forces are ignored."""
    finite = force_n[np.isfinite(force_n)]
    if finite.size == 0:
        return ""
    rest = float(np.median(finite[:REST_SAMPLES]))
    if rest >= contact_force_n:
        return ""  # the record starts in contact: no reading at rest to fall from
    if finite.max() - rest >= contact_force_n or not finite.min() - rest <= -contact_force_n:
        return ""
    return (f"the force falls to {finite.min():.3g} N from {rest:.3g} N at rest and never rises by "
            f"contact_force_n = {contact_force_n:g} N (it peaks at {finite.max():.3g} N): is the load cell's "
            "sign reversed?")
