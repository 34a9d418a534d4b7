"""The one measurement of a grasp: incremental while its streams arrive, or of a whole record.

A :class:`GraspStream` takes a grasp's force samples, width samples and tactile frames in
any interleaving, each with its capture timestamps, exactly as the bus delivers them; or a
grasp record's, whole (:meth:`GraspStream.from_record`, which offline measurement feeds through
it: :func:`~estimator.measure.measure_grasp`). It is the only code that builds
:class:`~estimator.measurements.GraspMeasurements` (:meth:`GraspStream.measurements`, which the
learned model's input is sampled from: :func:`~estimator.inference.sampling.sample_stream`), so
given the same data the live estimate and the offline one are the same floats. It keeps what a
measurement would recompute:

* each frame of the estimator's finger is decoded and warped onto the depth grid once (with
  ``estimator.depth_binning`` above 1 a JPEG is decoded that many times smaller), its depth and
  contact features computed once against the no-contact reference, and its depth reduced to the
  model's input size once (:class:`~estimator.frame_perception.FramePerception`). Frames are decoded
  live on arrival, offline when first needed (all of them, once one fails to decode:
  :meth:`GraspStream.skipping_bad_frames`); measured live, every frame since contact at the first
  estimate that sees it (:meth:`GraspStream.measure_frames`), offline only the frames measured;
  reduced live between frames (:meth:`GraspStream.reduce_depths`: the final estimate reduces only
  the frames that came since);
* the loading phase (:func:`~estimator.load_phase.find_load_phase`) is found again only when a
  sample or the loading-end marker came; the frames are aligned on it
  (:func:`~estimator.segment.align_frames`) once per phase, frame count and ``n_frames``;
* each :meth:`GraspStream.estimate` runs the analytical fits again over everything that has
  arrived (a few hundred samples and tens of frames: vectorised and cheap).

A grasp keeps at most :data:`~estimator.received.MAX_GRASP_FRAMES` frames of each finger (60 s at
30 Hz; at most about 470 MB at the shipped settings), live and offline alike: the first from shortly before
the contact onset (:mod:`estimator.received`); others are counted, not kept (an operator may hold an
object, or the dead-man before touching one, for minutes), and the estimates' notes say how many.

The rig
-------
A grasp is measured on the sensors and the gripper it was captured with: a record's own (its
gripper when it carries one, else the settings'), live the settings' (the robot node publishes no
rig: it reads the service's settings file). Clock-lag corrections are offline only: they correct a
record's timestamps before it is fed (:func:`~estimator.measure.measure_grasp`).

When is loading over?
---------------------
When the fingers stop at the target force the robot node publishes a *loading end* marker with
that time, after the width read at the stop and everything captured before it (:mod:`teleop.node`;
:meth:`GraspStream.mark_loading_end`). From then on :meth:`GraspStream.loading_complete` says the
loading is over once the first frame captured after the peak has come: the segmentation's *peak
frame* (:mod:`estimator.segment`); or, should no frame come, ``PEAK_FRAME_WINDOW_S`` of force past
the peak. The load cell lags the stop, so a stop with no contact in the force yet ends an air
grasp only once ``PEAK_FRAME_WINDOW_S`` of force past the stop has come.

Without a marker (older records and sessions, a gripper whose stop read failed) the end is known
only in hindsight: loading is over when the peak force is followed by :data:`LOADING_SETTLED_S` of
force within the peak tolerance, and a width sample and a frame newer than the peak have arrived
(so no loading frame is still to come and each has widths around it).

A leader-follower grasp (``robot_state`` mode ``following``: :meth:`GraspStream.mark_follow`) has
no marker and no settled end, since the operator may pause, back off and squeeze again: its loading
is over only at the grasp's end event; until then every frame gives a provisional estimate on the
loading envelope so far (:mod:`estimator.load_phase`).

An estimate taken at the loading end rests on what has arrived by then, without the hold and the
release; a whole record holds them, so its offline measurement can differ from such a final (the
width noise is estimated over every width sample, the peak searched over the whole force). A grasp
whose final comes at its end (an operator's) is measured on the same data both ways.

The estimate published is :func:`~estimator.estimate.choose_estimate`'s: the first that is not a
refusal, in the order of the methods asked for (:data:`~estimator.inference.hybrid.FALLBACK_ORDER`).
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from estimator import analytical, gel_layer, plausible
from estimator.errors import FitError, PerceptionError
from estimator.estimate import StreamEstimate, choose_estimate
from estimator.faults import checked_frames, checked_phase
from estimator.features import contact_features
from estimator.frame_perception import FramePerception
from estimator.load_phase import LoadPhase, find_load_phase
from estimator.measurements import (
    REFERENCE_GUARD_S,
    GraspMeasurements,
    check_calibration_fits,
    estimate_measurements,
    resolve_calibration,
)
from estimator.perception.calibration import Calibration
from estimator.perception.depth import reconstruct_depth
from estimator.perception.grid import depth_grid, frame_on_grid, grid_calibration
from estimator.received import MAX_GRASP_FRAMES, Frames, Series
from estimator.segment import PEAK_FRAME_WINDOW_S, Segment, align_frames, frames_in_capture_order
from estimator.settings import DEFAULT_METHODS, estimator_settings
from teleop.errors import RecordError
from teleop.record import GRASP_DONE_EVENT, FrameStream, GraspRecord, Provenance
from teleop.settings import GripperSettings, SensorSettings, Settings

__all__ = ["DEFAULT_METHODS", "LOADING_SETTLED_S", "GraspStream", "StreamEstimate"]

# Force samples this long after the peak, all within the peak tolerance, end the loading phase.
LOADING_SETTLED_S = 0.1


_NO_RECORD = object()


def check_inputs(record: Any = _NO_RECORD, *, settings: Any) -> None:
    """FitError unless ``record`` is a GraspRecord (when given) and ``settings`` is Settings."""
    if record is not _NO_RECORD and not isinstance(record, GraspRecord):
        raise FitError(f"record: expected a GraspRecord (teleop.record.read_record), got {type(record).__name__}")
    if not isinstance(settings, Settings):
        raise FitError(f"settings: expected Settings (teleop.settings.load_settings), got {type(settings).__name__}")


class GraspStream:
    """The measurement and the live estimate of one grasp from its streams (see the module docstring).

    Parameters
    ----------
    settings : Settings
        ``estimator`` (finger, contact force, frames, object Poisson ratio, depth binning); the
        rig too unless ``sensors`` and ``gripper`` are given.
    calibration : Calibration, path or None
        Colour-to-gradient calibration of the estimator's finger (its full image grid; binned
        here as the settings say); a path or None (the file its sensor names) is loaded when a
        frame is first measured. Checked against the sensor then (:meth:`warm_up` checks it at once).
    methods : sequence of str
        Analytical methods :meth:`estimate` runs, in order of preference (see :func:`~estimator.estimate.choose_estimate`).
    grasp_id : str
        Names the grasp in errors and in :meth:`to_record`.
    sensors, gripper : optional
        The rig the grasp is captured with (module notes); None: the settings'.

    Raises
    ------
    FitError
        An unknown method, or no sensor on the estimator's finger.
    """

    def __init__(self, *, settings: Settings, calibration: Calibration | str | Path | None,
                 methods: Sequence[str] = DEFAULT_METHODS, grasp_id: str = "",
                 sensors: Sequence[SensorSettings] | None = None, gripper: GripperSettings | None = None):
        check_inputs(settings=settings)
        if isinstance(methods, (str, bytes)):
            raise FitError(f"methods: expected a sequence of method names, got the str {methods!r}")
        unknown = [m for m in methods if m not in analytical.METHODS]
        if unknown or not methods:
            raise FitError(f"methods {list(methods)}: expected some of {', '.join(analytical.METHODS)}")
        self.settings = settings
        self.sensors = tuple(settings.sensors if sensors is None else sensors)
        self.gripper = settings.gripper if gripper is None else gripper
        self.finger = settings.sensing.finger
        self.sensor = self._sensor(self.finger, FitError, f"SensingSettings.finger = {self.finger!r}")
        self.binning = estimator_settings(settings).depth_binning
        self.grid = depth_grid(self.sensor, self.binning)
        self._calibration_source = calibration
        self._calibration: Calibration | None = None  # on the depth grid, once loaded and checked
        self.calibration_smoothing_px: float | None = None  # the file's, as the measurements record it
        self.methods = tuple(methods)
        self.grasp_id = grasp_id
        self.camera_lag_s: float | None = None  # offline corrections the record's times were fed with
        self.width_lag_s: float | None = None
        self._gripper_unstated = False  # a record's stream without the record's gripper: the settings' stands in
        self._force = Series()
        self._width = Series()
        self._frames: dict[str, Frames] = {}
        # The estimator finger's frames on the depth grid (those of a record that do not decode), the
        # no-contact reference, depths and features.
        self._perception = FramePerception(finger=self.finger, sensor=self.sensor, binning=self.binning,
                                           grid=self.grid, grasp_id=grasp_id)
        self._phase: LoadPhase | None = None  # of the force and width so far; None: find it again
        self._segments: dict[tuple[int, int, int], Segment] = {}  # (n_frames, frames kept, not kept) -> on self._phase
        self._loading_end_s: float | None = None
        self._follow = False

    @classmethod
    def from_record(cls, record: GraspRecord, *, settings: Settings,
                    calibration: Calibration | str | Path | None = None, methods: Sequence[str] = DEFAULT_METHODS,
                    camera_lag_s: float | None = None, width_lag_s: float | None = None) -> GraspStream:
        """A stream fed a whole grasp record, on the rig it was captured with (its sensors, and its
        gripper when it carries one, else the settings').

        Samples and frames go in as recorded (the segmentation skips non-finite or repeated
        timestamps, and frames captured no later than an earlier frame, as live), the
        ``grasp_done`` event as the loading-end marker; the estimator finger's frame times are
        corrected by ``camera_lag_s`` and the width times by ``width_lag_s`` (s, estimated offline:
        :func:`~estimator.measure.measure_grasp`), which the measurements record.

        Raises
        ------
        FitError
            The record has no sensor or no frames on the settings' finger; ``record`` is not a
            GraspRecord or ``settings`` not Settings.
        """
        check_inputs(record, settings=settings)
        finger = settings.sensing.finger
        try:
            record.sensor(finger)
            record.stream(finger)
        except KeyError as exc:
            raise FitError(f"SensingSettings.finger = {finger!r}: {exc.args[0]}") from exc
        stream = cls(settings=settings, calibration=calibration, methods=methods, sensors=record.sensors,
                     gripper=record.gripper)
        stream.camera_lag_s, stream.width_lag_s, stream._gripper_unstated = camera_lag_s, width_lag_s, record.gripper is None
        stream._force = Series.of(record.force_n)
        stream._width = Series.of(record.width_m, shift_s=width_lag_s)
        stream._loading_end_s = record.events.get(GRASP_DONE_EVENT)
        cut_s = stream._keep_from_s() if any(len(s.t_s) > MAX_GRASP_FRAMES for s in record.frames) else np.inf
        stream._frames = {s.finger: Frames.of_record(s, shift_s=camera_lag_s if s.finger == finger else None,
                                                     keep_from_s=cut_s) for s in record.frames}
        return stream

    def for_finger(self, finger: str, *, calibration: Calibration | str | Path | None) -> GraspStream:
        """A stream of the data received so far that measures ``finger`` (on its full grid when its
        sensor has markers: their dots are found there only), e.g. a model's marker finger.

        Raises
        ------
        FitError
            The rig has no sensor on ``finger``.
        """
        sensor = self._sensor(finger, FitError, f"finger {finger!r}")
        est = estimator_settings(self.settings)
        binning = 1 if sensor.markers else est.depth_binning
        settings = dataclasses.replace(self.settings, sensing=dataclasses.replace(self.settings.sensing, finger=finger))
        twin = GraspStream(settings=settings.with_section(dataclasses.replace(est, depth_binning=binning)),
                           calibration=calibration, methods=self.methods, grasp_id=self.grasp_id,
                           sensors=self.sensors, gripper=self.gripper)
        twin._force, twin._width = self._force.copy(), self._width.copy()
        twin._frames = {name: frames.copy() for name, frames in self._frames.items()}
        twin._loading_end_s, twin._follow, twin.width_lag_s = self._loading_end_s, self._follow, self.width_lag_s
        return twin

    def _sensor(self, finger: str, error: type[Exception], where: str) -> SensorSettings:
        """The rig's sensor on ``finger``; ``error`` naming ``where`` when it has none."""
        for sensor in self.sensors:
            if sensor.finger == finger:
                return sensor
        raise error(f"{where}: no sensor on finger {finger!r}: the rig has {[s.finger for s in self.sensors]}")

    @property
    def calibration(self) -> Calibration:
        """The calibration on the depth grid, loaded and checked against the sensor on first use.

        Raises CalibrationError when none can be loaded, or it was made for another image shape
        or pixel pitch.
        """
        if self._calibration is None:
            calibration = resolve_calibration(self.sensor, self._calibration_source)
            check_calibration_fits(calibration, self.sensor)
            self._calibration = grid_calibration(calibration, self.binning)
            self.calibration_smoothing_px = calibration.smoothing_px
        return self._calibration

    def warm_up(self) -> None:
        """Load and check the calibration, and fill the caches the first estimate would otherwise
        fill mid-grasp (about a second on 2 cores): the depth solver's and the feature fit's for
        this image size, and the series method's gel-layer table for this gel."""
        flat = np.full((*self.grid.image_shape, 3), 128, dtype=np.uint8)
        depth = reconstruct_depth(flat, flat, self.calibration)
        contact_features(depth[None], pixel_pitch_m=self.grid.pixel_pitch_m,
                         contact_threshold_m=self.grid.contact_threshold_m)
        gel_layer.gel_layer_factor(0.0, gel_thickness_m=self.sensor.gel_thickness_m,
                                   gel_poisson=self.sensor.gel_poisson)

    # ------------------------------------------------------------------ input

    @property
    def frame_count(self) -> int:
        """Frames of the estimator's finger kept."""
        return len(self._frames.get(self.finger, Frames()).t_s)

    @property
    def newest_force_s(self) -> float:
        """Capture time of the newest force sample (-inf before the first)."""
        return self._force.last_t_s

    def add_force(self, t_s: np.ndarray, value_n: np.ndarray) -> None:
        """Load-cell samples: capture times (s) and force (N). PerceptionError if malformed."""
        self._force.add(t_s, value_n, f"grasp {self.grasp_id!r} force")
        self._phase = None

    def add_width(self, t_s: np.ndarray, value_m: np.ndarray) -> None:
        """Gripper width samples: capture times (s) and width (m). PerceptionError if malformed."""
        self._width.add(t_s, value_m, f"grasp {self.grasp_id!r} width")
        self._phase = None

    def add_frame(self, finger: str, t_s: float, data: np.ndarray | bytes, encoding: str) -> bool:
        """One tactile frame as captured; True when it is the estimator's finger's and was kept.

        The estimator's frames are decoded and warped onto the depth grid here, once; other fingers'
        frames are kept as they came. Once :data:`~estimator.received.MAX_GRASP_FRAMES` frames of a
        finger were kept, the oldest is dropped for a new one while it is from before the contact onset
        (:meth:`~estimator.received.Frames.make_room`); once none is, later frames are checked and counted
        (:meth:`frames_not_kept`), not kept or decoded. Raises PerceptionError (the frame is not kept) for an
        estimator frame that does not decode or has the wrong size, a finger without a sensor, a
        non-finite time or an encoding other than the finger's earlier ones. Such a frame still counts
        toward the cap, as in the record it is in (one of a finger without a sensor excepted: a record
        has none), and errors name a frame by its index there. A frame captured no later
        than an earlier one of its finger (out of order or duplicated) is kept as it came, and skipped by
        the segmentation, whose notes count it (:func:`~estimator.segment.unplaced_frames`), as offline.
        """
        frames = self._frames.get(finger, Frames())
        where = f"grasp {self.grasp_id!r} frame {frames.arrived} of finger {finger!r}"
        sensor = self._sensor(finger, PerceptionError, where)
        self._frames[finger] = frames
        kept = len(frames.t_s)  # room is made first, as for the frame in a record (estimator.received)
        if frames.make_room(self._keep_from_s) and len(frames.t_s) < kept and finger == self.finger:
            self._perception.drop_first()
        try:
            frames.check(t_s, encoding, where=where)
            if frames.full:  # a long hold would grow the service without bound (estimator.received)
                frames.not_kept += 1
                return False
            if finger == self.finger:
                self._perception.images[len(frames.t_s)] = frame_on_grid(data, encoding, sensor, binning=self.binning, where=where)
            frames.add(t_s, data, encoding, where=where)
        except PerceptionError:
            frames.count_refused(t_s)  # its record holds it: offline it takes a place among those kept
            raise
        return finger == self.finger

    def frames_not_kept(self, finger: str) -> int:
        """Frames of ``finger`` that came once :data:`~estimator.received.MAX_GRASP_FRAMES` were kept and
        no room was made (the first ones dropped from before contact are not among them)."""
        return self._frames.get(finger, Frames()).not_kept

    def _keep_from_s(self) -> float:
        """Capture time (s) from which frames are needed: the no-contact reference's cut before the contact
        onset in the force so far (:meth:`~estimator.frame_perception.FramePerception.reference_index`);
        infinite before contact."""
        phase = self._load_phase()
        return phase.segment_fields["t_onset_s"] - REFERENCE_GUARD_S if phase else np.inf

    def mark_loading_end(self, t_s: float) -> None:
        """The loading end marker: the gripper's fingers stopped at ``t_s`` (s, capture clock).

        Raises PerceptionError for a time that is not finite.
        """
        if not np.isfinite(t_s):
            raise PerceptionError(f"grasp {self.grasp_id!r} loading end at {t_s!r}: not a finite time")
        self._loading_end_s = float(t_s)
        self._phase = None

    def mark_follow(self) -> None:
        """The grasp is a leader-follower grasp: an operator drives the fingers' target (the robot
        node's ``robot_state`` mode ``following``). It has no loading-end marker, and its loading is
        over only at the grasp's end (module notes)."""
        self._follow = True

    @property
    def follow(self) -> bool:
        """Whether :meth:`mark_follow` was called."""
        return self._follow

    @property
    def loading_end_s(self) -> float | None:
        """Time of the loading end marker, or None before one came."""
        return self._loading_end_s

    # ------------------------------------------------------------------ state

    def segment(self, *, n_frames: int | None = None) -> Segment:
        """The segmentation of what has arrived (falsy with a reason before contact), its frames
        sampled at ``n_frames`` (default ``estimator.n_frames``)."""
        n_frames = estimator_settings(self.settings).n_frames if n_frames is None else n_frames
        phase = self._load_phase()
        # Frames are appended, the first dropped: their counts name the frame times aligned (and the notes).
        frames = self._frames.get(self.finger, Frames())
        key = (n_frames, len(frames.t_s), not_kept := frames.not_kept, dropped := frames.dropped)
        cached = self._segments.get(key)
        if cached is None:
            received_t = self._perception.times(frames)
            frame_t = self._frame_times()  # align_frames drops and counts the frames it cannot place
            cached = checked_frames(align_frames(phase, received_t, n_frames=n_frames, finger=self.finger), frame_t,
                                    camera_hz=self.sensor.camera_hz, finger=self.finger)
            if skipped := self._perception.undecodable:  # a live stream drops them
                cached = dataclasses.replace(cached, notes=(*cached.notes, f"skipped {len(skipped)} frames "
                                             f"of finger {self.finger!r}: {next(iter(skipped.values()))}"))
            cap = f"(a grasp keeps at most {MAX_GRASP_FRAMES})"
            if dropped:
                cached = dataclasses.replace(cached, notes=(*cached.notes, f"its first {dropped} frames of finger "
                                             f"{self.finger!r}, from before contact, not kept {cap}"))
            if not_kept:
                cached = dataclasses.replace(cached, notes=(*cached.notes, f"{not_kept} frames of finger "
                                             f"{self.finger!r} after its first {dropped + MAX_GRASP_FRAMES} not "
                                             f"kept {cap}"))
            self._segments[key] = cached
        return cached

    def _load_phase(self) -> LoadPhase:
        """The loading phase in the force and width so far, found again only after new samples or
        the loading-end marker (a frame alone does not move it)."""
        if self._phase is None:
            self._segments.clear()  # aligned on the phase found before
            force, width = self._force.samples(), self._width.samples()
            phase = find_load_phase(force.t_s, force.value, width.t_s, width.value,
                                    contact_force_n=estimator_settings(self.settings).contact_force_n,
                                    stopped_s=self._loading_end_s, max_width_m=self.gripper.max_width_m,
                                    max_force_n=self.gripper.target_force_n)
            if self._gripper_unstated:  # its force limit is not the record's: its refusal says so
                phase = dataclasses.replace(phase, reason=plausible.unstated_gripper(phase.reason))
            self._phase = checked_phase(phase, force_t_s=force.t_s, width_t_s=width.t_s, width_hz=self.gripper.width_read_hz,
                                        force_hz=self.settings.load_cell.sample_rate_hz)
        return self._phase

    def loading_complete(self, segment: Segment | None = None) -> bool:
        """Whether the loading phase has ended and every loading frame, the peak frame included,
        has arrived (module docstring)."""
        if self._follow and self._loading_end_s is None:
            return False  # an operator may squeeze on: its grasp's end ends the loading
        segment = self.segment() if segment is None else segment
        if not segment or not np.isfinite(segment.t_peak_s):
            # The load cell's readings lag the fingers' stop: no contact is final only once they ran on past it.
            return (self._loading_end_s is not None
                    and self.newest_force_s >= self._loading_end_s + PEAK_FRAME_WINDOW_S)
        frame_after_peak = self._newest_frame_s() > segment.t_peak_s
        if self._loading_end_s is not None:
            return frame_after_peak or self.newest_force_s >= segment.t_peak_s + PEAK_FRAME_WINDOW_S
        return (self.newest_force_s >= segment.t_peak_s + LOADING_SETTLED_S
                and self._width.last_t_s >= segment.t_peak_s and frame_after_peak)

    def _frame_times(self) -> np.ndarray:
        """Capture times of the estimator finger's frames in the order they came, NaN for those skipped: that
        do not decode, or whose time is not after an earlier frame's (:func:`~estimator.segment.unplaced_frames`)."""
        return frames_in_capture_order(self._perception.times(self._frames.get(self.finger, Frames())))[0]

    def skipping_bad_frames(self, compute: Callable[[], Any]) -> Any:
        """``compute()``; run again after :meth:`decode_frames` when a record's frame it needs does not decode."""
        try:
            return compute()
        except (RecordError, PerceptionError):
            if not self.decode_frames():
                raise  # not a frame that fails to decode
            return compute()

    def decode_frames(self) -> bool:
        """Decode a record's frames of the estimator's finger, as :meth:`add_frame` does live: whether one that does
        not decode (or has the wrong size) was newly skipped (named in the notes); the error when none decodes."""
        try:
            return self._perception.decode(self._frames.get(self.finger, Frames()))
        finally:
            self._segments.clear()  # aligned with the frames skipped before

    # ------------------------------------------------------------------ measurement

    def measurements(self, segment: Segment | None = None, *, frames: np.ndarray | None = None,
                     tactile: bool = True) -> GraspMeasurements:
        """:class:`~estimator.measurements.GraspMeasurements` of what has arrived: force, width and
        approach at every loading frame and, with ``tactile``, depth and contact features.

        Decodes and measures only the frames it holds (cached): the no-contact frames of the
        reference, the loading frames (or ``frames`` of them) and the hold frames when the fits use
        them (the width times were corrected: ``width_lag_s``).

        Parameters
        ----------
        segment : Segment, optional
            The segmentation of what has arrived (:meth:`segment`; computed when not given).
        frames : array of int, optional
            Distinct positions within the loading frames (``segment.frame_index``) to measure, in
            the order given; None measures every loading frame. ``t_s``, ``force_n``, ``width_m``
            and ``approach_m`` are restricted to them as well.
        tactile : bool
            Measure depth and contact features; False measures force and width only (enough for
            ``no_tactile``) and decodes nothing.

        Returns
        -------
        GraspMeasurements
            ``segment`` is falsy with a reason when the grasp has no usable loading phase;
            ``features`` is None with ``tactile_reason`` when frames cannot be used.

        Raises
        ------
        CalibrationError
            A frame is to be measured and no calibration can be loaded, or it does not fit the sensor.
        FitError
            ``frames`` are not distinct positions of loading frames.
        RecordError, PerceptionError
            A frame of a given ``segment`` does not decode (one taken before :meth:`decode_frames`).
        """
        if tactile and segment is None:
            return self.skipping_bad_frames(lambda: self.measurements(self.segment(), frames=frames))
        segment = self.segment() if segment is None else segment
        stiffness = self.gripper.finger_stiffness_n_per_m

        def approach(width_m: np.ndarray, force_n: np.ndarray) -> np.ndarray:
            return analytical.approach_per_finger(width_m, force_n, onset_width_m=segment.onset_width_m,
                                                  finger_stiffness_n_per_m=stiffness)

        m = GraspMeasurements(
            finger=self.finger, sensor=self.sensor, segment=segment, finger_stiffness_n_per_m=stiffness,
            object_poisson=self.settings.sensing.object_poisson, t_s=segment.frame_t_s,
            force_n=segment.frame_force_n, width_m=segment.frame_width_m,
            approach_m=approach(segment.frame_width_m, segment.frame_force_n), camera_lag_s=self.camera_lag_s,
            width_lag_s=self.width_lag_s, hold_force_n=segment.hold_force_n,
            hold_approach_m=approach(segment.hold_width_m, segment.hold_force_n), depth_binning=self.binning,
            frames_dropped=self._frames.get(self.finger, Frames()).dropped)
        loading_index = segment.frame_index
        if frames is not None:
            frames = np.asarray(frames)
            count = loading_index.size
            if (frames.ndim != 1 or frames.dtype.kind not in "iu" or np.unique(frames).size != frames.size
                    or np.any((frames < 0) | (frames >= count))):
                raise FitError(f"frames {frames!r}: expected distinct positions 0..{count - 1} of the loading frames")
            m = dataclasses.replace(m, t_s=m.t_s[frames], force_n=m.force_n[frames], width_m=m.width_m[frames],
                                    approach_m=m.approach_m[frames])
            loading_index = loading_index[frames]
        if not tactile:
            return m
        perception = self._perception
        why = segment.reason or segment.frame_reason or perception.reference_reason(frame_t := self._frame_times(), segment)
        if why:
            return dataclasses.replace(m, tactile_reason=why)
        calibration = self.calibration  # loaded and checked before a frame is decoded
        # Hold frames enter the fits only with the width lag corrected (measurements._with_hold_point).
        hold_index = segment.hold_index if self.width_lag_s is not None else segment.hold_index[:0]
        return perception.measured(m, self._frames[self.finger], frame_t, segment, loading_index, hold_index,
                                   calibration, calibration_smoothing_px=self.calibration_smoothing_px)

    def measure_frames(self, segment: Segment | None = None) -> None:
        """Compute the depth and features of every frame since contact not measured yet (live), ahead
        of the estimate that will need them: whether or not widths around it have come, so no
        burst of frames waits for the next width sample (e.g. when the force shows the contact only
        after the frames came)."""
        segment = self.segment() if segment is None else segment
        perception = self._perception
        if segment.reason or perception.reference_reason(frame_t := self._frame_times(), segment):
            return
        calibration = self.calibration
        frames = self._frames[self.finger]
        perception.use_reference(frames, frame_t, segment)
        for position in np.flatnonzero(frame_t >= segment.t_contact_s):
            perception.features(frames, int(position), calibration)

    # ------------------------------------------------------------------ estimation

    def estimate(self, segment: Segment | None = None) -> StreamEstimate:
        """Every method over what has arrived, and the one to publish.

        Computes depth and features of frames since contact not seen before (:meth:`measure_frames`;
        of all of them when the no-contact reference moved); everything else is cached.
        """
        if segment is None:
            return self.skipping_bad_frames(lambda: self.estimate(self.segment()))
        started = time.perf_counter()
        self.measure_frames(segment)
        measurements = self.measurements(segment)
        estimates = tuple(estimate_measurements(measurements, m) for m in self.methods)
        used = segment.frame_t_s if measurements.features is not None else np.zeros(0)
        chosen = choose_estimate(estimates).with_latency(time.perf_counter() - started)
        return StreamEstimate(estimate=chosen, estimates=estimates, segment=segment,
                              t_data_s=self._newest_data_s(used), loading_frames=int(used.size))

    def last_loading_frame_s(self, segment: Segment) -> float:
        """Capture time of the last loading frame of ``segment``; without one, of the newest
        frame received that the segmentation places (of the newest force sample before any)."""
        return self._newest_data_s(segment.frame_t_s)

    def _newest_data_s(self, loading_t_s: np.ndarray) -> float:
        newest_s = float(loading_t_s[-1]) if loading_t_s.size else self._newest_frame_s()
        return newest_s if np.isfinite(newest_s) else self._force.last_t_s

    def _newest_frame_s(self) -> float:
        """Capture time of the newest frame the segmentation places, -inf before one (a skipped one is NaN)."""
        frame_t = self._frame_times()
        return float(np.max(frame_t, initial=-np.inf, where=np.isfinite(frame_t)))

    def reduce_depths(self, size_px: tuple[int, int] | None, window_m: tuple[float, float] | None = None) -> None:
        """Reduce every depth computed so far to ``size_px`` now, as :meth:`reduced_depths` will
        (between frames, so the final estimate reduces only the frames that came since)."""
        self._perception.reduce_depths(size_px, window_m)

    def reduced_depths(self, positions: np.ndarray, size_px: tuple[int, int] | None,
                       window_m: tuple[float, float] | None = None) -> np.ndarray:
        """Depth of the frames at ``positions`` (frames received; measured by the last
        :meth:`measurements`) reduced to the model's input (:func:`~estimator.inference.inputs.reduce_images`),
        float32 (n, rows, cols); each frame is reduced once per size and window."""
        return self._perception.reduced_depths(positions, size_px, window_m)

    # ------------------------------------------------------------------ export

    def to_record(self) -> GraspRecord:
        """What has arrived as a grasp record on this stream's rig (source ``hardware``: data as the
        bus delivered it)."""
        fingers = {s.finger for s in self.sensors}
        streams = tuple(FrameStream(finger, f.times(), tuple(f.encoded), f.encoding or "jpeg")
                        for finger, f in self._frames.items() if finger in fingers and f.t_s)  # not refused only
        return GraspRecord(
            sensors=self.sensors, gripper=self.gripper, frames=streams, force_n=self._force.samples(),
            width_m=self._width.samples(),
            provenance=Provenance(source="hardware", extra={"grasp_id": self.grasp_id},
                                  style="operator" if self._follow else "script"),
            events={} if self._loading_end_s is None else {GRASP_DONE_EVENT: self._loading_end_s},
        )
