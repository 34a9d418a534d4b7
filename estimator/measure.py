"""Offline measurement of a grasp record: fed through the one measurement path, and estimated.

:func:`measure_grasp` feeds a record through :class:`~estimator.stream.GraspStream`, the same code
that measures a grasp live from the bus, on the rig the record was captured with (its sensors, and
its gripper when it carries one): it segments the grasp, aligns force and width with every frame
and decodes only the frames it measures (the no-contact frames for the reference, the loading
frames, the hold frames when the fits use them) onto the depth grid (warped and cropped for a
Wedge, binned by ``EstimatorSettings.depth_binning``: :mod:`estimator.perception.grid`), masks
marker dots, reconstructs depth and measures contact features. Clock-lag corrections correct the
record's timestamps before it is fed. :func:`estimate_grasp` runs one analytical method on the
result (:func:`~estimator.measurements.estimate_measurements`).
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from estimator.errors import PerceptionError
from estimator.estimate import Estimate
from estimator.lag import estimate_camera_lag, estimate_width_lag
from estimator.measurements import (
    REFERENCE_FRAMES,
    REFERENCE_GUARD_S,
    TACTILE_METHODS,
    GraspMeasurements,
    check_method,
    estimate_measurements,
    median_frame,
    reference_indices,
)
from estimator.perception.calibration import Calibration
from estimator.perception.grid import decode_frame, to_grid
from estimator.segment import Segment
from estimator.stream import GraspStream, check_inputs
from teleop.errors import RecordError
from teleop.record import GRASP_DONE_EVENT, GraspRecord
from teleop.settings import SensorSettings, Settings

__all__ = ["estimate_grasp", "finger_sensor", "measure_grasp", "no_contact_reference", "reference_frame"]

# Camera-lag search: frames this long before the onset form the no-contact baseline.
MAX_CAMERA_LAG_S = 0.25


def finger_sensor(record: GraspRecord, finger: str) -> SensorSettings:
    """The sensor of ``record`` on ``finger`` (``SensingSettings.finger``), which has frames there.

    Raises
    ------
    RecordError
        The record has no sensor or no frames on ``finger``: a problem of that record, which a
        batch skips (another record may have both).
    """
    try:
        sensor = record.sensor(finger)
        record.stream(finger)
    except KeyError as exc:
        raise RecordError(f"SensingSettings.finger = {finger!r}: {exc.args[0]}") from exc
    return sensor


def _decode(record: GraspRecord, finger: str, index: np.ndarray, *, reduce: int = 1) -> np.ndarray:
    """Frames ``index`` of ``finger`` as uint8 (n, H, W, 3) BGR as captured, decoded ``reduce`` times smaller
    (:func:`~estimator.perception.grid.decode_frame`: PerceptionError naming the frame for one that does
    not decode or declares another size than the sensor's raw frame)."""
    sensor, stream = record.sensor(finger), record.stream(finger)
    frames = [decode_frame(stream.encoded[i], stream.encoding, sensor, binning=reduce,
                           where=f"finger {finger!r} frame {i}") for i in (int(i) for i in index)]
    if not frames:
        return np.zeros((0, sensor.raw_height_px // reduce, sensor.raw_width_px // reduce, 3), dtype=np.uint8)
    return np.stack(frames)


def _on_grid(record: GraspRecord, finger: str, index: np.ndarray, binning: int) -> np.ndarray:
    """Frames ``index`` of ``finger`` on the depth grid binned by ``binning``
    (:func:`~estimator.perception.grid.to_grid`), uint8 (n, H, W, 3) BGR."""
    sensor = record.sensor(finger)
    frames = _decode(record, finger, index, reduce=binning)
    return np.stack([to_grid(f, sensor, binning=binning) for f in frames]) if len(frames) else frames


def reference_frame(record: GraspRecord, finger: str, index: np.ndarray, *, binning: int = 1) -> np.ndarray:
    """No-contact reference on the depth grid binned by ``binning``: the per-pixel median of frames
    ``index`` of ``finger``, each on that grid first (fewer pixels to take the median of).

    Returns uint8 ``sensor.image_shape // binning + (3,)`` BGR for a Wedge (the raw shape over
    ``binning`` otherwise).
    """
    return median_frame(_on_grid(record, finger, index, binning))


def no_contact_reference(record: GraspRecord, finger: str, segment: Segment, *, binning: int = 1) -> np.ndarray:
    """The no-contact frame a measurement uses for ``finger`` when its frame clock is not corrected
    (:meth:`~estimator.stream.GraspStream.measurements`): the median of the last ``REFERENCE_FRAMES`` frames captured ``REFERENCE_GUARD_S``
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


def _clock_lags(record: GraspRecord, *, settings: Settings, camera: bool, width: bool) -> tuple[float | None, float | None]:
    """How late the record's frames (of the settings' finger) and widths are stamped: ``(camera_lag_s,
    width_lag_s)``, each None when not asked for or not found (see :func:`measure_grasp`)."""
    width_lag = camera_lag = None
    if not (camera or width):
        return camera_lag, width_lag
    stream = GraspStream.from_record(record, settings=settings)
    segment = stream.segment()
    if width and segment:
        # An operator's grasp (no stop reported) closes at its own speed: the hinge fits it.
        stopped = GRASP_DONE_EVENT in record.events
        width_lag = estimate_width_lag(record.width_m.t_s, record.width_m.value, t_stop_s=segment.t_peak_s,
                                       speed_m_s=stream.gripper.closing_speed_m_s if stopped else None)
        if width_lag is not None:
            segment = GraspStream.from_record(record, settings=settings, width_lag_s=width_lag).segment()
    if camera and segment:
        camera_lag = _camera_lag(record, settings.sensing.finger, segment)
    return camera_lag, width_lag


def measure_grasp(
    record: GraspRecord,
    *,
    settings: Settings,
    calibration: Calibration | str | Path | None = None,
    tactile: bool = True,
    correct_camera_lag: bool = False,
    correct_width_lag: bool = False,
) -> GraspMeasurements:
    """Segment a grasp and measure force, width and tactile contact at every loading frame: the
    record fed through :class:`~estimator.stream.GraspStream` (:meth:`~estimator.stream.GraspStream.from_record`),
    its timestamps corrected first by the clock lags asked for.

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
        sensor names (relative paths under ``configs/``). Only loaded when a
        frame is measured.
    tactile : bool
        Decode frames and reconstruct depth; False measures force and width
        only (enough for ``no_tactile``) and decodes nothing.
    correct_camera_lag : bool
        Estimate the camera clock's lag from the onset of tactile change
        against the force onset and shift the frame times by it.
    correct_width_lag : bool
        Estimate how late the widths are stamped from when the fingers stop
        against the force peak, and shift the width times by it (a host that
        stamps a gripper read when it returns is late by about one read); only
        a lag >= 0 is found (:func:`~estimator.lag.estimate_width_lag`), so
        fingers that stop before the force peaks keep their width times.

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
    FitError
        The record has no sensor or no frames on the settings' finger; ``record`` is not a
        GraspRecord or ``settings`` not Settings.
    RecordError, PerceptionError
        A frame does not decode, or is not of the sensor's raw size.
    """
    check_inputs(record, settings=settings)
    camera_lag, width_lag = _clock_lags(record, settings=settings, camera=correct_camera_lag,
                                        width=correct_width_lag)
    stream = GraspStream.from_record(record, settings=settings, calibration=calibration, camera_lag_s=camera_lag,
                                     width_lag_s=width_lag)
    return stream.measurements(tactile=tactile)


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
    method : {"no_tactile", "elastic", "hertz", "series"}
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
    check_method(method)
    if isinstance(source, GraspRecord):
        source = measure_grasp(source, settings=settings, calibration=calibration,
                               tactile=method in TACTILE_METHODS, correct_camera_lag=correct_camera_lag,
                               correct_width_lag=correct_width_lag)
    return estimate_measurements(source, method).with_latency(time.perf_counter() - started)
