"""Grasp segmentation: the tactile frames aligned on a grasp's loading phase (found by
:mod:`estimator.load_phase`, whose notes define onset, contact, loading phase and envelope):
the loading frames, the peak frame, the hold frames, and the frames sampled from them.

Each stream of a grasp (load-cell force, gripper width, tactile frames) keeps its own
timestamps on one clock. Nothing here matches samples by index: force and width are
interpolated at the frames' capture times, never extrapolated; frames with a non-finite
timestamp are skipped, and so is a frame whose capture time is not after an earlier frame's
(:func:`unplaced_frames`: out of order or duplicated, it cannot be placed; the notes count them).

Terms
-----
loading frames
    The frames captured during the loading phase (on its envelope when it has one), and the
    *peak frame*: the
    first frame captured after the peak, within ``PEAK_FRAME_WINDOW_S`` and
    while the force still holds (as for the hold, below): force samples up to
    a sample at or after it show that, or the gripper has reported when its
    fingers stopped (then the force holds until the release). The fingers
    stand still from the peak on, so that frame shows the peak state, and its
    force and width are those at the peak. A stiff object loads between two
    frames at 30 Hz: without it no frame would show it under load.
stop
    When the gripper reports its fingers stopped (``stopped_s``), widths of
    frames after it are the width at the stop: the load cell's reading may
    peak a little later than the fingers stop, after the last width sample.
hold
    After the peak the gripper holds still until it releases: up to
    ``HOLD_FRAMES`` frames from ``HOLD_SETTLE_S`` after the peak until the force
    falls by ``HOLD_TOLERANCE`` (``Segment.hold_*``). They all show the peak
    state; widths there are only right once their stamping lag is corrected.

Flags
-----
``Segment.flags`` are the loading phase's (:mod:`estimator.load_phase`), plus ``"too_few_samples"``
and ``"misaligned"`` when too few frames fall in the loading phase or widths miss some of them, and
``"cleaned_timestamps"`` when frames were dropped whose capture time is not after an earlier frame's.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from numbers import Integral

import numpy as np

from estimator.errors import FitError
from estimator.fit_inputs import real_array
from estimator.load_phase import ENVELOPE_TOLERANCE, LoadPhase, check_contact_force, find_load_phase
from estimator.signals import interpolate

__all__ = ["Segment", "align_frames", "frames_in_capture_order", "sampling_axis", "segment_grasp", "unplaced_frames"]

# Hold frames: the gripper holds still at the peak force before it releases. Gripper widths are read
# with about 0.1 s latency and stamped on return, so the first reads after the stop still show the
# fingers closing; hold frames start this long after the peak. The hold ends where the force falls
# below the peak by HOLD_TOLERANCE (or its noise).
HOLD_SETTLE_S = 0.15
HOLD_TOLERANCE = 0.05
HOLD_FRAMES = 3
# The peak frame comes within this time after the peak (three frame periods at 30 Hz), before the hold.
PEAK_FRAME_WINDOW_S = 0.1
# The most frames a sample may ask for: far above any model's or setting's (EstimatorSettings.n_frames: 1..64),
# far below a sample too large to allocate.
MAX_N_FRAMES = 10_000


@dataclass(frozen=True)
class Segment:
    """The loading phase of one grasp and everything aligned on it.

    Times are seconds on the record's clock; forces are baseline-subtracted
    newtons; widths are the gripper's reported widths in metres (at the motor,
    not yet corrected for finger compliance). ``reason`` is empty when a
    loading phase was found; it says why not otherwise. ``frame_reason`` says
    why no tactile frame can be used (empty when frames are usable).
    """

    reason: str
    flags: tuple[str, ...] = ()
    notes: tuple[str, ...] = ()
    force_baseline_n: float = 0.0
    force_noise_n: float = 0.0
    width_noise_m: float = 0.0
    peak_force_n: float = 0.0
    t_onset_s: float = float("nan")
    t_contact_s: float = float("nan")
    t_peak_s: float = float("nan")
    onset_width_m: float = float("nan")
    # How far the gripper closes while the onset may fall (:mod:`estimator.load_phase`), as a standard deviation (m).
    onset_width_sigma_m: float = 0.0
    # Loading phase at the force samples' own times (for methods that need no frames).
    load_t_s: np.ndarray = field(default_factory=lambda: np.zeros(0))
    load_force_n: np.ndarray = field(default_factory=lambda: np.zeros(0))
    load_width_m: np.ndarray = field(default_factory=lambda: np.zeros(0))
    # Loading frames, the peak frame last when there is one (module notes): indices into the record's
    # frame stream, capture times, and force and width at those times (the peak frame's: at the peak).
    frame_reason: str = "no loading phase"
    frame_index: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.intp))
    frame_t_s: np.ndarray = field(default_factory=lambda: np.zeros(0))
    frame_force_n: np.ndarray = field(default_factory=lambda: np.zeros(0))
    frame_width_m: np.ndarray = field(default_factory=lambda: np.zeros(0))
    # Positions within the loading frames of the n_frames sampled equidistantly from contact to the
    # last loading frame: in time ("time"), or in approach along the loading envelope ("approach").
    sample: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.intp))
    sample_by: str = "time"
    # The reported width at contact (m), where approach sampling starts.
    contact_width_m: float = float("nan")
    # Which loading phase was used and why, when it is a loading envelope (:mod:`estimator.load_phase`); else empty.
    loading: str = ""
    # Hold frames (up to HOLD_FRAMES, spread over the hold at the peak force): indices into the
    # record's frame stream and the force and width at their times.
    hold_index: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.intp))
    hold_t_s: np.ndarray = field(default_factory=lambda: np.zeros(0))
    hold_force_n: np.ndarray = field(default_factory=lambda: np.zeros(0))
    hold_width_m: np.ndarray = field(default_factory=lambda: np.zeros(0))

    def __bool__(self) -> bool:
        return not self.reason

    def describe(self) -> str:
        """Flags and their details, and the loading envelope when there is one, as one line, for an
        estimate's reason."""
        return "; ".join(n for n in (*self.notes, self.loading) if n)


