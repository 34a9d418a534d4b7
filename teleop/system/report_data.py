"""What ``teleop report`` shows of each grasp of a session log, gathered from the log alone.

The grasps come from :func:`teleop.session.export.session_grasps` (its grouping of frames,
force and width into grasps, and its labels from the catalogue stored in the log). Beside
them, one pass over the ``grasp_event``, ``estimate`` and ``display`` messages collects each
grasp's object name, its estimates over time and what the softness display rendered.

Tactile moments are picked and reconstructed with the estimator's own perception: the grasp
is segmented as the estimator segments it (:func:`estimator.measure.measure_grasp`, forces
and widths only), the no-contact reference is the estimator's
(:func:`estimator.measure.no_contact_reference`) and depth is
:func:`estimator.perception.depth.reconstruct_depth` with the calibration stored in the log
for that finger, on the estimator's depth grid. A finger whose calibration the log does not
carry is shown without depth; nothing falls back to files on this machine or to simulator
truth.
"""

from __future__ import annotations

import dataclasses
import shutil
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from estimator.errors import EstimatorError
from estimator.measure import measure_grasp, no_contact_reference
from estimator.measurements import (
    REFERENCE_GUARD_S,
    GraspMeasurements,
    check_calibration_fits,
    reference_indices,
)
from estimator.perception.calibration import Calibration, load_calibration
from estimator.perception.depth import reconstruct_depth
from estimator.perception.grid import grid_calibration, to_grid
from estimator.perception.markers import detect_markers
from estimator.segment import Segment
from estimator.settings import depth_binning_problem, estimator_settings
from teleop.errors import ComplianceTeleopError, RecordError, TeleopError
from teleop.record import FrameStream, GraspRecord, decode_image
from teleop.session.logfile import LogInfo, LogReader
from teleop.settings import SensorSettings, Settings

__all__ = [
    "MOMENTS",
    "DisplayPoint",
    "EstimatePoint",
    "GraspView",
    "ReportError",
    "TactileMoment",
    "grasp_messages",
    "log_calibrations",
    "tactile_moments",
]

MOMENTS = ("before contact", "mid-loading", "peak force")


class ReportError(TeleopError):
    """A report cannot be written, or its page cannot be rendered (no Chromium, Chromium failed)."""


@dataclass(frozen=True)
class EstimatePoint:
    """One ``estimate`` message: capture time (s, the log's clock), modulus and interval (Pa)."""

    t_s: float
    e_pa: float | None
    interval_pa: tuple[float | None, float | None]
    state: str
    reason: str
    provisional: bool
    method: str


@dataclass(frozen=True)
class DisplayPoint:
    """One ``display`` message: what the softness display rendered at ``t_s``."""

    t_s: float
    phase: str
    stiffness: float  # fraction of the display's range, 1 = rigid
    e_pa: float | None
    rigid: bool
    unknown: bool
    provisional: bool


@dataclass(frozen=True)
class TactileMoment:
    """One tactile frame of one finger on the depth grid, and its reconstructed depth (m) if any."""

    finger: str
    name: str  # one of MOMENTS
    t_s: float
    force_n: float
    image_bgr: np.ndarray
    depth_m: np.ndarray | None


@dataclass
class GraspView:
    """Everything the report shows of one grasp.

    ``record`` (frames, force, width) is held only while the grasp's figures are drawn; ``reason``
    says why the log gives none. ``label_pa``, ``label_source`` and ``start_s`` come from the record,
    whose label (a ``label`` message's, else the catalogue's) also names the object.
    """

    grasp_id: str
    object_name: str | None = None
    record: GraspRecord | None = None
    reason: str = ""
    label_pa: float | None = None
    label_source: str | None = None
    start_s: float | None = None
    estimates: list[EstimatePoint] = field(default_factory=list)
    display: list[DisplayPoint] = field(default_factory=list)
    segment: Segment | None = None
    moments: list[TactileMoment] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)  # why some of the tactile panel is missing

    def take(self, record: GraspRecord | None, reason: str) -> None:
        """Hold the grasp's ``record`` (or the ``reason`` there is none) and what the page keeps of it."""
        self.record, self.reason = record, reason
        if record is not None:
            if record.label is not None:
                self.object_name = record.label.object_name
                self.label_pa, self.label_source = record.label.modulus_pa, record.label.source
            self.start_s = record.events["grasp_start"]

    @property
    def t0_s(self) -> float:
        """The grasp's start event time (else its first estimate or rendering): the time axes' origin."""
        if self.start_s is not None:
            return self.start_s
        times = [e.t_s for e in self.estimates] + [d.t_s for d in self.display]
        return min(times) if times else 0.0

    @property
    def final(self) -> EstimatePoint | None:
        """The last non-provisional estimate, if the estimator sent one."""
        return next((e for e in reversed(self.estimates) if not e.provisional), None)

    @property
    def rendered(self) -> DisplayPoint | None:
        """What the display settled on for the grasp: its last active rendering of the final
        estimate (before it went stale or faded), else its last active one, else its last one."""
        active = [d for d in self.display if d.phase == "active"]
        final = [d for d in active if not d.provisional]
        return (final or active or self.display or [None])[-1]


