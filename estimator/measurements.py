"""What the analytical estimators read from one grasp, and the estimate they give from it.

:class:`GraspMeasurements` is built by one implementation, :class:`~estimator.stream.GraspStream`,
live from the bus and offline from a grasp record (:func:`~estimator.measure.measure_grasp` feeds
the record through it). :func:`estimate_measurements` runs one analytical method on them. The
helpers here are what both sides share: the calibration a sensor names, the no-contact
reference's frames (:func:`reference_indices`) and their per-pixel median (:func:`median_frame`), and
the measurement of one frame against it (:func:`measure_frame`).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from estimator import analytical
from estimator.errors import CalibrationError, FitError
from estimator.estimate import Estimate
from estimator.features import ContactFeatures, contact_features
from estimator.linefit import MeasurementNoise
from estimator.perception.calibration import Calibration, load_calibration
from estimator.perception.depth import reconstruct_depth
from estimator.perception.grid import DepthGrid, depth_grid
from estimator.perception.markers import detect_markers
from estimator.segment import Segment
from teleop.record import GraspRecord
from teleop.settings import SensorSettings, resolve_path, shipped_calibration_hint

log = logging.getLogger(__name__)

__all__ = [
    "REFERENCE_FRAMES",
    "FIT_READS",
    "REFERENCE_GUARD_S",
    "TACTILE_METHODS",
    "FitReads",
    "GraspMeasurements",
    "calibration_path",
    "calibration_problem",
    "missing_calibration",
    "calibration_sensor_mismatch",
    "check_calibration_fits",
    "check_method",
    "estimate_measurements",
    "measure_frame",
    "median_frame",
    "reference_indices",
    "resolve_calibration",
]


@dataclass(frozen=True)
class FitReads:
    """What one analytical fit reads from a grasp (its row of :data:`FIT_READS`).

    Attributes
    ----------
    depth : bool
        Tactile frames (depth, contact features): measured only for such a fit.
    onset_width : bool
        A positive width at the contact onset, which normalises its strain: refused without one.
    approach : bool
        Its strain rests on the approach the gripper's widths give: an ok fit is a lower bound when
        no width was read during the loading.
    """

    depth: bool
    onset_width: bool
    approach: bool


#: What each analytical method (:data:`~estimator.analytical.METHODS`) reads: a new fit gets its row
#: here and its branch in ``_fit``.
FIT_READS = {
    "no_tactile": FitReads(depth=False, onset_width=True, approach=True),
    "elastic": FitReads(depth=True, onset_width=True, approach=True),
    "hertz": FitReads(depth=True, onset_width=False, approach=False),
    "series": FitReads(depth=True, onset_width=False, approach=True),
}
#: The methods that read depth (the others need no tactile frame).
TACTILE_METHODS = tuple(method for method, reads in FIT_READS.items() if reads.depth)
# No-contact frames: those ending this long before the force onset, the last few of them.
REFERENCE_GUARD_S = 0.1
REFERENCE_FRAMES = 5


@dataclass(frozen=True)
class GraspMeasurements:
    """Everything the analytical estimators need from one grasp, aligned in time.

    Attributes
    ----------
    finger : str
        Finger whose tactile frames were read.
    sensor : SensorSettings
        That finger's sensor, from the rig the grasp was captured with (the record's, or live the
        settings').
    segment : Segment
        Contact, onset, loading phase, flags; also the loading phase at the
        force samples' times (used by ``no_tactile``).
    finger_stiffness_n_per_m : float
        Finger bending stiffness used to correct widths (N/m): the rig's gripper.
    object_poisson : float
    t_s, force_n, width_m, approach_m : ndarray, shape (n,)
        Per measured loading frame (every loading frame unless only some ``frames`` were asked
        for: :meth:`~estimator.stream.GraspStream.measurements`): time (s, frame clock corrected
        by ``camera_lag_s``),
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
        measured only when the fits use them: with the width lag corrected, offline).
    image_bgr : ndarray, shape (n, H, W, 3), uint8, or None
        The measured loading frames on the depth grid (warped and cropped for a
        Wedge, binned), BGR.
    reference_bgr : ndarray, shape (H, W, 3), uint8, or None
        The no-contact reference they were measured against.
    calibration_smoothing_px : float or None
        The colour smoothing (Gaussian sigma, px of the calibration's images) of the calibration
        the depth was reconstructed with (a learned model reads depth only as it was trained);
        None without depth.
    frames_dropped : int
        Frames of ``finger`` dropped before those kept (:meth:`~estimator.received.Frames.make_room`):
        a :attr:`segment`'s frame position plus this is the frame's index in its record's stream.
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
    frames_dropped: int = 0

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

    A relative path in ``SensorSettings.calibration`` is resolved by
    :func:`~teleop.settings.resolve_path` (against the settings file's folder when loaded).

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


def calibration_problem(record: GraspRecord, finger: str, override: str | None, option: str | None, *,
                        markers: bool = False, marker_override: str | None = None,
                        marker_option: str | None = None) -> str | None:
    """Why a calibration of ``record`` the estimate reads cannot be used (None: they can): that of
    ``finger`` and, with ``markers``, that of the other finger with markers (the marker finger).

    ``estimator evaluate``, ``compare``, ``bench`` and ``build-dataset`` skip such a record with this reason.

    Parameters
    ----------
    record : GraspRecord
    finger : str
        A finger ``record`` has a sensor on.
    override : str or None
        The calibration given for every record (``option``'s value); when given, the record's own is not read.
    option : str or None
        The command-line option that gives ``override`` (named in the reason: ``--calibration``); None
        where the command has none.
    markers : bool
        Also the marker finger's calibration (a model variant with markers reads it); a record
        without a marker finger has none to check.
    marker_override, marker_option
        As ``override`` and ``option``, for the marker finger.

    Returns
    -------
    str or None
        The reason, naming the finger, the missing file and the option that would give one; None
        when the record names files that exist.
    """
    problem = _finger_calibration_problem(record, finger, override, option)
    if problem is None and markers:
        other = next((s.finger for s in record.sensors if s.finger != finger and s.markers), None)
        if other is not None:
            problem = _finger_calibration_problem(record, other, marker_override, marker_option)
    return problem


def missing_calibration(record: GraspRecord, finger: str, calibration: str | None, *, markers: bool = False) -> str:
    """Why a calibration file ``record``'s estimate reads is gone (``calibration missing: ...``), or '':
    :func:`calibration_problem` of ``finger`` unless ``calibration`` (``--calibration``) serves every
    record, and with ``markers`` (a model variant with markers) of the marker finger too. The one
    wording ``estimator estimate``, ``evaluate`` and ``bench`` give it."""
    problem = calibration_problem(record, finger, calibration, "--calibration", markers=markers)
    return f"calibration missing: {problem}" if problem else ""


def _finger_calibration_problem(record: GraspRecord, finger: str, override: str | None,
                                option: str | None) -> str | None:
    """:func:`calibration_problem` of one finger. A simulated record names the file of the settings it was
    simulated with and carries none inside: it is given one, or simulated again, never exported again."""
    if override is not None:
        return None
    sensor: SensorSettings = record.sensor(finger)
    # Made by `teleop simulate`, not exported from a session log (a simulated session's too).
    simulated = record.provenance.source == "simulated" and record.provenance.model != "session"
    if not sensor.calibration:
        again = ("simulate it again (`teleop simulate`) with" if simulated else
                 "export its session again with `teleop export` and")
        remedy = (f"pass {option} CAL (a calibration of that sensor from `estimator calibrate`)" if option else
                  f"{again} settings that name one for that finger")
        return f"its sensor on finger {finger!r} names no calibration file: {remedy}"
    path = calibration_path(sensor)
    if path.is_file():
        return None
    if simulated:
        fix = (shipped_calibration_hint(sensor)
               or f"make one with `estimator calibrate` and name it in [sensors.{finger}] calibration")
        given = f"pass {option} CAL, put the file there" if option else "put the file there"
        return (f"it names calibration {path} for finger {finger!r}, which does not exist (the file of the settings "
                f"it was simulated with): {given}, or simulate it again (`teleop simulate`) with settings that "
                f"name one: {fix}")
    return (f"it names calibration {path} for finger {finger!r}, which does not exist: export its session "
            f"again with `teleop export` (exported records carry their calibration inside)"
            + (f", put the file there, or pass {option} CAL" if option else ", or put the file there"))


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
    """Raise CalibrationError unless ``cal`` was made for ``sensor``'s image grid; warn (once per
    pair) when it names another sensor (model, finger, serial) than ``sensor``, as another sensor's
    colours read as other slopes even on the same grid."""
    _check_calibration_sensor(cal, sensor)
    if tuple(cal.image_shape) != tuple(sensor.image_shape):
        raise CalibrationError(
            f"the calibration is for {cal.image_shape} images; sensor {sensor.finger!r} gives "
            f"{sensor.image_shape}{' (warped and cropped)' if sensor.model == 'wedge' else ''}"
        )
    if not np.isclose(cal.pixel_pitch_m, sensor.pixel_pitch_m, rtol=0.01):
        raise CalibrationError(
            f"the calibration's pixel pitch {cal.pixel_pitch_m:.4g} m differs from sensor "
            f"{sensor.finger!r}'s {sensor.pixel_pitch_m:.4g} m"
        )


def calibration_sensor_mismatch(cal: Calibration, sensor: SensorSettings) -> str | None:
    """How the sensor ``cal`` records it was fitted on (when it records one) differs from ``sensor``,
    or None. An identity either side leaves unstated (no serial, a calibration fitted without
    --settings) is not compared."""
    made_for = cal.provenance.get("sensor") or {}
    differ = [f"{key} {made_for[key]!r} (this sensor: {getattr(sensor, key)!r})"
              for key in ("model", "finger", "serial")
              if made_for.get(key) and getattr(sensor, key) and made_for[key] != getattr(sensor, key)]
    if not differ:
        return None
    return (f"the calibration was made for another sensor than {sensor.model} "
            f"{sensor.serial or sensor.finger!r}: {', '.join(differ)}")


def _check_calibration_sensor(cal: Calibration, sensor: SensorSettings) -> None:
    """Warn when ``cal`` was made for another sensor (:func:`calibration_sensor_mismatch`). A warning,
    not a refusal: a lab may calibrate one sensor and use it on its twin."""
    mismatch = calibration_sensor_mismatch(cal, sensor)
    if mismatch and mismatch not in _WARNED:  # once per pair: an evaluation loads it for every record
        _WARNED.add(mismatch)
        log.warning("%s; its colours may read as other slopes here", mismatch)


_WARNED: set[str] = set()


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


def reference_indices(frame_t_s: np.ndarray, t_before_s: float) -> np.ndarray:
    """The last ``REFERENCE_FRAMES`` frames captured before ``t_before_s``."""
    before = np.flatnonzero(np.isfinite(frame_t_s) & (frame_t_s < t_before_s))
    return before[-REFERENCE_FRAMES:]


def measure_frame(frame: np.ndarray, reference: np.ndarray, calibration: Calibration,
                  grid: DepthGrid) -> tuple[np.ndarray, ContactFeatures]:
    """Depth (m, float32, the calibration's grid) and contact features of one frame on the depth grid
    (:func:`~estimator.perception.grid.frame_on_grid`) against its no-contact reference, as
    :class:`~estimator.stream.GraspStream` measures each frame (markers found and inpainted first
    when the sensor has them). ``calibration`` and ``grid`` are those of the depth grid
    (:func:`~estimator.perception.grid.grid_calibration`, :func:`~estimator.perception.grid.depth_grid`)."""
    mask = detect_markers(frame, reference) if grid.markers else None
    depth = reconstruct_depth(frame, reference, calibration, marker_mask=mask)
    return depth, contact_features(depth[None], pixel_pitch_m=grid.pixel_pitch_m,
                                   contact_threshold_m=grid.contact_threshold_m)


# --------------------------------------------------------------------------- estimation


def _run(m: GraspMeasurements, method: str) -> Estimate:
    result = _fit(m, method)
    if result.state == "ok" and FIT_READS[method].approach and "width_unread" in m.segment.flags:
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
    reads = FIT_READS[method]
    noise = m.noise
    onset_width = segment.onset_width_m
    if reads.onset_width and not (np.isfinite(onset_width) and onset_width > 0):
        got = f"{onset_width:.3g} m" if np.isfinite(onset_width) else "no width reading"
        return Estimate.refuse(method, f"no positive width at the contact onset (got {got}) "
                                       "to normalise the strain")
    if reads.depth:
        if m.features is None:
            return Estimate.refuse(method, m.tactile_reason or "tactile features were not measured")
        force, approach, f = _with_hold_point(m, m.features)
    if method == "no_tactile":
        rows, cols = m.sensor.pad_size_m
        return analytical.no_tactile(segment.load_force_n, m.approach_at_force_samples(),
                                     initial_width_m=onset_width, pad_area_m2=rows * cols, noise=noise)
    k_gel = m.sensor.gel_compliance_per_pa
    if method == "series":
        width = onset_width if np.isfinite(onset_width) and onset_width > 0 else None
        return analytical.series(approach, f.peak_depth_m, gel_compliance_per_pa=k_gel,
                                 object_poisson=m.object_poisson, noise=noise,
                                 contact_radius_m=f.cap_radius_m, gel_thickness_m=m.sensor.gel_thickness_m,
                                 gel_poisson=m.sensor.gel_poisson, force_n=force if width else None,
                                 initial_width_m=width)
    if method == "hertz":
        return analytical.hertz(force, approach, f.peak_depth_m, f.cap_radius_m,
                                gel_compliance_per_pa=k_gel, object_poisson=m.object_poisson,
                                noise=noise, truncated=f.cap_touches_edge)
    if method == "elastic":
        return analytical.elastic(force, approach, f.peak_depth_m, f.area_m2,
                                  initial_width_m=onset_width, noise=noise,
                                  truncated=f.touches_edge)
    raise FitError(f"method {method!r} has no branch in _fit of estimator/measurements.py: expected one "
                   "that runs its fit")


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




def check_method(method: str) -> None:
    """Raise FitError unless ``method`` is an analytical method (:data:`~estimator.analytical.METHODS`)
    with its row in :data:`FIT_READS`."""
    if method not in analytical.METHODS:
        raise FitError(f"method {method!r}: expected one of {', '.join(analytical.METHODS)}")
    if method not in FIT_READS:
        raise FitError(f"method {method!r} has no row in FIT_READS of estimator/measurements.py: expected "
                       "what it reads from a grasp (and its branch in _fit)")


def estimate_measurements(m: GraspMeasurements, method: str) -> Estimate:
    """One analytical method on ``m``: the grasp's segmentation notes appended to its reason.

    Parameters
    ----------
    m : GraspMeasurements
    method : {"no_tactile", "elastic", "hertz", "series"}

    Returns
    -------
    Estimate
        Not stamped with a latency (the caller knows what it waited for).

    Raises
    ------
    FitError
        An unknown method, or one without its row in :data:`FIT_READS` or its branch in ``_fit``.
    """
    check_method(method)
    result = _run(m, method)
    return result.with_note(m.segment.describe())  # a refusal too: what was dropped may say why