def unplaced_frames(frame_t_s: np.ndarray) -> np.ndarray:
    """Which frames (capture times ``frame_t_s``, in the order they were captured: a record's, or as
    they arrived) cannot be placed: a finite time not after every earlier frame's finite time (out of
    order or duplicated). The frames kept then go strictly forward in time; a non-finite time is
    neither one (it is skipped) nor moves the time the next frame must be after."""
    t = np.asarray(frame_t_s, dtype=np.float64)
    if t.size < 2:
        return np.zeros(t.shape, dtype=bool)
    finite = np.where(np.isfinite(t), t, -np.inf)
    latest = np.concatenate([[-np.inf], np.maximum.accumulate(finite)[:-1]])
    return np.isfinite(t) & (t <= latest)


def frames_in_capture_order(frame_t_s: np.ndarray, finger: str | None = None) -> tuple[np.ndarray, str]:
    """``frame_t_s`` with NaN for the frames that cannot be placed (:func:`unplaced_frames`), and a
    note counting them ('' when none), naming ``finger`` when given."""
    t = np.asarray(frame_t_s, dtype=np.float64)
    unplaced = unplaced_frames(t)
    count = int(unplaced.sum())
    if not count:
        return t, ""
    of = f" of finger {finger!r}" if finger is not None else ""
    return np.where(unplaced, np.nan, t), (f"dropped {count} tactile frames{of} whose capture time is not after "
                                           "the previous frame's (out of order or duplicated)")


