"""The loading phase of a grasp, found in its force and width streams alone, before any
tactile frame is aligned on it (:mod:`estimator.segment`): baseline, onset, contact, peak, and
the loading envelope of a grasp an operator drives.

Force and width are cleaned (non-finite values and timestamps dropped, sorted, duplicate
timestamps merged into their mean), interpolated at the times where they are needed, and never
extrapolated.

Terms
-----
baseline
    The load cell's reading before contact (a tare offset), subtracted from
    every force.
onset
    The time the force leaves its baseline noise: the first moment of
    contact, from which the approach and the strain are measured. It is
    interpolated between the last quiet force sample and the next, as if the
    force rose linearly between them; a stiff object's force jumps within that
    period, so the onset is known only to within it: uniformly, a standard
    deviation of period / sqrt(12), which the gripper's closing speed turns into
    ``onset_width_sigma_m``.
contact
    ``t = 0`` of the paper: the first time the force reaches
    ``EstimatorSettings.contact_force_n`` (0.75 N).
loading phase
    From contact to peak force: the first sample within three noise deviations
    (or 1 %) of the maximum, so that a noisy or creeping hold phase does not
    count as loading. A
    saturated load cell (a plateau of identical readings at the top) ends it
    where the plateau starts.
loading envelope
    A grasp whose gripper reported no stop (``stopped_s`` None: an operator drove the fingers'
    target, or the stop is unknown) may close at a varying speed, pause, back off and squeeze
    again before its peak. Its loading phase is the monotone *loading envelope*: from contact to
    the peak, the samples and frames at a running maximum of the force (within
    ``ENVELOPE_TOLERANCE`` of the maximum so far, or three noise deviations); backing off and
    re-squeezing below the previous maximum are skipped (their states repeat those of the way
    up), and pauses on the way up leave frames of one state. The description names a back-off only
    for a sustained fall beyond the noise, faster than the fingers standing still let an object
    relax, and a pause only where the force stays in one band of its rise far longer than in the
    bands around it: a slow steady close is not paused, and a long still hold is one pause. Its
    frames are sampled equidistantly in approach (the width's closure since contact) rather than in time
    (``Segment.sample_by``): at the paper's constant closing speed the two coincide, so the
    models see the distribution they were trained on. ``Segment.loading`` says which loading
    phase was used and what was skipped, for the estimate's reason. A grasp with a reported stop
    (the paper's scripted grasp) keeps the whole loading phase, sampled in time.

Flags
-----
``"cleaned_timestamps"`` non-finite or duplicate samples were dropped or merged;
``"implausible_width"``, ``"implausible_force"`` readings the gripper cannot make, a load cell
read with its sign reversed (:mod:`estimator.plausible`), or widths that open over the loading
while the force rises (the grasp is refused);
``"non_monotonic"`` the force drops beyond its noise during loading;
``"clipped"`` the force saturates (plateau of identical top readings);
``"too_few_samples"`` fewer samples or frames than the methods want;
``"misaligned"`` the streams do not cover each other's times (frames or widths
missing over part of the loading phase);
``"width_unread"`` no width reading falls between the onset and the peak (a stiff
object loads faster than the gripper reports its width): the approach is
interpolated between a reading while the fingers closed and one after they
stopped, which assumes they kept closing; the true approach is smaller.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from estimator.errors import FitError
from estimator.fit_inputs import is_real
from estimator.plausible import (
    MIN_FORCE_NOISE_N,
    MIN_WIDTH_NOISE_M,
    implausible_forces,
    implausible_widths,
    reversed_force,
)
from estimator.signals import clean_samples, crossing_time, interpolate, noise_std, reading_noise

__all__ = ["LoadPhase", "check_contact_force", "find_load_phase"]

BASELINE_GUARD_S = 0.05
ONSET_SIGMAS = 4.0
MIN_CLIP_RUN = 3
PEAK_TOLERANCE = 0.01  # loading ends within this share of the peak force
# Loading envelope (module notes): a sample or frame is on it within this share of the running maximum
# (or three noise deviations). On the force averaged over SMOOTH_SAMPLES samples, a fall below its
# maximum by BACKOFF_SHARE (or five deviations) is a back-off, and the maximum staying within one band
# of the peak's ENVELOPE_TOLERANCE (or three deviations) for PAUSE_S or longer, and PAUSE_FACTOR times
# as long as in the PAUSE_BANDS bands on either side, is a pause: a slow steady close is not one.
ENVELOPE_TOLERANCE = 0.01
BACKOFF_SHARE = 0.02
SMOOTH_SAMPLES = 5
PAUSE_S = 0.15
PAUSE_FACTOR = 4.0
PAUSE_BANDS = 3  # the bands on either side that give the loading rate a band's dwell is judged against
MAX_BANDS = 1000  # bands of the rise a pause is looked for in: bounds their count on any data


def _closing_speed(t_s: np.ndarray, width_m: np.ndarray, before_s: float) -> float:
    """How fast the width closes (m/s) over the last two width samples at or before ``before_s``
    (the first two when fewer precede it)."""
    last = max(int(np.searchsorted(t_s, before_s, side="right")) - 1, 1)
    dt = float(t_s[last]) - float(t_s[last - 1])  # Python floats: a gap beyond the float range is inf, silently
    return abs(float(width_m[last]) - float(width_m[last - 1])) / dt if dt > 0 else 0.0


def _opening_widths(force_n: np.ndarray, width_m: np.ndarray, *, sigma_f: float, sigma_w: float) -> str:
    """Why the loading's widths cannot be a grasp's, or '': they open (first to last sample, beyond
    the noise of two readings) while the force rises. A grasp closes the fingers as it squeezes; a
    rigid object stops them, and their bending under the force only closes the motor further."""
    if width_m.size < 2:
        return ""
    opened, rose = float(width_m[-1] - width_m[0]), float(force_n[-1] - force_n[0])
    limit = 3.0 * math.sqrt(2.0) * sigma_w
    if not (opened > limit and rose > 3.0 * math.sqrt(2.0) * sigma_f):
        return ""
    return (f"the widths open by {opened * 1e3:.3g} mm over the loading while the force rises by {rose:.3g} N "
            f"(beyond their noise {limit * 1e3:.2g} mm): a grasp closes the fingers as it squeezes, so the width "
            "readings do not follow the grasp")


def _smoothed(value: np.ndarray) -> np.ndarray:
    """``value`` averaged over ``SMOOTH_SAMPLES`` centred samples (fewer at the ends): single noise
    samples no longer stand out, and a monotone force stays monotone."""
    window = np.ones(min(SMOOTH_SAMPLES, value.size))
    return np.convolve(value, window, "same") / np.convolve(np.ones(value.size), window, "same")


def _envelope(t: np.ndarray, loading: np.ndarray, sigma_f: float) -> tuple[np.ndarray, int, float, float]:
    """The loading envelope of the loading samples ``loading`` at times ``t`` (module notes).

    Returns the mask of samples on it, the number of back-offs, the seconds spent backing off and
    re-squeezing, and the seconds paused on the way up.
    """
    top = np.maximum.accumulate(loading)
    on = loading >= top - np.maximum(3.0 * sigma_f, ENVELOPE_TOLERANCE * top)
    if t.size < 2:
        return on, 0, 0.0, 0.0
    # Back-offs and pauses are judged on the smoothed force against the noise the loading itself
    # shows (a load cell may read noisier under load), so that noise extremes over a long still
    # hold neither raise the running maximum nor fall below it.
    scale = float(np.max(np.abs(loading))) or 1.0  # in its units, sums of forces near the float range stay finite
    force, sigma = loading / scale, max(sigma_f, noise_std(loading)) / scale
    smooth = _smoothed(force)
    rise = np.maximum.accumulate(smooth)
    below = smooth < rise - np.maximum(3.0 * sigma, ENVELOPE_TOLERANCE * rise)
    fallen = smooth < rise - np.maximum(5.0 * sigma, BACKOFF_SHARE * rise)
    edges = np.diff(np.concatenate([[0], below.astype(np.int8), [0]]))
    starts, ends = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)  # runs below[start:end]
    # A back-off is a sustained fall beyond the noise, not a dip within it, and faster than the
    # loading's mean rate over PAUSE_FACTOR: a slower one is the object relaxing while the fingers
    # hold still.
    slowest = (rise[-1] - rise[0]) / (t[-1] - t[0]) / PAUSE_FACTOR
    backing = np.zeros(t.size, dtype=bool)
    backoffs = 0
    for start, end in zip(starts, ends, strict=True):
        if not fallen[start:end].any():
            continue
        first, last_on = start + int(np.argmax(fallen[start:end])), start - 1  # rise[0] == smooth[0]: start > 0
        fell = (rise[first] - smooth[first]) - (rise[last_on] - smooth[last_on])
        if fell >= slowest * (t[first] - t[last_on]):
            backing[start:end] = True
            backoffs += 1
    dt = np.diff(t)
    # Each interval between samples belongs to the band of the envelope's rise where it starts; a
    # band the force stays in far longer than in the bands around it (the grasp's own loading rate
    # there, however it stiffens) is a pause.
    # At most MAX_BANDS bands, however far the noise floor lies below the rise.
    step = max(3.0 * sigma, ENVELOPE_TOLERANCE * float(force.max()), float(rise[-1] - rise[0]) / MAX_BANDS)
    band = ((rise[:-1] - rise[0]) // step).astype(np.int64) if step > 0 else np.zeros(t.size - 1, dtype=np.int64)
    dwell = np.bincount(band, weights=np.where(backing[:-1], 0.0, dt))
    around = np.lib.stride_tricks.sliding_window_view(
        np.concatenate([np.full(PAUSE_BANDS, np.nan), dwell, np.full(PAUSE_BANDS, np.nan)]), 2 * PAUSE_BANDS + 1).copy()
    around[:, PAUSE_BANDS] = np.nan  # the band itself
    # A rise within one band has no bands around it to judge its dwell by: it is no pause, however long.
    usual = np.nanmedian(around, axis=1) if dwell.size > 1 else np.full(1, np.inf)
    skipped_s = float(np.sum(dt[backing[:-1]]))
    paused_s = float(np.sum(dwell[dwell >= np.maximum(PAUSE_S, PAUSE_FACTOR * usual)]))
    return on, backoffs, skipped_s, paused_s


def _describe_envelope(*, duration_s: float, peak_force_n: float, backoffs: int, skipped_s: float,
                       paused_s: float) -> str:
    """``Segment.loading``: which loading phase was used and why."""
    parts = [f"loading: the envelope over {duration_s:.2f} s from contact to the {peak_force_n:.3g} N peak"]
    if backoffs:
        parts.append(f"{backoffs} back-off{'s' if backoffs > 1 else ''} and re-squeeze skipped ({skipped_s:.2f} s)")
    if paused_s > 0:
        parts.append(f"paused {paused_s:.2f} s")
    parts.append("frames sampled by approach (no gripper stop reported, as when an operator drives the fingers)")
    return ", ".join(parts)


@dataclass(frozen=True)
class LoadPhase:
    """What :func:`~estimator.segment.segment_grasp` finds in the force and width streams alone,
    before any frame is aligned on it (:func:`find_load_phase`);
    :func:`~estimator.segment.align_frames` aligns a frame set on it.

    Falsy, with ``reason``, when there is no usable loading phase. The arrays are the cleaned
    samples (force baseline-subtracted); ``peak`` indexes the peak force sample in them.
    """

    reason: str
    flags: tuple[str, ...] = ()
    notes: tuple[str, ...] = ()
    force_baseline_n: float = 0.0
    segment_fields: dict = field(default_factory=dict)  # the Segment fields that need no frames
    force_t_s: np.ndarray = field(default_factory=lambda: np.zeros(0))
    force_n: np.ndarray = field(default_factory=lambda: np.zeros(0))
    width_t_s: np.ndarray = field(default_factory=lambda: np.zeros(0))
    width_m: np.ndarray = field(default_factory=lambda: np.zeros(0))
    peak: int = 0
    stopped_s: float | None = None
    contact: int = 0  # index of the first sample at contact force
    envelope: bool = False  # the loading phase is the loading envelope (module notes)

    def __bool__(self) -> bool:
        return not self.reason


def check_contact_force(contact_force_n: float) -> None:
    """Raise :class:`FitError` unless ``contact_force_n`` is a finite force above zero."""
    if not (is_real(contact_force_n) and math.isfinite(contact_force_n) and contact_force_n > 0):
        raise FitError(f"contact_force_n: expected a finite real number > 0, got {contact_force_n!r}")


def _check_options(stopped_s: object, max_width_m: object, max_force_n: object) -> None:
    """Raise :class:`FitError` naming the first option of :func:`find_load_phase` that is not
    as documented: ``stopped_s`` None or a real number (not finite: no stop), the limits None or
    finite real numbers > 0."""
    if stopped_s is not None and not is_real(stopped_s):
        raise FitError(f"stopped_s: expected None or a real number of seconds, got {stopped_s!r}")
    for name, value in (("max_width_m", max_width_m), ("max_force_n", max_force_n)):
        if value is not None and not (is_real(value) and math.isfinite(value) and value > 0):
            raise FitError(f"{name}: expected None or a finite real number > 0, got {value!r}")


def find_load_phase(
    force_t_s: np.ndarray,
    force_n: np.ndarray,
    width_t_s: np.ndarray,
    width_m: np.ndarray,
    *,
    contact_force_n: float,
    stopped_s: float | None = None,
    max_width_m: float | None = None,
    max_force_n: float | None = None,
) -> LoadPhase:
    """The force and width part of :func:`~estimator.segment.segment_grasp` (same parameters, no
    frames): contact, onset, peak and the loading phase at the force samples' times.

    A live estimator aligns each new frame set on it (:func:`~estimator.segment.align_frames`)
    without finding the phase again while no force or width sample came.
    """
    check_contact_force(contact_force_n)
    _check_options(stopped_s, max_width_m, max_force_n)
    flags: list[str] = []
    notes: list[str] = []
    stopped = stopped_s is not None and bool(np.isfinite(stopped_s))

    def flag(name: str, note: str) -> None:
        if name not in flags:
            flags.append(name)
        notes.append(note)

    tf, force = clean_samples(force_t_s, force_n, names=("force_t_s", "force_n"))
    tw, width = clean_samples(width_t_s, width_m, names=("width_t_s", "width_m"))
    dropped = (np.size(force_t_s) - tf.size, np.size(width_t_s) - tw.size)
    if any(dropped):
        flag("cleaned_timestamps", f"dropped or merged {dropped[0]} force and {dropped[1]} width "
                                   "samples: non-finite values or timestamps, or duplicate timestamps")
    if max_width_m is not None:
        outside, note = implausible_widths(width, max_width_m=max_width_m)
        if note:
            flag("implausible_width", note)
            tw, width = tw[~outside], width[~outside]
    if max_force_n is not None:
        beyond, note, refused = implausible_forces(force, max_force_n=max_force_n)
        if refused:
            return LoadPhase(reason=note, flags=(*flags, "implausible_force"), notes=tuple(notes))
        if note:
            flag("implausible_force", note)
            tf, force = tf[~beyond], force[~beyond]
    if tf.size < 3:
        return LoadPhase(reason=f"too few force samples ({tf.size} usable, need 3)",
                         flags=(*flags, "too_few_samples"), notes=tuple(notes))
    if tw.size < 2:
        return LoadPhase(reason=f"too few width samples ({tw.size} usable, need 2)",
                         flags=(*flags, "too_few_samples"), notes=tuple(notes))

    # Baseline: the load cell's reading well before the force first nears contact.
    above = np.flatnonzero(force >= contact_force_n)
    if why := reversed_force(force, contact_force_n=contact_force_n):
        return LoadPhase(reason=why, flags=(*flags, "implausible_force"), notes=tuple(notes))
    if above.size == 0:
        return LoadPhase(
            reason=f"no contact: the force peaks at {force.max():.3g} N, below "
                   f"contact_force_n = {contact_force_n:g} N",
            flags=tuple(flags), notes=tuple(notes),
        )
    quiet = tf <= tf[above[0]] - BASELINE_GUARD_S
    baseline = float(np.median(force[quiet])) if quiet.sum() >= 3 else 0.0
    with np.errstate(over="ignore"):
        force = force - baseline
    representable = np.isfinite(force)  # only absurd readings overflow
    tf, force, quiet = tf[representable], force[representable], quiet[representable]
    before = force[quiet] if quiet.sum() >= 5 else force
    sigma_f = noise_std(before)  # as read: a plateau of identical readings is a saturation
    above = np.flatnonzero(force >= contact_force_n)
    if above.size == 0:
        return LoadPhase(
            reason=f"no contact: the force peaks at {force.max():.3g} N above its baseline "
                   f"{baseline:.3g} N, below contact_force_n = {contact_force_n:g} N",
            flags=tuple(flags), notes=tuple(notes), force_baseline_n=baseline,
        )
    contact = int(above[0])
    t_contact = crossing_time(tf, force, contact - 1, contact_force_n) if contact > 0 else float(tf[0])

    # Peak: the first sample within the noise (or 1 %) of the maximum after contact, so that noise
    # or a slow creep on the hold phase does not stretch the loading phase over it; a saturation
    # plateau (identical top readings) ends it where the plateau starts.
    top = contact + int(np.argmax(force[contact:]))
    run = top
    while run + 1 < force.size and force[run + 1] == force[top]:
        run += 1
    if run - top + 1 >= MIN_CLIP_RUN and sigma_f > 0:
        flag("clipped", f"force saturates at {force[top] + baseline:.4g} N for {run - top + 1} samples; "
                        "loading ends where the plateau starts")
    if "clipped" in flags:
        peak = top
    else:
        near_top = force[top] - max(3.0 * sigma_f, PEAK_TOLERANCE * force[top])
        peak = contact + int(np.argmax(force[contact : top + 1] >= near_top))
    peak_force = float(force[peak])

    loading = force[contact : peak + 1]
    load_t = tf[contact : peak + 1]
    on_envelope = np.ones(loading.shape, dtype=bool)
    envelope_note = ""
    drop = float(np.max(np.maximum.accumulate(loading) - loading))
    if drop > max(5.0 * sigma_f, 0.02 * peak_force):
        flag("non_monotonic", f"force drops by {drop:.3g} N during loading (noise {sigma_f:.2g} N)")
    if not stopped:  # no stop reported: the loading envelope (module notes)
        on_envelope, backoffs, skipped_s, paused_s = _envelope(load_t, loading, sigma_f)
        envelope_note = _describe_envelope(duration_s=float(tf[peak]) - t_contact, peak_force_n=peak_force,
                                           backoffs=backoffs, skipped_s=skipped_s, paused_s=paused_s)

    # Onset: where the force last left its baseline noise before contact.
    onset_level = min(max(ONSET_SIGMAS * sigma_f, 0.02 * contact_force_n), 0.5 * contact_force_n)
    below = np.flatnonzero(force[:contact] <= onset_level)
    if below.size:
        last_quiet = int(below[-1])
        t_onset = min(crossing_time(tf, force, last_quiet, onset_level), t_contact)
        onset_t_sigma = (float(tf[last_quiet + 1]) - float(tf[last_quiet])) / math.sqrt(12.0)
    else:
        t_onset = float(tf[0])
        onset_t_sigma = 0.0
        flag("misaligned", "the force record starts in contact: onset taken at its first sample")

    sigma_w = reading_noise(width, floor=MIN_WIDTH_NOISE_M)
    onset_width = float(interpolate(np.array([t_onset]), tw, width)[0])
    onset_width_sigma = _closing_speed(tw, width, t_onset) * onset_t_sigma
    if not np.isfinite(onset_width):
        flag("misaligned", f"no width sample around the contact onset at {t_onset:.3f} s "
                           f"(widths span {tw[0]:.3f}..{tw[-1]:.3f} s)")

    t_peak = float(tf[peak])
    loading, load_t = loading[on_envelope], load_t[on_envelope]
    load_w = interpolate(np.minimum(load_t, stopped_s) if stopped else load_t, tw, width)
    covered = np.isfinite(load_w)
    if not covered.all():
        flag("misaligned", f"widths (span {tw[0]:.3f}..{tw[-1]:.3f} s) miss "
                           f"{int((~covered).sum())} of {load_t.size} loading force samples")
    if why := _opening_widths(loading[covered], load_w[covered], sigma_f=reading_noise(before, floor=MIN_FORCE_NOISE_N),
                              sigma_w=sigma_w):
        return LoadPhase(reason=why, flags=(*flags, "implausible_width"), notes=tuple(notes), force_baseline_n=baseline)
    if load_t.size < 2:
        flag("too_few_samples", "the loading phase holds a single force sample")
    if not np.any((tw > t_onset) & (tw <= t_peak)):
        flag("width_unread", "no width was read from the onset to the peak: the approach is interpolated "
                             "across a stop of the fingers it cannot see")

    fields = dict(
        force_noise_n=reading_noise(before, floor=MIN_FORCE_NOISE_N), width_noise_m=sigma_w, peak_force_n=peak_force, t_onset_s=t_onset,
        t_contact_s=t_contact, t_peak_s=t_peak, onset_width_m=onset_width,
        onset_width_sigma_m=onset_width_sigma, load_t_s=load_t[covered],
        load_force_n=loading[covered], load_width_m=load_w[covered],
        contact_width_m=float(interpolate(np.array([t_contact]), tw, width)[0]), loading=envelope_note,
    )
    return LoadPhase(reason="", flags=tuple(flags), notes=tuple(notes), force_baseline_n=baseline,
                     segment_fields=fields, force_t_s=tf, force_n=force, width_t_s=tw, width_m=width,
                     peak=peak, stopped_s=stopped_s if stopped else None, contact=contact, envelope=not stopped)
