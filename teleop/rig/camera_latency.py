"""A tactile camera's latency against the load cell, from a tap on the gel.

A tap presses the gel and the load cell under it at one instant. Both devices stamp what
they deliver on arrival (``time.monotonic()``, :mod:`teleop.devices.base`), so the image
change (:func:`image_change`: each frame's mean absolute difference to the gel at rest) follows
the force by the camera's latency relative to the load cell. :func:`measure_latency`
resamples both signals on one fine time grid, each standardised, and takes the lag of
their cross-correlation's peak (``scipy.signal.correlate``); the Pearson correlation of
the two signals aligned at that lag says how well they follow each other.

Positive latency: the camera's frames are stamped later than the load cell's samples of
the same event; subtract it from a frame's stamp to put the frame on the load cell's time.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np
import scipy.signal

from teleop.errors import TeleopError

__all__ = ["LatencyFit", "image_change", "measure_latency"]

# A tap shows when its peak stands this many robust noise deviations above the rest level.
TAP_SIGMAS = 8.0


@dataclass(frozen=True)
class LatencyFit:
    """A camera's latency against the load cell, or (falsy) why it was not measured.

    Attributes
    ----------
    latency_s : float
        Camera stamps minus load-cell stamps of one event (s); NaN when refused.
    correlation : float
        Pearson correlation of image change and force aligned at that lag (1: identical shapes).
    force_peak_n : float
        The tap's force above the rest level (N).
    change_peak : float
        The tap's image change above the rest level (8-bit levels).
    reason : str
        Empty when measured; otherwise what was wrong, for a person.
    """

    latency_s: float = float("nan")
    correlation: float = float("nan")
    force_peak_n: float = float("nan")
    change_peak: float = float("nan")
    reason: str = ""

    def __bool__(self) -> bool:
        return not self.reason


def image_change(images: Iterable[np.ndarray], reference: np.ndarray) -> np.ndarray:
    """Mean absolute difference of each frame to the gel at rest, in 8-bit levels.

    Parameters
    ----------
    images : iterable of ndarray
        uint8 frames (raw camera frames, BGR), in capture order.
    reference : ndarray
        The gel at rest, same shape (e.g. the per-pixel median of frames spread over the
        recording: a tap is brief, so frames at rest outnumber it there).

    Returns
    -------
    ndarray
        float64 (n,).
    """
    # float, not int16: a median of frames can fall between two levels (127.5).
    rest = np.asarray(reference, dtype=np.float32)
    out = []
    for i, image in enumerate(images):
        if image.shape != rest.shape:
            raise TeleopError(f"images[{i}] has shape {image.shape}: expected the reference's {rest.shape}")
        out.append(float(np.abs(image.astype(np.float32) - rest).mean()))
    return np.asarray(out)


def _signal(name: str, t_s, value) -> tuple[np.ndarray, np.ndarray]:
    t, v = np.asarray(t_s, dtype=np.float64), np.asarray(value, dtype=np.float64)
    if t.ndim != 1 or t.shape != v.shape:
        raise TeleopError(f"{name}: times and values must be 1-D of one length, got {t.shape} and {v.shape}")
    keep = np.isfinite(t) & np.isfinite(v)
    order = np.argsort(t[keep], kind="stable")
    return t[keep][order], v[keep][order]


def _tap(t: np.ndarray, v: np.ndarray) -> tuple[float, float, float]:
    """Rest level, peak height above it, and the robust noise deviation of a signal."""
    rest = float(np.median(v))
    noise = 1.4826 * float(np.median(np.abs(v - rest)))
    return rest, float(np.max(v) - rest), noise


def measure_latency(
    frame_t_s, change, force_t_s, force_n, *, max_lag_s: float = 0.3, step_s: float = 0.001,
    min_force_n: float = 0.2, min_change: float = 0.5, min_correlation: float = 0.7,
) -> LatencyFit:
    """The camera's latency against the load cell from a tap (module notes).

    Parameters
    ----------
    frame_t_s, change : array_like
        Frame stamps (s, ``time.monotonic()``) and each frame's image change (:func:`image_change`).
    force_t_s, force_n : array_like
        Load-cell stamps (s, the same clock) and forces (N).
    max_lag_s : float
        Largest latency considered, either sign (s).
    step_s : float
        Spacing of the common time grid (s); the result's resolution.
    min_force_n, min_change : float
        Smallest tap that counts, in force (N) and image change (8-bit levels) above rest;
        each must also stand ``TAP_SIGMAS`` noise deviations above it.
    min_correlation : float
        Weakest Pearson correlation at the peak that is trusted.

    Returns
    -------
    LatencyFit
        Falsy with the reason when the recordings do not overlap, no tap shows in the force
        or the image, or the two do not follow each other.
    """
    if not (0 < step_s < max_lag_s):
        raise TeleopError(f"step_s = {step_s!r}, max_lag_s = {max_lag_s!r}: expected 0 < step_s < max_lag_s")
    t_frame, change = _signal("frames", frame_t_s, change)
    t_force, force = _signal("force", force_t_s, force_n)
    if min(t_frame.size, t_force.size) < 4:
        return LatencyFit(reason=f"too little recorded: {t_frame.size} frames and {t_force.size} force samples "
                                 "(at least 4 of each)")
    start, end = max(t_frame[0], t_force[0]), min(t_frame[-1], t_force[-1])
    if end - start < 2 * max_lag_s:
        return LatencyFit(reason=f"frames and force samples overlap for {max(end - start, 0.0):.2f} s: at least "
                                 f"{2 * max_lag_s:.2f} s needed (do both devices deliver?)")
    force_rest, force_peak, force_noise = _tap(t_force, force)
    change_rest, change_peak, change_noise = _tap(t_frame, change)
    peaks = {"force_peak_n": force_peak, "change_peak": change_peak}
    if force_peak < max(min_force_n, TAP_SIGMAS * force_noise):
        return LatencyFit(**peaks, reason=f"no tap in the force: its peak is {force_peak:.3f} N above rest (noise "
                                          f"{force_noise:.3f} N); tap the gel firmly over the load cell")
    if change_peak < max(min_change, TAP_SIGMAS * change_noise):
        return LatencyFit(**peaks, reason=f"no tap in the image: its change peaks {change_peak:.2f} levels above "
                                          f"rest (noise {change_noise:.2f}); tap the gel of this camera")
    grid = np.arange(start, end, step_s)
    a = np.interp(grid, t_frame, change) - change_rest
    b = np.interp(grid, t_force, force) - force_rest
    a, b = (a - a.mean()) / a.std(), (b - b.mean()) / b.std()
    # correlate(a, b)[k] sums a[n + lag_k] * b[n]: peaks where the image trails the force by lag_k.
    scores = scipy.signal.correlate(a, b, mode="full", method="fft")
    lags = scipy.signal.correlation_lags(a.size, b.size, mode="full")
    within = np.abs(lags) * step_s <= max_lag_s
    best = int(np.argmax(np.where(within, scores, -np.inf)))
    lag = int(lags[best])
    if abs(lag) * step_s >= max_lag_s - step_s:
        return LatencyFit(**peaks, reason=f"the image change and the force match best at the search limit "
                                          f"({lag * step_s * 1e3:+.0f} ms of +-{max_lag_s * 1e3:.0f} ms): one tap, "
                                          "and keep still otherwise")
    shift = 0.0
    if 0 < best < scores.size - 1:  # parabola through the peak and its neighbours
        left, mid, right = scores[best - 1:best + 2]
        curvature = left - 2.0 * mid + right
        shift = 0.5 * (left - right) / curvature if curvature < 0 else 0.0
    aligned = a[lag:] if lag >= 0 else a[:lag]
    reference = b[:b.size - lag] if lag >= 0 else b[-lag:]
    correlation = float(np.corrcoef(aligned, reference)[0, 1])
    if not correlation >= min_correlation:
        return LatencyFit(**peaks, correlation=correlation,
                          reason=f"the image change does not follow the force (correlation {correlation:.2f}, at "
                                 f"least {min_correlation} needed): tap once, firmly, and keep still otherwise")
    return LatencyFit(latency_s=float((lag + shift) * step_s), correlation=correlation, **peaks)