def _frames_in_phase(frame_t_s: np.ndarray, t_start: float, t_end: float) -> tuple[np.ndarray, np.ndarray]:
    """Indices and times of frames with a finite, first-seen timestamp inside [t_start, t_end]."""
    t = np.asarray(frame_t_s, dtype=np.float64)
    finite = np.flatnonzero(np.isfinite(t))
    _, first = np.unique(t[finite], return_index=True)
    index = finite[first]  # sorted by time, duplicates keep their first frame
    inside = (t[index] >= t_start) & (t[index] <= t_end)
    return index[inside], t[index[inside]]


def _equidistant(frame_t: np.ndarray, t_start: float, t_end: float, n: int) -> np.ndarray:
    """Positions of the frames nearest to ``n`` times spread evenly over [t_start, t_end]."""
    targets = np.linspace(t_start, t_end, n)
    return np.unique(np.abs(frame_t[None, :] - targets[:, None]).argmin(axis=1))


def _on_envelope(index: np.ndarray, frame_t: np.ndarray, tf: np.ndarray, force: np.ndarray, *, contact: int,
                 peak: int, sigma_f: float) -> tuple[np.ndarray, np.ndarray]:
    """The frames (indices, times) of the loading phase whose force lies on its envelope (:mod:`estimator.load_phase`)."""
    top = np.maximum.accumulate(force[contact : peak + 1])
    before = np.searchsorted(tf[contact : peak + 1], frame_t, side="right") - 1
    top_at = np.where(before >= 0, top[np.maximum(before, 0)], 0.0)
    on = interpolate(frame_t, tf, force) >= top_at - np.maximum(3.0 * sigma_f, ENVELOPE_TOLERANCE * top_at)
    return index[on], frame_t[on]


def _hold_level(force: np.ndarray, peak: int, sigma_f: float) -> float:
    """The force below which the gripper no longer holds the peak (the release begins)."""
    return float(force[peak] - max(HOLD_TOLERANCE * force[peak], 5.0 * sigma_f))


def _peak_frame(frame_t_s: np.ndarray, tf: np.ndarray, force: np.ndarray, *, peak: int, sigma_f: float,
                stopped: bool) -> tuple[np.ndarray, np.ndarray]:
    """Index and time of the peak frame (module notes), or two empty arrays when there is none."""
    t_peak = float(tf[peak])
    index, t = _frames_in_phase(frame_t_s, math.nextafter(t_peak, math.inf), t_peak + PEAK_FRAME_WINDOW_S)
    if index.size == 0:
        return index, t
    known = stopped or tf[-1] >= t[0]
    if not known or np.any(force[(tf > t_peak) & (tf <= t[0])] < _hold_level(force, peak, sigma_f)):
        return index[:0], t[:0]
    return index[:1], t[:1]


def _hold_frames(
    frame_t_s: np.ndarray, tf: np.ndarray, force: np.ndarray, tw: np.ndarray, width: np.ndarray, *,
    peak: int, sigma_f: float,
) -> dict[str, np.ndarray]:
    """Frames of the hold at the peak force, with force and width at their times (Segment fields).

    The hold runs from ``HOLD_SETTLE_S`` after the peak until the force first falls below the peak
    by ``HOLD_TOLERANCE`` (or five noise deviations, if more): the release.
    """
    level = _hold_level(force, peak, sigma_f)
    fallen = np.flatnonzero(force[peak:] < level)
    t_end = float(tf[peak + fallen[0] - 1]) if fallen.size else float(tf[-1])
    index, t = _frames_in_phase(frame_t_s, float(tf[peak]) + HOLD_SETTLE_S, t_end)
    f, w = interpolate(t, tf, force), interpolate(t, tw, width)
    usable = np.isfinite(f) & np.isfinite(w)
    index, t, f, w = index[usable], t[usable], f[usable], w[usable]
    if index.size > HOLD_FRAMES:
        pick = np.unique(np.linspace(0, index.size - 1, HOLD_FRAMES).round().astype(np.intp))
        index, t, f, w = index[pick], t[pick], f[pick], w[pick]
    return dict(hold_index=index, hold_t_s=t, hold_force_n=f, hold_width_m=w)


