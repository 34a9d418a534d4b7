"""Clock lags of a grasp's streams, measured from the grasp itself.

A camera stamps frames on its own clock and a gripper stamps a width read when the read returns;
both run late against the load cell. :func:`estimate_camera_lag` finds the camera's lag from when
the tactile image starts to change against the force onset; :func:`estimate_width_lag` finds how
late widths are stamped from where the fingers stop against the force peak
(:mod:`estimator.load_phase` and :mod:`estimator.segment` give them).
"""

from __future__ import annotations

import math
from numbers import Real

import numpy as np

from estimator.errors import FitError
from estimator.load_phase import ONSET_SIGMAS
from estimator.plausible import MIN_WIDTH_NOISE_M
from estimator.signals import clean_samples, crossing_time, reading_noise

__all__ = ["WIDTH_LAG_SLACK_S", "estimate_camera_lag", "estimate_width_lag"]

# Hinge times one width-lag search may try: the default searches 161.
MAX_HINGES = 100_000
# A width stamped when its read returns is late, never early, so the width lag lies in [0, max_lag_s]. The
# search reaches this far below 0 so that a zero lag, fitted a little early through the reads' noise, is no
# edge of the search: it counts as 0. A best hinge earlier still means the fingers stopped before the force
# peaked (an operator's grasp), which no stamping lag explains.
WIDTH_LAG_SLACK_S = 0.02


def _positive_option(name: str, value: object, method: str = "estimate_width_lag") -> float:
    """``value`` as a float when it is a finite real number > 0, else a FitError naming it."""
    if not (isinstance(value, Real) and not isinstance(value, bool) and math.isfinite(value) and value > 0):
        raise FitError(f"{method}: {name} must be a finite number > 0, got {value!r}")
    return float(value)


def _time_option(name: str, value: object, method: str) -> None:
    """A FitError naming ``value`` unless it is a real number (of seconds; not a bool)."""
    if not (isinstance(value, Real) and not isinstance(value, bool)):
        raise FitError(f"{method}: {name} must be a real number of seconds, got {value!r}")


def estimate_camera_lag(
    frame_t_s: np.ndarray,
    tactile_change: np.ndarray,
    *,
    t_onset_s: float,
    max_lag_s: float = 0.25,
) -> float | None:
    """Camera clock lag behind the force clock, from the onset of tactile change.

    The tactile change of a frame is e.g. ``mean |frame - reference|``; it
    leaves its no-contact noise when the force does. The lag is the time the
    change first exceeds its baseline by ``ONSET_SIGMAS`` noise deviations
    (interpolated between frames) minus the force onset ``t_onset_s``;
    subtract it from the frame times to put them on the force clock. Its
    resolution is a fraction of the frame period.

    Parameters
    ----------
    frame_t_s : ndarray, shape (f,)
        Frame times (s), in any order (non-finite samples are dropped, duplicate times merged, as
        :func:`~estimator.signals.clean_samples` does).
    tactile_change : ndarray, shape (f,)
        Change of each frame against the no-contact reference (any unit).
    t_onset_s : float
        Force onset (s), see :func:`segment_grasp`.
    max_lag_s : float
        Largest lag considered (s); frames before ``t_onset_s - max_lag_s``
        form the no-contact baseline.

    Returns
    -------
    float or None
        The lag (s), or None when there are too few no-contact frames or the
        change never leaves its noise within ``max_lag_s`` of the onset.

    Raises
    ------
    FitError
        The samples are not 1-D real series of one length, ``t_onset_s`` is not
        a real number, or ``max_lag_s`` is not a finite number > 0.
    """
    _time_option("t_onset_s", t_onset_s, "estimate_camera_lag")
    max_lag_s = _positive_option("max_lag_s", max_lag_s, "estimate_camera_lag")
    t, change = clean_samples(frame_t_s, tactile_change, names=("frame_t_s", "tactile_change"))
    quiet = t < t_onset_s - max_lag_s
    if quiet.sum() < 3:
        return None
    base = float(np.median(change[quiet]))
    spread = 1.4826 * float(np.median(np.abs(change[quiet] - base)))
    level = base + max(ONSET_SIGMAS * spread, 1e-9 + 1e-6 * abs(base))
    after = np.flatnonzero((t >= t_onset_s - max_lag_s) & (change > level))
    if after.size == 0 or after[0] == 0:
        return None
    lag = crossing_time(t, change, int(after[0]) - 1, level) - t_onset_s
    return float(lag) if abs(lag) <= max_lag_s else None