def grasp_messages(reader: LogReader) -> tuple[dict[str, GraspView], bool]:
    """Object names, estimates and display renderings per grasp id; and whether the log has any
    ``display`` message at all (older logs have none)."""
    views: dict[str, GraspView] = {}
    any_display = False
    for logged in reader.messages(("grasp_event", "estimate", "display")):
        message = logged.message
        if message.type not in ("grasp_event", "estimate", "display"):
            continue
        any_display |= message.type == "display"
        body = message.fields
        grasp_id = body.grasp_id
        if grasp_id is None:  # the display idling between grasps
            continue
        view = views.setdefault(grasp_id, GraspView(grasp_id))
        if message.type == "grasp_event":
            if body.event == "start" and body.object_name is not None:
                view.object_name = body.object_name
        elif message.type == "estimate":
            low, high = body.interval_pa
            view.estimates.append(EstimatePoint(
                message.t_capture_s, body.E_pa, (low, high), body.state, body.reason,
                bool(body.provisional), body.method))
        else:
            view.display.append(DisplayPoint(
                message.t_capture_s, body.phase, float(body.stiffness), body.E_pa,
                bool(body.rigid), bool(body.unknown), bool(body.provisional)))
    return views, any_display


def log_calibrations(info: LogInfo, settings: Settings) -> dict[str, Calibration | str]:
    """Each finger's calibration as the log stores it (``calibration/<finger>/<file>``), checked
    against the finger's sensor; or, for a finger without a usable one, why (a sentence).

    Each is read back from a temporary folder (:func:`tempfile.mkdtemp`); ReportError when it cannot
    be written there (a full disk, a file size limit), naming that folder."""
    out: dict[str, Calibration | str] = {}
    for sensor in settings.sensors:
        name = f"calibration/{sensor.finger}/{Path(sensor.calibration).name}"
        data = info.attachments.get(name) if sensor.calibration else None
        if data is None:
            out[sensor.finger] = f"the log carries no calibration for finger {sensor.finger!r}"
            continue
        try:
            tmp = tempfile.mkdtemp(prefix="teleop-report-calibration-")
        except OSError as exc:
            raise ReportError(f"cannot make a temporary folder for the log's calibration {name} (in "
                              f"{tempfile.gettempdir()}): {exc.strerror or exc}") from exc
        try:
            path = Path(tmp) / Path(name).name
            try:
                path.write_bytes(data)
            except OSError as exc:
                raise ReportError(f"cannot write the log's calibration {name} into the temporary folder {tmp}: "
                                  f"{exc.strerror or exc} (set TMPDIR to a folder with room)") from exc
            try:
                calibration = load_calibration(path)
                check_calibration_fits(calibration, sensor)
            except EstimatorError as exc:
                out[sensor.finger] = f"attachment {name}: {exc}"
                continue
        finally:
            shutil.rmtree(tmp, ignore_errors=True)
        out[sensor.finger] = calibration
    return out


def _finger_settings(settings: Settings, finger: str) -> Settings:
    """``settings`` with the estimator on ``finger``, at the estimator's depth binning, or 1 where
    that finger's sensor cannot be binned (markers are found on the full grid only)."""
    sensor = next(s for s in settings.sensors if s.finger == finger)
    binning = estimator_settings(settings).depth_binning
    binning = 1 if depth_binning_problem(binning, sensor) else binning
    on_finger = dataclasses.replace(settings, sensing=dataclasses.replace(settings.sensing, finger=finger))
    return on_finger.with_section(dataclasses.replace(estimator_settings(settings), depth_binning=binning))


