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
  noise alone changes every frame), or loading frames that all lost the reference's spatial
  structure (pixel noise: averaged over :data:`STRUCTURE_CELL_PX` cells, each correlates with the
  reference by less than :data:`STRUCTURE_CORRELATION`; not judged on a reference flatter than
  :data:`FLAT_CELL_LEVELS` at that scale) refuses the tactile methods: :func:`camera_fault`.
"""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np

from estimator.load_phase import LoadPhase
from estimator.segment import Segment

__all__ = ["FLAT_CELL_LEVELS", "RATE_FACTOR", "STILL_WIDTH_M", "STRUCTURE_CELL_PX", "STRUCTURE_CORRELATION",
           "TEXTURE_LEVELS", "camera_fault", "checked_frames", "checked_phase", "period_fault"]

RATE_FACTOR = 100.0
# Widths that move less than this over a whole record never moved: fingers
# that close onto an object from open travel millimetres.
STILL_WIDTH_M = 1e-4
# A frame whose pixels spread less than this (standard deviation, 8-bit levels) shows no gel: a lit
# gel's shading alone spreads them by tens of levels.
TEXTURE_LEVELS = 2.0
# Grey frames averaged over square cells of this side (px) keep the gel's shading, vignette and LED
# gradients while the camera's noise averages out (64 px divide its s.d. by 8).
STRUCTURE_CELL_PX = 8
# A reference whose cell means spread less than this (s.d., 8-bit levels) gives nothing to correlate
# with. Measured: a gel's 6.2 (the simulator), 10 and 15 (the GelSight rigs); a reference of pure
# noise frames, already averaged by the median and the depth grid's binning, 1.4 to 2.3.
FLAT_CELL_LEVELS = 0.5
# A loading frame whose cell means correlate with the reference's (Pearson: blind to exposure and
# gain) by less than this shows no gel. Measured (first loading frame; late frames of a stiff object
# in brackets): pure uint8 noise, synthetic or in simulated records, -0.16 to 0.16 (315 cells of
# 125 x 175 px); the simulator at camera_noise 2, 30 and 50: 0.93-1.00, 0.96-0.97, 0.92-0.94 (steel
# ball: 0.65; squeezed to 60 N: 0.52); configs/rigs/gelsight.toml and gelsight_mini.toml: 0.99 or
# more (0.75); a 12-level shift or a 1.3x gain changes them by 0.002 at most.
STRUCTURE_CORRELATION = 0.3


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
    structure = _cell_means(reference)
    if not frames or float(structure.std()) < FLAT_CELL_LEVELS:
        return ""
    best = -1.0
    for image in frames:  # in loading order: the frame nearest the onset passes, and ends the check
        best = max(best, _correlation(_cell_means(image), structure))
        if best >= STRUCTURE_CORRELATION:
            return ""
    return (f"every loading frame of {camera} lost the spatial structure of its no-contact reference (over "
            f"{STRUCTURE_CELL_PX} px cells, correlation {best:.2f} at most, a gel's stays above "
            f"{STRUCTURE_CORRELATION:g}): pixel noise, not a gel")


def _cell_means(image: np.ndarray) -> np.ndarray:
    """Grey means (float32) of the whole :data:`STRUCTURE_CELL_PX` cells of the BGR ``image``."""
    grey = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    rows, cols = (max(1, n // STRUCTURE_CELL_PX) for n in grey.shape)  # a frame under a cell: one, flat
    whole = grey[:rows * STRUCTURE_CELL_PX, :cols * STRUCTURE_CELL_PX].astype(np.float32)  # exact cells: none overlap
    return cv2.resize(whole, (cols, rows), interpolation=cv2.INTER_AREA)


def _correlation(a: np.ndarray, b: np.ndarray) -> float:
    """Pearson correlation of the values of ``a`` and ``b``; 0 when either is flat."""
    a, b = a - a.mean(), b - b.mean()
    norm = float(np.sqrt(np.dot(a.ravel(), a.ravel()) * np.dot(b.ravel(), b.ravel())))
    return float(np.dot(a.ravel(), b.ravel())) / norm if norm else 0.0