def sampling_axis(segment: Segment) -> tuple[np.ndarray, float]:
    """Where each loading frame lies on the axis its sample is spread over, and where contact lies
    on it: capture time (s) from the contact time, or (``sample_by == "approach"``) the reported
    width's closure since contact (m) from 0."""
    if segment.sample_by == "approach":
        return segment.contact_width_m - segment.frame_width_m, 0.0
    return segment.frame_t_s, segment.t_contact_s


def _check_n_frames(n_frames: int) -> None:
    if not (isinstance(n_frames, Integral) and not isinstance(n_frames, bool) and 1 <= n_frames <= MAX_N_FRAMES):
        raise FitError(f"n_frames: expected an integer from 1 to {MAX_N_FRAMES}, got {n_frames!r}")


def _frame_times(frame_t_s: np.ndarray) -> np.ndarray:
    """The frames' capture times as a 1-D float64 array, else a FitError naming them."""
    t = real_array("align_frames", "frame_t_s", frame_t_s)
    if t.ndim != 1:
        raise FitError(f"align_frames: frame_t_s must be a 1-D series of capture times, got shape {t.shape}")
    return t


def segment_grasp(
    force_t_s: np.ndarray,
    force_n: np.ndarray,
    width_t_s: np.ndarray,
    width_m: np.ndarray,
    frame_t_s: np.ndarray,
    *,
    contact_force_n: float,
    n_frames: int,
    stopped_s: float | None = None,
    max_width_m: float | None = None,
    max_force_n: float | None = None,
    finger: str | None = None,
) -> Segment:
    """Find contact, onset and the loading phase; align force and width with the frames.

    :func:`~estimator.load_phase.find_load_phase` on the force and width, then :func:`align_frames` on the frames.

    Parameters
    ----------
    force_t_s, force_n : array_like, shape (k,)
        Load-cell samples: time (s) and force (N).
    width_t_s, width_m : array_like, shape (m,)
        Gripper width samples: time (s) and width (m).
    frame_t_s : array_like, shape (f,)
        Capture time (s) of each tactile frame, as recorded (may hold NaN, or
        times out of order or duplicated: such frames are skipped, and those not
        after an earlier frame's time counted in the notes).
    contact_force_n : float
        Force that defines first contact (N).
    n_frames : int
        Frames to sample equidistantly in time from contact to the last loading frame.
    stopped_s : float, optional
        When the gripper reported its fingers stopped (its grasp command
        completed; s): the force holds from the peak until the release, so the
        peak frame needs no force sample after it, and frames after it take the
        width at the stop (module notes).
    max_width_m, max_force_n : float, optional
        The gripper's full opening (m) and maximum grasp force (N): readings beyond what they allow
        are dropped, or the grasp refused (:mod:`estimator.plausible`).
    finger : str, optional
        The frames' finger, named in the notes.

    Returns
    -------
    Segment
        Falsy, with a reason, when there is no usable loading phase.
    """
    check_contact_force(contact_force_n)
    _check_n_frames(n_frames)
    frame_t_s = _frame_times(frame_t_s)
    phase = find_load_phase(force_t_s, force_n, width_t_s, width_m, contact_force_n=contact_force_n,
                            stopped_s=stopped_s, max_width_m=max_width_m, max_force_n=max_force_n)
    return align_frames(phase, frame_t_s, n_frames=n_frames, finger=finger)


