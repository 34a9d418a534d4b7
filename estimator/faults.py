"""A sensor that cannot be right: timestamps in other units, a width that never moved, a dead camera.

Each check triggers only on data no working rig delivers, and says which stream and what was seen:

* a stream whose samples or frames come more than :data:`RATE_FACTOR` times faster or slower than
  the rig's rate (timestamps in nanoseconds or milliseconds, not seconds) refuses the grasp (force,
  width) or its tactile methods (frames): :func:`checked_phase`, :func:`checked_frames`;
* a gripper width of 0 m or less at the contact onset (no object fits between closed fingers), or
  widths that stay within :data:`STILL_WIDTH_M` over the whole record of a grasp that starts before contact
  (the fingers close onto the object before the force rises, whatever its stiffness), refuses the
  grasp: every estimate rests on the approach the widths give, the model's too;
* a tactile frame without texture (all black, all saturated: a dead camera or lost light),
  loading frames all bit-identical to the no-contact reference (a frozen camera: a live camera's
  noise alone changes every frame), or loading frames that all differ from the reference over
  most of their pixels by more than :data:`STILL_GEL_LEVELS` (pixel noise: outside a contact the
  gel does not change) refuses the tactile methods: :func:`camera_fault`.
"""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np

from estimator.load_phase import LoadPhase
from estimator.segment import Segment

__all__ = ["RATE_FACTOR", "STILL_GEL_LEVELS", "STILL_WIDTH_M", "TEXTURE_LEVELS", "camera_fault", "checked_frames", "checked_phase",
           "period_fault"]

RATE_FACTOR = 100.0
# Widths that move less than this over a whole record never moved: fingers
# that close onto an object from open travel millimetres.
STILL_WIDTH_M = 1e-4
# A frame whose pixels spread less than this (standard deviation, 8-bit levels) shows no gel: a lit
# gel's shading alone spreads them by tens of levels.
TEXTURE_LEVELS = 2.0
# A loading frame whose median pixel differs from the no-contact reference by more than this (8-bit
# levels) is not of a gel: at least the frame nearest the onset shows the gel still outside a small
# contact, within the camera's noise (a level or two; pure pixel noise differs by tens).
STILL_GEL_LEVELS = 10


def period_fault(t_s: np.ndarray, rate_hz: float, what: str) -> str:
    """Why the capture times ``t_s`` of ``what`` cannot be seconds of a stream at ``rate_hz``: their
    median step lies more than :data:`RATE_FACTOR` times off ``1 / rate_hz``; '' when it does not, or
    for fewer than three distinct finite times."""
    t = np.unique(np.asarray(t_s, dtype=np.float64))
    t = t[np.isfinite(t)]
    if t.size < 3:
        return ""
    with np.errstate(over="ignore"):  # a step beyond the float range is off all the same
        step = float(np.median(np.diff(t)))
    expected = 1.0 / rate_hz
    if expected / RATE_FACTOR <= step <= expected * RATE_FACTOR:
        return ""
    return (f"{what} come every {step:.3g} s (median step), the rig's {rate_hz:g} Hz gives {expected:.3g} s: "
            "timestamps not in seconds (nanoseconds, milliseconds?)")


def _width_fault(phase: LoadPhase) -> str:
    """Why the phase's widths cannot be a gripper's that closed on an object ('' when they can)."""
    onset_s, onset_width = phase.segment_fields["t_onset_s"], phase.segment_fields["onset_width_m"]
    if np.isfinite(onset_width) and onset_width <= 0:
        return (f"gripper width {onset_width:.3g} m at the contact onset: an object between the fingers keeps them "
                "apart (a dead width sensor, or widths not in metres?)")
    width = phase.width_m
    opens_before = phase.force_t_s[0] < onset_s and phase.width_t_s[0] < onset_s  # quiet force, widths read
    moved = float(np.ptp(width))
    # Not scaled by the width noise: an operator's moving fingers inflate that estimate to millimetres.
    if not opens_before or moved > STILL_WIDTH_M:
        return ""
    return (f"gripper widths stay within {moved * 1e3:.3g} mm of {float(np.median(width)) * 1e3:.4g} mm over the "
            f"whole record while the force rises from its baseline to {phase.segment_fields['peak_force_n']:.3g} N: "
            "fingers that close onto an object move before it (a stuck or dead width sensor?)")