def estimate_width_lag(
    width_t_s: np.ndarray,
    width_m: np.ndarray,
    *,
    t_stop_s: float,
    max_lag_s: float = 0.3,
    step_s: float = 0.002,
    speed_m_s: float | None = None,
) -> float | None:
    """Delay of the width timestamps behind the force clock, from the moment the fingers stop.

    A gripper squeezing to a target force stops closing when the force peaks
    (``t_stop_s``, e.g. :attr:`Segment.t_peak_s`). A host that stamps a width
    read when the call returns stamps it late by about one read latency. The
    width trace around the stop is fitted by least squares with a hinge:
    closing at a constant speed, then still; the lag is the hinge time minus
    ``t_stop_s``. Subtract it from the width times.

    The lag is searched in ``[0, max_lag_s]`` only, the lags a stamp taken late
    can have, and ``WIDTH_LAG_SLACK_S`` below: a best hinge up to that much
    before the stop is a zero lag fitted through noise and gives 0. A best hinge
    at either end of the search (e.g. fingers that stop well before the force
    peaks, as an operator's may) gives None, not a lag the fit cannot place.

    Parameters
    ----------
    width_t_s, width_m : ndarray, shape (m,)
        Width samples: time (s) and width (m).
    t_stop_s : float
        When the force peaks (s).
    max_lag_s : float
        Largest lag considered (s).
    step_s : float
        Resolution of the hinge-time search (s).
    speed_m_s : float, optional
        The commanded closing speed (m/s, > 0). Given, the hinge fit keeps it
        and fits the stop width alone: the record holds only two or three
        reads before the stop, too few to fit the speed as well.

    Returns
    -------
    float or None
        The lag (s); None when the stop time is not finite, the trace has too
        few samples on either side of the stop, does not close before it
        (its fitted closing speed is within ``ONSET_SIGMAS`` standard errors
        of zero), or the best hinge lies at an end of the search range.

    Raises
    ------
    FitError
        The samples are not 1-D of one length, ``t_stop_s`` is not a real
        number, an option is not a finite number > 0, or ``step_s`` is too
        fine for ``max_lag_s`` (more than ``MAX_HINGES`` hinge times).
    """
    _time_option("t_stop_s", t_stop_s, "estimate_width_lag")
    max_lag_s = _positive_option("max_lag_s", max_lag_s)
    step_s = _positive_option("step_s", step_s)
    if speed_m_s is not None:
        _positive_option("speed_m_s", speed_m_s)
    if (max_lag_s + WIDTH_LAG_SLACK_S) / step_s > MAX_HINGES:
        raise FitError(f"estimate_width_lag: step_s = {step_s!r} s is too fine for max_lag_s = {max_lag_s!r} s "
                       f"(at most {MAX_HINGES} hinge times)")
    t, w = clean_samples(width_t_s, width_m, names=("width_t_s", "width_m"))
    if not math.isfinite(t_stop_s):
        return None
    near = (t >= t_stop_s - 1.0) & (t <= t_stop_s + 1.0)
    t, w = t[near], w[near]
    lags = step_s * np.arange(-math.ceil(WIDTH_LAG_SLACK_S / step_s), round(max_lag_s / step_s) + 1)
    hinges = t_stop_s + lags
    before = (t[None, :] < hinges[:, None]).sum(axis=1)
    usable = (before >= 3) & (t.size - before >= 2)
    if not usable.any():
        return None
    # w = w_stop + v * min(t - hinge, 0): linear least squares in (w_stop, v) for every hinge.
    x = np.minimum(t[None, :] - hinges[:, None], 0.0)
    n = t.size
    sx, sy = x.sum(axis=1), w.sum()
    sxx, sxy = (x * x).sum(axis=1), x @ w
    det = n * sxx - sx**2
    with np.errstate(invalid="ignore", divide="ignore"):
        fitted = (n * sxy - sx * sy) / det
        speed = fitted if speed_m_s is None else np.full(hinges.shape, -float(speed_m_s))
        offset = (sy - speed * sx) / n
        residual = ((w[None, :] - offset[:, None] - speed[:, None] * x) ** 2).sum(axis=1)
    residual = np.where(usable & (det > 0) & (speed < 0), residual, np.inf)  # closing: width falls
    best = int(np.argmin(residual))
    if not np.isfinite(residual[best]) or best in (0, hinges.size - 1):
        return None
    # The trace must close beyond its noise: a flat or noisy one still fits some tiny negative speed.
    # The fitted speed's standard error uses the robust reading noise, not the fit's residual, which
    # a hinge that fits a real grasp imperfectly (or the commanded speed) inflates; real closings
    # clear ONSET_SIGMAS by far (simulated grasps: >= 15 standard errors).
    standard_error = reading_noise(w, floor=MIN_WIDTH_NOISE_M) / math.sqrt(det[best] / n)
    if not -fitted[best] > ONSET_SIGMAS * standard_error:
        return None
    return max(float(lags[best]), 0.0)