def align_frames(phase: LoadPhase, frame_t_s: np.ndarray, *, n_frames: int, finger: str | None = None) -> Segment:
    """The segmentation of a grasp with frames at ``frame_t_s`` on its loading ``phase``: the
    loading frames (the peak frame last), the hold frames and the equidistant sample
    (:func:`segment_grasp`'s frame part; ``frame_t_s``, ``n_frames`` and ``finger`` as there)."""
    _check_n_frames(n_frames)
    frame_t_s, unplaced = frames_in_capture_order(_frame_times(frame_t_s), finger)
    flags, notes = list(phase.flags), list(phase.notes)

    def flag(name: str, note: str) -> None:
        if name not in flags:
            flags.append(name)
        notes.append(note)

    if unplaced:
        flag("cleaned_timestamps", unplaced)  # as the force path says of its samples (estimator.load_phase)
    if not phase:
        return Segment(reason=phase.reason, flags=tuple(flags), notes=tuple(notes),
                       force_baseline_n=phase.force_baseline_n)

    tf, force, tw, width, peak = phase.force_t_s, phase.force_n, phase.width_t_s, phase.width_m, phase.peak
    stopped, stopped_s = phase.stopped_s is not None, phase.stopped_s
    sigma_f = phase.segment_fields["force_noise_n"]
    t_contact, t_peak = phase.segment_fields["t_contact_s"], phase.segment_fields["t_peak_s"]
    common = dict(
        reason="", force_baseline_n=phase.force_baseline_n, **phase.segment_fields,
        **_hold_frames(frame_t_s, tf, force, tw, width, peak=peak, sigma_f=sigma_f),
    )

    index, frame_t = _frames_in_phase(frame_t_s, t_contact, t_peak)
    if phase.envelope:
        index, frame_t = _on_envelope(index, frame_t, tf, force, contact=phase.contact, peak=peak, sigma_f=sigma_f)
    peak_index, peak_t = _peak_frame(frame_t_s, tf, force, peak=peak, sigma_f=sigma_f, stopped=stopped)
    index, frame_t = np.concatenate([index, peak_index]), np.concatenate([frame_t, peak_t])
    if index.size == 0:
        ft = np.asarray(frame_t_s, dtype=np.float64)
        ft = ft[np.isfinite(ft)]
        span = f"{ft.min():.3f}..{ft.max():.3f} s" if ft.size else "none"
        overlap = ft.size and ft.max() >= tf[0] and ft.min() <= tf[-1]
        name = "too_few_samples" if overlap else "misaligned"
        why = (f"no tactile frame within the loading phase {t_contact:.3f}..{t_peak:.3f} s or within "
               f"{PEAK_FRAME_WINDOW_S:g} s after it (frames: {span})")
        if name not in flags:  # why is frame_reason's alone: a refusal says it before the notes (Segment.describe)
            flags.append(name)
        return Segment(flags=tuple(flags), notes=tuple(notes), frame_reason=why, **common)

    state_t = np.minimum(frame_t, t_peak)  # the peak frame shows the state at the peak
    frame_force = interpolate(state_t, tf, force)
    frame_width = interpolate(np.minimum(state_t, stopped_s) if stopped else state_t, tw, width)
    usable = np.isfinite(frame_force) & np.isfinite(frame_width)
    if not usable.all():
        flag("misaligned", f"{int((~usable).sum())} loading frames lie outside the width samples' span")
    index, frame_t = index[usable], frame_t[usable]
    frame_force, frame_width = frame_force[usable], frame_width[usable]
    frame_reason = ""
    if index.size == 0:
        frame_reason = "no loading frame has a width sample around it"
        sample = np.zeros(0, dtype=np.intp)
    else:
        axis = dict(sample_by="approach") if phase.envelope and np.isfinite(common["contact_width_m"]) else {}
        coords, start = sampling_axis(Segment(reason="", frame_t_s=frame_t, frame_width_m=frame_width,
                                              t_contact_s=t_contact, contact_width_m=common["contact_width_m"],
                                              **axis))
        common.update(axis)
        sample = _equidistant(coords, start, float(coords[-1]), n_frames)
        if sample.size < n_frames:
            flag("too_few_samples", f"{index.size} loading frames give {sample.size} distinct "
                                    f"samples of the {n_frames} wanted")
    return Segment(
        flags=tuple(flags), notes=tuple(notes), frame_reason=frame_reason, frame_index=index,
        frame_t_s=frame_t, frame_force_n=frame_force, frame_width_m=frame_width, sample=sample,
        **common,
    )
