"""From a grasp record to measurements, and from measurements to an estimate.

:func:`measure_grasp` reads what hardware gives (frames, forces, widths and
their timestamps) and nothing else: it segments the grasp and aligns force
and width with every frame; :func:`measure_tactile` (run by it unless no
tactile method is asked for) decodes only the frames it needs (the no-contact
frames for the reference, the loading frames or a chosen few of them, the hold
frames when the fits use them) onto the depth grid (warped and cropped for a Wedge,
binned by ``EstimatorSettings.depth_binning``: :mod:`estimator.perception.grid`),
masks marker dots, reconstructs depth and measures contact features.
:func:`estimate_grasp` runs one analytical method on the result.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from estimator import analytical
from estimator.errors import CalibrationError, FitError, PerceptionError
from estimator.estimate import Estimate
from estimator.features import ContactFeatures, contact_features
from estimator.lag import estimate_camera_lag, estimate_width_lag
from estimator.linefit import MeasurementNoise
from estimator.perception.calibration import Calibration, load_calibration
from estimator.perception.depth import reconstruct_depth
from estimator.perception.grid import DepthGrid, depth_grid, grid_calibration, to_grid
from estimator.perception.markers import detect_markers
from estimator.segment import Segment, segment_grasp
from estimator.settings import estimator_settings
from teleop.record import GRASP_DONE_EVENT, GraspRecord
from teleop.settings import SensorSettings, Settings, resolve_path

__all__ = [
    "TACTILE_METHODS",
    "GraspMeasurements",
    "calibration_path",
    "check_calibration_fits",
    "estimate_grasp",
    "measure_grasp",
    "measure_tactile",
    "median_frame",
    "no_contact_reference",
    "reference_frame",
    "reference_indices",
    "resolve_calibration",
]

TACTILE_METHODS = ("elastic", "hertz", "split")
# No-contact frames: those ending this long before the force onset, the last few of them.
REFERENCE_GUARD_S = 0.1
REFERENCE_FRAMES = 5
# Camera-lag search: frames this long before the onset form the no-contact baseline.
MAX_CAMERA_LAG_S = 0.25


@dataclass(frozen=True)
class GraspMeasurements:
    """Everything the analytical estimators need from one grasp, aligned in time.

    Attributes
    ----------
    finger : str
        Finger whose tactile frames were read.
    sensor : SensorSettings
        That finger's sensor as recorded with the grasp.
    segment : Segment
        Contact, onset, loading phase, flags; also the loading phase at the
        force samples' times (used by ``no_tactile``).
    finger_stiffness_n_per_m : float
        Finger bending stiffness used to correct widths (N/m).
    object_poisson : float
    t_s, force_n, width_m, approach_m : ndarray, shape (n,)
        Per measured loading frame (every loading frame unless
        :func:`measure_tactile` was given ``frames``): time (s, frame clock corrected by ``camera_lag_s``),
        force (N), reported width (m) and per-finger approach since onset (m).
    features : ContactFeatures or None
        Contact features per measured loading frame; None when no tactile method was
        asked for or frames could not be used (see ``tactile_reason``).
    depth_binning : int
        Depth is measured on ``sensor``'s image grid binned by this much (:attr:`grid`).
    depth_m : ndarray, shape (n, H, W), float32, or None
        Reconstructed depth of every measured loading frame, on :attr:`grid`.
    camera_lag_s : float or None
        Estimated camera clock lag that was corrected for, if estimated.
    width_lag_s : float or None
        Estimated delay of the width timestamps that was corrected for, if estimated.
    tactile_reason : str
        Why there are no tactile features (empty when there are, or when none
        were asked for).
    hold_force_n, hold_approach_m : ndarray, shape (h,)
        Force (N) and per-finger approach (m) at the hold frames
        (:attr:`Segment.hold_index`, the gripper still at the peak force).
    hold_features : ContactFeatures or None
        Contact features of the hold frames; None when not measured (they are
        measured only when the fits use them: with the width lag corrected).
    image_bgr : ndarray, shape (n, H, W, 3), uint8, or None
        The measured loading frames on the depth grid (warped and cropped for a
        Wedge, binned), BGR.
    reference_bgr : ndarray, shape (H, W, 3), uint8, or None
        The no-contact reference they were measured against.
    calibration_smoothing_px : float or None
        The colour smoothing (Gaussian sigma, px of the calibration's images) of the calibration
        the depth was reconstructed with (a learned model reads depth only as it was trained);
        None without depth.
    """

    finger: str
    sensor: SensorSettings
    segment: Segment
    finger_stiffness_n_per_m: float
    object_poisson: float
    t_s: np.ndarray
    force_n: np.ndarray
    width_m: np.ndarray
    approach_m: np.ndarray
    features: ContactFeatures | None = None
    depth_binning: int = 1
    depth_m: np.ndarray | None = None
    camera_lag_s: float | None = None
    width_lag_s: float | None = None
    tactile_reason: str = ""
    hold_force_n: np.ndarray = field(default_factory=lambda: np.zeros(0))
    hold_approach_m: np.ndarray = field(default_factory=lambda: np.zeros(0))
    hold_features: ContactFeatures | None = None
    image_bgr: np.ndarray | None = None
    reference_bgr: np.ndarray | None = None
    calibration_smoothing_px: float | None = None

    @property
    def grid(self) -> DepthGrid:
        """The depth grid: ``sensor``'s image grid binned by ``depth_binning``
        (:func:`~estimator.perception.grid.depth_grid`)."""
        return depth_grid(self.sensor, self.depth_binning)

    @property
    def noise(self) -> MeasurementNoise:
        """Resolution of each measurement: force and width noise and the onset width's
        uncertainty estimated from the record; depth resolution, depth scale uncertainty and
        pixel pitch from the sensor (the pitch of the depth grid)."""
        return MeasurementNoise(
            force_n=self.segment.force_noise_n,
            width_m=self.segment.width_noise_m,
            depth_m=self.sensor.depth_resolution_m,
            length_m=self.sensor.pixel_pitch_m * self.depth_binning,
            depth_scale=self.sensor.depth_scale_uncertainty,
            onset_width_m=self.segment.onset_width_sigma_m,
        )

    @property
    def sample(self) -> np.ndarray:
        """Positions of the ``n_frames`` frames sampled equidistantly over the loading phase."""
        return self.segment.sample

    def approach_at_force_samples(self) -> np.ndarray:
        """Per-finger approach at the loading phase's force samples (m)."""
        return analytical.approach_per_finger(
            self.segment.load_width_m, self.segment.load_force_n,
            onset_width_m=self.segment.onset_width_m,
            finger_stiffness_n_per_m=self.finger_stiffness_n_per_m,
        )


def calibration_path(sensor: SensorSettings, override: str | Path | None = None) -> Path:
    """The calibration file to use: ``override`` if given, else the one the sensor names.

    A relative path in ``SensorSettings.calibration`` is under ``configs/``.

    Raises
    ------
    CalibrationError
        Neither names a calibration file.
    """
    if override is not None:
        return Path(override)
    if not sensor.calibration:
        raise CalibrationError(
            f"sensor on finger {sensor.finger!r} names no calibration file: run "
            f"`estimator calibrate`, then set calibration in [sensors.{sensor.finger}] or pass "
            "--calibration"
        )
    return resolve_path(sensor.calibration)


def resolve_calibration(sensor: SensorSettings, calibration: Calibration | str | Path | None) -> Calibration:
    """``calibration`` itself when it is loaded, else the file it or the sensor names, loaded.

    Raises
    ------
    CalibrationError
        No calibration is named, or the file cannot be loaded.
    """
    if isinstance(calibration, Calibration):
        return calibration
    return load_calibration(calibration_path(sensor, calibration))


def check_calibration_fits(cal: Calibration, sensor: SensorSettings) -> None:
    """Raise CalibrationError unless ``cal`` was made for ``sensor``'s image grid."""
    if tuple(cal.image_shape) != tuple(sensor.image_shape):
        raise CalibrationError(
            f"the calibration is for {cal.image_shape} images; sensor {sensor.finger!r} gives "
            f"{sensor.image_shape} (warped and cropped)"
        )
    if not np.isclose(cal.pixel_pitch_m, sensor.pixel_pitch_m, rtol=0.01):
        raise CalibrationError(
            f"the calibration's pixel pitch {cal.pixel_pitch_m:.4g} m differs from sensor "
            f"{sensor.finger!r}'s {sensor.pixel_pitch_m:.4g} m"
        )


def _decode(record: GraspRecord, finger: str, index: np.ndarray, *, reduce: int = 1) -> np.ndarray:
    """Frames ``index`` of ``finger`` as uint8 (n, H, W, 3) BGR as captured, decoded ``reduce`` times smaller."""
    return record.stream(finger).frames((int(i) for i in index), reduce=reduce)


def _on_grid(record: GraspRecord, finger: str, index: np.ndarray, binning: int) -> np.ndarray:
    """Frames ``index`` of ``finger`` on the depth grid binned by ``binning``
    (:func:`~estimator.perception.grid.to_grid`), uint8 (n, H, W, 3) BGR."""
    sensor = record.sensor(finger)
    frames = _decode(record, finger, index, reduce=binning)
    return np.stack([to_grid(f, sensor, binning=binning) for f in frames]) if len(frames) else frames


def median_frame(frames: np.ndarray) -> np.ndarray:
    """Per-pixel median of a uint8 stack (n, ...), rounded half to even like ``np.rint(np.median)``.

    An odd-even transposition sort of the few images with element-wise min/max: a handful of
    passes over whole images instead of a partition of n values at every pixel (40x faster).
    """
    layers = list(frames)
    n = len(layers)
    for sweep in range(n):
        for i in range(sweep % 2, n - 1, 2):
            low, high = layers[i], layers[i + 1]
            layers[i], layers[i + 1] = np.minimum(low, high), np.maximum(low, high)
    if n % 2:
        return np.array(layers[n // 2], dtype=np.uint8)
    pair_sum = layers[n // 2 - 1].astype(np.uint16) + layers[n // 2]
    return np.rint(pair_sum / 2).astype(np.uint8)


def reference_frame(record: GraspRecord, finger: str, index: np.ndarray, *, binning: int = 1) -> np.ndarray:
    """No-contact reference on the depth grid binned by ``binning``: the per-pixel median of frames
    ``index`` of ``finger``, each on that grid first (fewer pixels to take the median of).

    Returns uint8 ``sensor.image_shape // binning + (3,)`` BGR for a Wedge (the raw shape over
    ``binning`` otherwise).
    """
    return median_frame(_on_grid(record, finger, index, binning))


def reference_indices(frame_t_s: np.ndarray, t_before_s: float) -> np.ndarray:
    """The last ``REFERENCE_FRAMES`` frames captured before ``t_before_s``."""
    before = np.flatnonzero(np.isfinite(frame_t_s) & (frame_t_s < t_before_s))
    return before[-REFERENCE_FRAMES:]


def no_contact_reference(record: GraspRecord, finger: str, segment: Segment, *, binning: int = 1) -> np.ndarray:
    """The no-contact frame :func:`measure_tactile` uses for ``finger`` when its frame clock is not
    corrected: the median of the last ``REFERENCE_FRAMES`` frames captured ``REFERENCE_GUARD_S``
    or more before ``segment``'s onset (uint8 BGR, on the depth grid binned by ``binning``).

    Raises
    ------
    PerceptionError
        No frame of ``finger`` was captured before the onset.
    """
    index = reference_indices(record.stream(finger).t_s, segment.t_onset_s - REFERENCE_GUARD_S)
    if index.size == 0:
        raise PerceptionError(f"finger {finger!r}: no tactile frame before the contact onset at "
                              f"{segment.t_onset_s:.3f} s to serve as the no-contact reference")
    return reference_frame(record, finger, index, binning=binning)


def _camera_lag(record: GraspRecord, finger: str, segment: Segment) -> float | None:
    """Lag of the frame clock, from the onset of ``mean |frame - reference|`` (raw frames).

    The reference is the median of every other no-contact frame; the frames
    left out of it give the change's no-contact baseline (a frame inside the
    median differs less from it than a fresh one would).
    """
    t = record.stream(finger).t_s
    quiet = np.flatnonzero(np.isfinite(t) & (t < segment.t_onset_s - MAX_CAMERA_LAG_S))
    reference_index = quiet[::-2][:REFERENCE_FRAMES]
    window = np.flatnonzero(np.isfinite(t) & (t <= segment.t_contact_s + MAX_CAMERA_LAG_S))
    window = np.setdiff1d(window[t[window] >= segment.t_onset_s - 2 * MAX_CAMERA_LAG_S], reference_index)
    if reference_index.size < 3 or window.size < 4:
        return None
    reference = median_frame(_decode(record, finger, reference_index)).astype(np.int16)
    change = np.abs(_decode(record, finger, window).astype(np.int16) - reference).mean(axis=(1, 2, 3))
    return estimate_camera_lag(t[window], change, t_onset_s=segment.t_onset_s, max_lag_s=MAX_CAMERA_LAG_S)


def measure_grasp(
    record: GraspRecord,
    *,
    settings: Settings,
    calibration: Calibration | str | Path | None = None,
    tactile: bool = True,
    correct_camera_lag: bool = False,
    correct_width_lag: bool = False,
) -> GraspMeasurements:
    """Segment a grasp and measure force, width and tactile contact at every loading frame.

    Parameters
    ----------
    record : GraspRecord
    settings : Settings
        ``estimator`` (finger, contact force, frames, object Poisson ratio, depth
        binning) is used; the sensor is the one recorded with the grasp, and so is the
        gripper (``finger_stiffness_n_per_m``, ``closing_speed_m_s``) when the record
        carries one, else ``settings.gripper``.
    calibration : Calibration, path or None
        Colour-to-gradient calibration; None reads the file the record's
        sensor names (relative paths under ``configs/``). Only loaded when
        ``tactile``.
    tactile : bool
        Decode frames and reconstruct depth; False measures force and width
        only (enough for ``no_tactile``) and decodes nothing.
    correct_camera_lag : bool
        Estimate the camera clock's lag from the onset of tactile change
        against the force onset and shift the frame times by it.
    correct_width_lag : bool
        Estimate how late the widths are stamped from when the fingers stop
        against the force peak, and shift the width times by it (a host that
        stamps a gripper read when it returns is late by about one read).

    Returns
    -------
    GraspMeasurements
        ``segment`` is falsy with a reason when the grasp has no usable
        loading phase; ``features`` is None with ``tactile_reason`` when
        frames cannot be used.

    Raises
    ------
    CalibrationError
        A tactile measurement was asked for and no calibration can be loaded,
        or it was made for another image shape or pixel pitch.
    RecordError
        A frame does not decode.
    """
    finger = settings.sensing.finger
    try:
        sensor = record.sensor(finger)
        stream = record.stream(finger)
    except KeyError as exc:
        raise FitError(f"SensingSettings.finger = {finger!r}: {exc.args[0]}") from exc
    est = estimator_settings(settings)
    gripper = record.gripper if record.gripper is not None else settings.gripper

    def segment_with(width_t_s: np.ndarray, frame_t_s: np.ndarray) -> Segment:
        return segment_grasp(
            record.force_n.t_s, record.force_n.value, width_t_s, record.width_m.value,
            frame_t_s, contact_force_n=est.contact_force_n, n_frames=est.n_frames,
            stopped_s=record.events.get(GRASP_DONE_EVENT),
        )

    width_t, frame_t = record.width_m.t_s, stream.t_s
    segment = segment_with(width_t, frame_t)
    width_lag = lag = None
    if correct_width_lag and segment:
        # An operator's grasp (no stop reported) closes at its own speed: the hinge fits it.
        stopped = GRASP_DONE_EVENT in record.events
        width_lag = estimate_width_lag(width_t, record.width_m.value, t_stop_s=segment.t_peak_s,
                                       speed_m_s=gripper.closing_speed_m_s if stopped else None)
        if width_lag is not None:
            width_t = width_t - width_lag
            segment = segment_with(width_t, frame_t)
    if correct_camera_lag and segment:
        lag = _camera_lag(record, finger, segment)
        if lag is not None:
            frame_t = frame_t - lag
            segment = segment_with(width_t, frame_t)
    stiffness = gripper.finger_stiffness_n_per_m
    approach = analytical.approach_per_finger(
        segment.frame_width_m, segment.frame_force_n,
        onset_width_m=segment.onset_width_m, finger_stiffness_n_per_m=stiffness,
    )
    hold_approach = analytical.approach_per_finger(
        segment.hold_width_m, segment.hold_force_n,
        onset_width_m=segment.onset_width_m, finger_stiffness_n_per_m=stiffness,
    )
    measurements = GraspMeasurements(
        finger=finger, sensor=sensor, segment=segment, finger_stiffness_n_per_m=stiffness,
        object_poisson=settings.sensing.object_poisson, t_s=segment.frame_t_s, force_n=segment.frame_force_n,
        width_m=segment.frame_width_m, approach_m=approach, camera_lag_s=lag, width_lag_s=width_lag,
        hold_force_n=segment.hold_force_n, hold_approach_m=hold_approach, depth_binning=est.depth_binning,
    )
    if not tactile:
        return measurements
    return measure_tactile(record, measurements, calibration=calibration)


def measure_tactile(
    record: GraspRecord,
    measurements: GraspMeasurements,
    *,
    calibration: Calibration | str | Path | None = None,
    frames: np.ndarray | None = None,
) -> GraspMeasurements:
    """Add the tactile measurements to force-and-width ones: depth and contact features.

    Decodes, warps and reconstructs only the frames it measures, and the
    no-contact frames of the reference; the hold frames only when the fits use
    them (the width stamping lag was corrected, see :func:`measure_grasp`).

    Parameters
    ----------
    record : GraspRecord
        The record ``measurements`` were taken from.
    measurements : GraspMeasurements
        From ``measure_grasp(record, ..., tactile=False)``.
    calibration : Calibration, path or None
        See :func:`measure_grasp`.
    frames : array of int, optional
        Distinct positions within the loading frames (``segment.frame_index``)
        to measure, in the order given; None measures every loading frame.
        ``t_s``, ``force_n``, ``width_m`` and ``approach_m`` are restricted to
        them as well.

    Returns
    -------
    GraspMeasurements
        With ``features``, ``depth_m``, ``image_bgr`` and ``reference_bgr``, or
        without them and with ``tactile_reason`` when frames cannot be used.

    Raises
    ------
    CalibrationError
        No calibration can be loaded, or it was made for another image shape or pixel pitch.
    FitError
        ``frames`` are not distinct positions of loading frames.
    RecordError
        A frame does not decode.
    """
    m, segment = measurements, measurements.segment
    if frames is not None:
        frames = np.asarray(frames)
        count = segment.frame_index.size
        if (frames.ndim != 1 or frames.dtype.kind not in "iu" or np.unique(frames).size != frames.size
                or np.any((frames < 0) | (frames >= count))):
            raise FitError(f"frames {frames!r}: expected distinct positions 0..{count - 1} of the loading frames")
        m = replace(m, t_s=m.t_s[frames], force_n=m.force_n[frames], width_m=m.width_m[frames],
                    approach_m=m.approach_m[frames])
    finger, sensor = m.finger, m.sensor
    frame_t = record.stream(finger).t_s - (m.camera_lag_s or 0.0)
    why = segment.reason or segment.frame_reason
    if not why:
        reference_index = reference_indices(frame_t, segment.t_onset_s - REFERENCE_GUARD_S)
        if reference_index.size == 0:
            why = (f"no tactile frame before the contact onset at {segment.t_onset_s:.3f} s to serve "
                   "as the no-contact reference")
    if why:
        return replace(m, tactile_reason=why)

    cal = resolve_calibration(sensor, calibration)
    check_calibration_fits(cal, sensor)
    smoothing_px = cal.smoothing_px
    binning, grid = m.depth_binning, m.grid
    cal = grid_calibration(cal, binning)
    reference = reference_frame(record, finger, reference_index, binning=binning)
    loading_index = segment.frame_index if frames is None else segment.frame_index[frames]
    # Hold frames enter the fits only with the width lag corrected (see _with_hold_point).
    hold_index = segment.hold_index if m.width_lag_s is not None else segment.hold_index[:0]
    images = _on_grid(record, finger, np.concatenate([loading_index, hold_index]), binning)
    depth = np.empty((len(images), *reference.shape[:2]), dtype=np.float32)
    for i, image in enumerate(images):
        mask = detect_markers(image, reference) if grid.markers else None
        depth[i] = reconstruct_depth(image, reference, cal, marker_mask=mask)
    features = contact_features(
        depth, pixel_pitch_m=grid.pixel_pitch_m, contact_threshold_m=grid.contact_threshold_m
    )
    loading = slice(0, loading_index.size)
    hold = slice(loading_index.size, len(images))
    return replace(m, features=features.take(loading), depth_m=depth[loading],
                   hold_features=features.take(hold) if hold_index.size else None,
                   image_bgr=images[loading], reference_bgr=reference, calibration_smoothing_px=smoothing_px)


# --------------------------------------------------------------------------- estimation


#: Methods whose strain rests on the approach the gripper's widths give.
APPROACH_METHODS = ("no_tactile", "elastic", "split")


def _run(m: GraspMeasurements, method: str) -> Estimate:
    result = _fit(m, method)
    if result.state == "ok" and method in APPROACH_METHODS and "width_unread" in m.segment.flags:
        # The interpolated approach assumes the fingers kept closing; they may have stopped, so the
        # object is at most as compliant as the fit says: its stiffer end is not resolved.
        low, _ = result.interval_pa
        return Estimate.at_least(method, low, f"{result.reason}; no width was read during the loading, "
                                              "so the approach is an upper bound: E is at least the low end")
    return result


def _fit(m: GraspMeasurements, method: str) -> Estimate:
    segment = m.segment
    if not segment:
        return Estimate.refuse(method, segment.reason)
    noise = m.noise
    onset_width = segment.onset_width_m
    if method in ("no_tactile", "elastic") and not (np.isfinite(onset_width) and onset_width > 0):
        return Estimate.refuse(method, f"no positive width at the contact onset (got {onset_width:.3g} m) "
                                       "to normalise the strain")
    if method == "no_tactile":
        rows, cols = m.sensor.pad_size_m
        return analytical.no_tactile(segment.load_force_n, m.approach_at_force_samples(),
                                     initial_width_m=onset_width, pad_area_m2=rows * cols, noise=noise)
    f = m.features
    if f is None:
        return Estimate.refuse(method, m.tactile_reason or "tactile features were not measured")
    k_gel = m.sensor.gel_compliance_per_pa
    force, approach, f = _with_hold_point(m, f)
    if method == "split":
        width = onset_width if np.isfinite(onset_width) and onset_width > 0 else None
        return analytical.split(approach, f.peak_depth_m, gel_compliance_per_pa=k_gel,
                                object_poisson=m.object_poisson, noise=noise,
                                contact_radius_m=f.cap_radius_m, gel_thickness_m=m.sensor.gel_thickness_m,
                                gel_poisson=m.sensor.gel_poisson, force_n=force if width else None,
                                initial_width_m=width)
    if method == "hertz":
        return analytical.hertz(force, approach, f.peak_depth_m, f.cap_radius_m,
                                gel_compliance_per_pa=k_gel, object_poisson=m.object_poisson,
                                noise=noise, truncated=f.cap_touches_edge)
    return analytical.elastic(force, approach, f.peak_depth_m, f.area_m2,
                              initial_width_m=onset_width, noise=noise,
                              truncated=f.touches_edge)


def _with_hold_point(m: GraspMeasurements, f: ContactFeatures) -> tuple[np.ndarray, np.ndarray, ContactFeatures]:
    """Loading frames plus one point for the hold at the peak force: the median of the hold frames.

    The gel and the fingers are still during the hold, so its frames all show the peak state; their
    median is one more (and the best resolved) point of the loading curve. Stiff objects load
    within a frame period or two, so for them it is often the only point at full force. Used only
    when the width stamping lag was corrected: stale widths of the stopped fingers would add
    about ``closing speed * lag / 2`` (~2 mm) to its approach.
    """
    h = m.hold_features
    if h is None or len(h) == 0 or m.width_lag_s is None:
        return m.force_n, m.approach_m, f

    def joined(loading: np.ndarray, hold: np.ndarray) -> np.ndarray:
        point = np.median(hold, axis=0, keepdims=True)
        return np.concatenate([loading, point.astype(loading.dtype) if loading.dtype == bool else point])

    hold_point = ContactFeatures(**{name: joined(getattr(f, name), getattr(h, name))
                                    for name in ContactFeatures.__dataclass_fields__})
    return joined(m.force_n, m.hold_force_n), joined(m.approach_m, m.hold_approach_m), hold_point


def estimate_grasp(
    source: GraspRecord | GraspMeasurements,
    method: str,
    *,
    settings: Settings,
    calibration: Calibration | str | Path | None = None,
    correct_camera_lag: bool = False,
    correct_width_lag: bool = False,
) -> Estimate:
    """Estimate the grasped object's Young's modulus with one analytical method.

    Parameters
    ----------
    source : GraspRecord or GraspMeasurements
        A record is measured first (frames decoded only for tactile methods).
    method : {"no_tactile", "elastic", "hertz", "split"}
    settings : Settings
    calibration : Calibration, path or None
        See :func:`measure_grasp`.
    correct_camera_lag, correct_width_lag : bool
        See :func:`measure_grasp`.

    Returns
    -------
    Estimate
        Stamped with the time this call took (``latency_s``); notes on the
        grasp's segmentation flags are appended to its reason.
    """
    started = time.perf_counter()
    if method not in analytical.METHODS:
        raise FitError(f"method {method!r}: expected one of {', '.join(analytical.METHODS)}")
    if isinstance(source, GraspRecord):
        source = measure_grasp(source, settings=settings, calibration=calibration,
                               tactile=method in TACTILE_METHODS, correct_camera_lag=correct_camera_lag,
                               correct_width_lag=correct_width_lag)
    result = _run(source, method)
    if source.segment:
        result = result.with_note(source.segment.describe())
    return result.with_latency(time.perf_counter() - started)