def checked_phase(phase: LoadPhase, *, force_t_s: np.ndarray, width_t_s: np.ndarray, force_hz: float,
                  width_hz: float) -> LoadPhase:
    """``phase`` (found on force and width received at ``force_t_s`` and ``width_t_s``), or a refusal
    naming the stream when the force's or the width's rate is not the rig's (``force_hz``,
    ``width_hz``) or the widths cannot be a gripper's that closed on an object (module notes)."""
    rate = period_fault(force_t_s, force_hz, "force samples") or period_fault(width_t_s, width_hz, "width samples")
    width = "" if rate or not phase else _width_fault(phase)
    if not (rate or width):
        return phase
    flags = phase.flags if rate or "implausible_width" in phase.flags else (*phase.flags, "implausible_width")
    return LoadPhase(reason=rate or width, flags=flags, notes=phase.notes, force_baseline_n=phase.force_baseline_n)


def checked_frames(segment: Segment, frame_t_s: np.ndarray, *, camera_hz: float, finger: str) -> Segment:
    """``segment``, its frames refused (``frame_reason``) when their rate is not the camera's ``camera_hz``."""
    why = period_fault(frame_t_s, camera_hz, f"tactile frames of finger {finger!r}") if segment else ""
    return dataclasses.replace(segment, frame_reason=why) if why else segment


def camera_fault(reference: np.ndarray, frames: list[np.ndarray], frame_t_s: np.ndarray, finger: str) -> str:
    """Why the no-contact ``reference`` and loading ``frames`` (captured at ``frame_t_s``) of ``finger``
    cannot show its gel (module notes); '' when they can."""
    camera = f"the camera of finger {finger!r}"
    for image, what in ((reference, "the no-contact reference"),
                        *((f, f"the loading frame at {t:.3f} s") for f, t in zip(frames, frame_t_s, strict=True))):
        mean, std = cv2.meanStdDev(image.reshape(-1, 1))  # a twentieth of numpy's time: it runs per estimate
        level, spread = float(mean[0, 0]), float(std[0, 0])
        if spread < TEXTURE_LEVELS:
            seen = "black" if level < 16 else "saturated" if level > 239 else "one flat grey"
            return (f"{what} of {camera} has no texture: {seen} (mean level {level:.0f}, spread {spread:.2g}): "
                    "a dead camera or lost light")
    if frames and all(np.array_equal(f, reference) for f in frames):
        return (f"every loading frame of {camera} is bit-identical to its no-contact reference: a frozen camera "
                "(a live one's noise alone changes every frame)")
    # The first loading frame, nearest the onset, mostly clears it: the others are counted only for noise.
    if frames and all(_changed_share(f, reference) > 0.5 for f in frames):
        least = min(_changed_share(f, reference) for f in frames)
        return (f"every loading frame of {camera} differs from its no-contact reference by more than "
                f"{STILL_GEL_LEVELS} levels in {least:.0%} or more of its pixel values: pixel noise, not a gel "
                "(outside a contact the gel stays as in the reference)")
    return ""


def _changed_share(image: np.ndarray, reference: np.ndarray) -> float:
    """Share of the values of ``image`` more than :data:`STILL_GEL_LEVELS` off ``reference`` (over
    half: the median change is above it); counted, not sorted: it runs per estimate."""
    changed = cv2.absdiff(image, reference) > STILL_GEL_LEVELS
    return np.count_nonzero(changed) / changed.size