def _moment_indices(t_s: np.ndarray, segment: Segment, reference: np.ndarray, *, dropped: int) -> list[int]:
    """Frames before contact (the reference's last), halfway through the loading phase and at the
    peak force (the estimator's peak frame, the last loading frame; the frame nearest the peak
    when no frame falls in the loading phase); ``dropped``: the frames the stream dropped before
    those its segment indexes (:attr:`~estimator.measurements.GraspMeasurements.frames_dropped`)."""
    mid_t = 0.5 * (segment.t_onset_s + segment.t_peak_s)
    loading = segment.frame_index + dropped
    candidates = loading if loading.size else np.arange(t_s.size)
    mid = int(candidates[np.argmin(np.abs(t_s[candidates] - mid_t))])
    peak = int(loading[-1]) if loading.size else int(np.argmin(np.abs(t_s - segment.t_peak_s)))
    return [int(reference[-1]), mid, peak]


def tactile_moments(
    view: GraspView, *, settings: Settings, calibrations: dict[str, Calibration | str]
) -> None:
    """Fill ``view.segment`` (the estimator's finger's, else the first finger's), ``view.moments``
    (every finger, in :data:`MOMENTS` order) and ``view.notes`` (what cannot be shown, and why)."""
    record = view.record
    try:  # a grasp the estimator cannot segment spoils its own figures, not the report
        measured = {
            stream.finger: measure_grasp(record, settings=_finger_settings(settings, stream.finger), tactile=False)
            for stream in record.frames
        }
    except ComplianceTeleopError as exc:
        view.notes.append(f"not measured: {exc}")
        return
    segments = {finger: m.segment for finger, m in measured.items()}
    view.segment = segments.get(settings.sensing.finger, next(iter(segments.values())))
    if not view.segment:
        view.notes.append(f"no loading phase: {view.segment.reason}")
        return
    for stream in record.frames:
        calibration = calibrations.get(stream.finger, "the settings have no sensor on the finger")
        if isinstance(calibration, str):
            view.notes.append(f"finger {stream.finger!r}: frames without depth: {calibration}")
        try:
            moments = _finger_moments(record, measured[stream.finger], calibration=calibration)
        except ComplianceTeleopError as exc:  # a frame that does not decode spoils one finger, not the report
            view.notes.append(f"finger {stream.finger!r}: {exc}")
            continue
        if isinstance(moments, str):
            view.notes.append(f"finger {stream.finger!r}: {moments}")
            continue
        view.moments.extend(moments)


def _finger_moments(
    record: GraspRecord, measured: GraspMeasurements, *, calibration: Calibration | str
) -> list[TactileMoment] | str:
    """The :data:`MOMENTS` of the finger ``measured`` (force and width only) was taken on, or why
    there are none; depth where a calibration is given."""
    finger, segment, binning = measured.finger, measured.segment, measured.depth_binning
    stream = record.stream(finger)
    reference_index = reference_indices(stream.t_s, segment.t_onset_s - REFERENCE_GUARD_S)
    if reference_index.size == 0:
        return "no frame before the contact onset"
    sensor = measured.sensor
    reference = None
    if not isinstance(calibration, str):
        calibration = grid_calibration(calibration, binning)
        reference = no_contact_reference(record, finger, segment, binning=binning)
    force, out = record.force_n, []
    for name, index in zip(MOMENTS, _moment_indices(stream.t_s, segment, reference_index, dropped=measured.frames_dropped), strict=True):
        image = to_grid(_frame(stream, index, sensor, binning), sensor, binning=binning)
        depth = None
        if reference is not None:
            mask = detect_markers(image, reference) if measured.grid.markers else None
            depth = reconstruct_depth(image, reference, calibration, marker_mask=mask)
        t = float(stream.t_s[index])
        out.append(TactileMoment(finger, name, t, float(np.interp(t, force.t_s, force.value)), image, depth))
    return out


def _frame(stream: FrameStream, index: int, sensor: SensorSettings, binning: int) -> np.ndarray:
    """Frame ``index`` of ``stream``, ``binning`` times smaller on each side, decoded only once its
    header declares ``sensor``'s raw frame size: a few bytes of a corrupt or hostile log may declare
    an image of gigabytes. RecordError naming the frame otherwise, or when it does not decode."""
    where = f"finger {stream.finger!r} frame {index}"
    try:
        image = decode_image(stream.encoded[index], reduce=binning, shape=(sensor.raw_height_px, sensor.raw_width_px))
    except ValueError as exc:
        raise RecordError(f"{where}: {exc}") from exc
    if image is None:
        raise RecordError(f"{where}: {stream.encoding} data does not decode")
    return image
