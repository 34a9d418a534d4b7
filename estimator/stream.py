"""Incremental estimation of one grasp while its streams arrive: the live twin of :func:`measure_grasp`.

A :class:`GraspStream` takes a grasp's force samples, width samples and tactile frames in
any interleaving, each with its capture timestamps, exactly as the bus delivers them. It
keeps what batch estimation would recompute:

* each frame of the estimator's finger is decoded and warped onto the depth grid once, on arrival
  (:func:`~estimator.perception.grid.frame_on_grid`: with ``estimator.depth_binning`` above 1 a
  JPEG is decoded that many times smaller and warped straight onto the binned grid);
* depth and contact features of a frame (loading and hold frames alike) are computed once, at
  the first estimate after contact that sees the frame (whether or not widths around it have
  arrived yet, so no burst of frames waits for the next width sample), against the no-contact
  reference (the median of the last frames before the onset, as
  :func:`~estimator.measure.measure_grasp` takes it; if later data moves the reference, the
  cached depths are dropped and recomputed);
* the loading phase in the force and width (:func:`~estimator.segment.find_load_phase`) is
  found again only when a force or width sample or the loading-end marker came; every
  segmentation aligns the frames received on it (:func:`~estimator.segment.align_frames`), and
  the model's sample of frames (:meth:`GraspStream.sampled_grasp`) is aligned on the same phase;
* depth maps are reduced to the model's input size once per frame (:meth:`GraspStream.reduce_depths`
  between frames: the final estimate then reduces only the frames that came since);
* on every :meth:`GraspStream.estimate` the analytical fits run again over everything that has
  arrived (a few hundred samples and tens of frames: vectorised and cheap).

Given the same data, the estimate equals :func:`~estimator.measure.estimate_grasp` on the
grasp record (without clock-lag corrections): same segmentation, reference, depth, features
and fits; and :meth:`GraspStream.sampled_grasp` equals
:func:`~estimator.inference.sampling.sample_grasp` on it (the learned model's input) from the
cached depths, without measuring a frame again.

When is loading over?
---------------------
The gripper's grasp command completes when the fingers stop at the target force; the robot
node then publishes a *loading end* marker with that time, after the width the gripper read
at the stop and everything captured before it (:mod:`teleop.node`).
:meth:`GraspStream.mark_loading_end` records it, and from then on
:meth:`GraspStream.loading_complete` says the loading is over as soon as the first frame
captured after the peak has come (within a frame period): the segmentation's *peak frame*,
which shows the peak state (:mod:`estimator.segment`); or, should no frame come,
``PEAK_FRAME_WINDOW_S`` of force past the peak. The load cell's readings lag the stop (a
stiff object loads within a few of its samples), so a stop with no contact in the force yet
ends the grasp as an air grasp only once ``PEAK_FRAME_WINDOW_S`` of force past the stop has
come.

Without a marker (recorded grasps and sessions from before it, a gripper whose stop read
failed) the end is only known in hindsight, as force, width and frames come at their own
rates (80, 10 and 30 Hz on the rig): loading is over when the segmentation's peak force is
followed by :data:`LOADING_SETTLED_S` of force samples that stay within the peak tolerance,
and a width sample and a tactile frame newer than the peak have arrived (so no loading frame
is still to come and each has widths around it).

A leader-follower grasp (an operator drives the fingers' target width; the estimator service
learns it from the robot node's ``robot_state`` mode ``following`` and calls
:meth:`GraspStream.mark_follow`) has no marker and no settled end: the operator may pause, back
off and squeeze again, so a flat force says nothing. Its loading is over only at the grasp's end
event; until then every frame gives a provisional estimate, on the loading envelope so far
(:mod:`estimator.segment`: the segmentation without a stop).

Either way an estimate taken then rests on the loading frames alone: the hold frames batch
estimation adds (from ``segment.HOLD_SETTLE_S`` after the peak until the release) have not
been captured yet.

Which estimate is published
---------------------------
:func:`choose_estimate` takes the first estimate that is not a refusal, in the order of the
methods asked for (the order of :data:`~estimator.inference.hybrid.FALLBACK_ORDER` by default),
so a bound is published when it is all a method can say, and a refusal only when every method
refuses.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Sequence
from dataclasses import dataclass, field

import cv2
import numpy as np

from estimator import analytical
from estimator.errors import FitError, PerceptionError
from estimator.estimate import Estimate
from estimator.features import ContactFeatures, contact_features
from estimator.inference.inputs import ANALYTICAL_METHODS, reduce_images
from estimator.inference.sampling import SampledGrasp, sample_positions
from estimator.measure import (
    REFERENCE_GUARD_S,
    GraspMeasurements,
    check_calibration_fits,
    estimate_grasp,
    median_frame,
    reference_indices,
)
from estimator.perception.calibration import Calibration
from estimator.perception.depth import reconstruct_depth
from estimator.perception.grid import (
    ENCODINGS,
    DepthGrid,
    depth_grid,
    frame_on_grid,
    grid_calibration,
    raw_frame,
)
from estimator.perception.markers import detect_markers
from estimator.segment import PEAK_FRAME_WINDOW_S, LoadPhase, Segment, align_frames, find_load_phase
from estimator.settings import DEFAULT_METHODS, estimator_settings
from teleop.errors import SettingsError
from teleop.record import GRASP_DONE_EVENT, FrameStream, GraspRecord, Provenance, Samples
from teleop.settings import Settings

__all__ = [
    "DEFAULT_METHODS",
    "configured_methods",
    "LOADING_SETTLED_S",
    "GraspStream",
    "StreamEstimate",
    "choose_estimate",
    "measure_frame",
]

def configured_methods(settings: Settings) -> tuple[str, ...]:
    """The analytical methods ``estimator.methods`` names (each checked when the settings are
    read), or the defaults when it names none."""
    return estimator_settings(settings).methods or DEFAULT_METHODS


# Force samples this long after the peak, all within the peak tolerance, end the loading phase.
LOADING_SETTLED_S = 0.1


def measure_frame(frame: np.ndarray, reference: np.ndarray, calibration: Calibration,
                  grid: DepthGrid) -> tuple[np.ndarray, ContactFeatures]:
    """Depth (m, float32, the calibration's grid) and contact features of one frame on the depth grid
    (:func:`~estimator.perception.grid.frame_on_grid`) against its no-contact reference, as
    :func:`~estimator.measure.measure_tactile` measures each frame (markers found and inpainted first
    when the sensor has them). ``calibration`` and ``grid`` are those of the depth grid
    (:func:`~estimator.perception.grid.grid_calibration`, :func:`~estimator.perception.grid.depth_grid`)."""
    mask = detect_markers(frame, reference) if grid.markers else None
    depth = reconstruct_depth(frame, reference, calibration, marker_mask=mask)
    return depth, contact_features(depth[None], pixel_pitch_m=grid.pixel_pitch_m,
                                   contact_threshold_m=grid.contact_threshold_m)


def choose_estimate(estimates: Sequence[Estimate]) -> Estimate:
    """The first estimate that is not a refusal; if all refuse, one refusal naming every reason."""
    if not estimates:
        raise FitError("choose_estimate needs at least one estimate")
    for estimate in estimates:
        if estimate:
            return estimate
    reasons = "; ".join(f"{e.method}: {e.reason}" for e in estimates)
    return Estimate.refuse(estimates[0].method, f"every method refuses ({reasons})")


@dataclass(frozen=True)
class StreamEstimate:
    """One estimate of a grasp in progress.

    Attributes
    ----------
    estimate : Estimate
        The published one (:func:`choose_estimate`), stamped with the compute time.
    estimates : tuple of Estimate
        Every method asked for, in order.
    segment : Segment
        The segmentation it rests on.
    t_data_s : float
        Capture time (s, stream clock) of the newest loading frame the fits used; without
        loading frames, of the newest frame received.
    loading_frames : int
        Loading frames the fits used.
    """

    estimate: Estimate
    estimates: tuple[Estimate, ...]
    segment: Segment
    t_data_s: float
    loading_frames: int


@dataclass
class _Series:
    """A growing timestamped scalar stream."""

    t_s: list[np.ndarray] = field(default_factory=list)
    value: list[np.ndarray] = field(default_factory=list)
    last_t_s: float = -np.inf

    def add(self, t_s: np.ndarray, value: np.ndarray, what: str) -> None:
        t = np.asarray(t_s, dtype=np.float64).ravel()
        v = np.asarray(value, dtype=np.float64).ravel()
        if t.shape != v.shape:
            raise PerceptionError(f"{what}: {t.size} timestamps but {v.size} values")
        if not (np.isfinite(t).all() and np.isfinite(v).all()):
            raise PerceptionError(f"{what}: timestamps and values must be finite")
        if t.size:
            self.t_s.append(t)
            self.value.append(v)
            self.last_t_s = max(self.last_t_s, float(t.max()))

    def samples(self) -> Samples:
        if not self.t_s:
            return Samples(np.zeros(0), np.zeros(0))
        return Samples(np.concatenate(self.t_s), np.concatenate(self.value))


@dataclass
class _Frames:
    """Frames of one finger as received: capture times and the bytes as captured."""

    t_s: list[float] = field(default_factory=list)
    encoded: list[bytes] = field(default_factory=list)
    encoding: str | None = None


class GraspStream:
    """The live estimate of one grasp from its streams (see the module docstring).

    Parameters
    ----------
    settings : Settings
        ``estimator`` (finger, contact force, frames, object Poisson ratio, depth binning), the
        sensors and ``gripper.finger_stiffness_n_per_m``, as for :func:`~estimator.measure.measure_grasp`.
    calibration : Calibration
        Colour-to-gradient calibration of the estimator's finger (its full image grid; binned
        here as the settings say).
    methods : sequence of str
        Analytical methods to run, in order of preference (see :func:`choose_estimate`).
    grasp_id : str
        Names the grasp in errors and in :meth:`to_record`.

    Raises
    ------
    CalibrationError
        The calibration does not fit the finger's image grid or pixel pitch.
    FitError
        An unknown method, or no sensor on the estimator's finger.
    """

    def __init__(self, *, settings: Settings, calibration: Calibration,
                 methods: Sequence[str] = DEFAULT_METHODS, grasp_id: str = ""):
        unknown = [m for m in methods if m not in analytical.METHODS]
        if unknown or not methods:
            raise FitError(f"methods {list(methods)}: expected some of {', '.join(analytical.METHODS)}")
        self.settings = settings
        self.finger = settings.sensing.finger
        try:
            self.sensor = settings.sensor(self.finger)
        except SettingsError as exc:
            raise FitError(f"SensingSettings.finger = {self.finger!r}: {exc}") from exc
        check_calibration_fits(calibration, self.sensor)
        self.binning = estimator_settings(settings).depth_binning
        self.grid = depth_grid(self.sensor, self.binning)
        self.calibration = grid_calibration(calibration, self.binning)
        self.calibration_smoothing_px = calibration.smoothing_px  # the file's, as measure_tactile records it
        self.methods = tuple(methods)
        self.grasp_id = grasp_id
        self._force = _Series()
        self._width = _Series()
        self._frames: dict[str, _Frames] = {}
        self._images: list[np.ndarray] = []  # the estimator finger's frames, warped and cropped
        self._reference_key: tuple[int, ...] | None = None
        self._reference: np.ndarray | None = None
        self._features: dict[int, ContactFeatures] = {}  # frame position -> features of that frame
        self._depth: dict[int, np.ndarray] = {}  # frame position -> its depth (m), for the model's input
        self._reduced: dict[tuple, np.ndarray] = {}  # (position, size, window) -> reduced depth
        self._phase: LoadPhase | None = None  # of the force and width so far; None: find it again
        self._loading_end_s: float | None = None
        self._follow = False

    def warm_up(self) -> None:
        """Fill the caches the first estimate would otherwise fill mid-grasp (about a second on
        2 cores): the depth solver's and the feature fit's for this image size, and the split
        method's gel-layer table for this gel."""
        flat = np.full((*self.grid.image_shape, 3), 128, dtype=np.uint8)
        depth = reconstruct_depth(flat, flat, self.calibration)
        contact_features(depth[None], pixel_pitch_m=self.grid.pixel_pitch_m,
                         contact_threshold_m=self.grid.contact_threshold_m)
        analytical.gel_layer_factor(0.0, gel_thickness_m=self.sensor.gel_thickness_m,
                                    gel_poisson=self.sensor.gel_poisson)

    # ------------------------------------------------------------------ input

    @property
    def frame_count(self) -> int:
        """Frames of the estimator's finger received."""
        return len(self._images)

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
        """One tactile frame as captured; True when it is the estimator's finger.

        The estimator's frames are decoded and warped onto the depth grid here, once; other fingers' frames are
        kept as they came (for :meth:`to_record`). Raises PerceptionError (the frame is not
        kept) for an estimator frame that does not decode or has the wrong size, an unknown
        finger, a non-finite time or an encoding other than the finger's earlier ones.
        """
        where = f"grasp {self.grasp_id!r} frame {len(self._frames.get(finger, _Frames()).t_s)} of finger {finger!r}"
        if not np.isfinite(t_s):
            raise PerceptionError(f"{where}: capture time {t_s!r} is not finite")
        try:
            sensor = self.settings.sensor(finger)
        except SettingsError as exc:
            raise PerceptionError(f"{where}: {exc}") from exc
        if encoding not in ENCODINGS:
            raise PerceptionError(f"{where}: encoding {encoding!r}, expected one of {', '.join(ENCODINGS)}")
        frames = self._frames.setdefault(finger, _Frames())
        stored = "png" if encoding == "raw" else encoding
        if frames.encoding not in (None, stored):
            raise PerceptionError(f"{where}: {encoding} after {frames.encoding} frames")
        if finger == self.finger:
            self._images.append(frame_on_grid(data, encoding, sensor, binning=self.binning, where=where))
        if encoding == "raw":  # kept lossless, as a grasp record stores raw frames
            data = cv2.imencode(".png", raw_frame(data, where=where), [cv2.IMWRITE_PNG_COMPRESSION, 1])[1]
        frames.encoding = stored
        frames.t_s.append(float(t_s))
        frames.encoded.append(bytes(data) if isinstance(data, bytes | bytearray) else np.ascontiguousarray(data).tobytes())
        return finger == self.finger

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

    def segment(self) -> Segment:
        """The segmentation of what has arrived (falsy with a reason before contact)."""
        return align_frames(self._load_phase(), self._frame_times(), n_frames=estimator_settings(self.settings).n_frames)

    def _load_phase(self) -> LoadPhase:
        """The loading phase in the force and width so far, found again only after new samples or
        the loading-end marker (a frame alone does not move it)."""
        if self._phase is None:
            force, width = self._force.samples(), self._width.samples()
            self._phase = find_load_phase(force.t_s, force.value, width.t_s, width.value,
                                          contact_force_n=estimator_settings(self.settings).contact_force_n,
                                          stopped_s=self._loading_end_s)
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
        frame_t = self._frame_times()
        frame_after_peak = frame_t.size > 0 and float(frame_t.max()) > segment.t_peak_s
        if self._loading_end_s is not None:
            return frame_after_peak or self.newest_force_s >= segment.t_peak_s + PEAK_FRAME_WINDOW_S
        return (self.newest_force_s >= segment.t_peak_s + LOADING_SETTLED_S
                and self._width.last_t_s >= segment.t_peak_s and frame_after_peak)

    def _frame_times(self) -> np.ndarray:
        return np.asarray(self._frames.get(self.finger, _Frames()).t_s, dtype=np.float64)

    # ------------------------------------------------------------------ estimation

    def estimate(self, segment: Segment | None = None) -> StreamEstimate:
        """Every method over what has arrived, and the one to publish.

        Computes depth and features of frames since contact not seen before (and of all of
        them when the no-contact reference moved); everything else is cached.
        """
        started = time.perf_counter()
        segment = self.segment() if segment is None else segment
        measurements = self._measure(segment)
        estimates = tuple(estimate_grasp(measurements, m, settings=self.settings) for m in self.methods)
        used = segment.frame_t_s if measurements.features is not None else np.zeros(0)
        chosen = choose_estimate(estimates).with_latency(time.perf_counter() - started)
        return StreamEstimate(estimate=chosen, estimates=estimates, segment=segment,
                              t_data_s=self._newest_data_s(used), loading_frames=int(used.size))

    def measure_frames(self, segment: Segment | None = None) -> None:
        """Compute the depth and features of every frame since contact not measured yet, ahead
        of the estimate that will need them (e.g. when the force shows the contact only after
        the frames came)."""
        self._measure(self.segment() if segment is None else segment)

    def last_loading_frame_s(self, segment: Segment) -> float:
        """Capture time of the last loading frame of ``segment``; without one, of the newest
        frame received (of the newest force sample before any frame)."""
        return self._newest_data_s(segment.frame_t_s)

    def _newest_data_s(self, loading_t_s: np.ndarray) -> float:
        frame_t = self._frame_times()
        if loading_t_s.size:
            return float(loading_t_s[-1])
        return float(frame_t.max()) if frame_t.size else self._force.last_t_s

    def sampled_grasp(self, *, n_frames: int, size_px: tuple[int, int] | None,
                      segment: Segment | None = None, window_m: tuple[float, float] | None = None) -> SampledGrasp:
        """The learned model's depth input, as :func:`~estimator.inference.sampling.sample_grasp`
        measures it on :meth:`to_record` (no shift, depth images of the estimator's finger, no
        colour or marker images), from the cached depths.

        Parameters
        ----------
        n_frames : int
            Frames sampled over the loading phase.
        size_px : (int, int) or None
            (rows, cols) the depth maps are reduced to; None keeps the depth grid.
        segment : Segment, optional
            The segmentation of what has arrived (computed when not given).
        window_m : (float, float) or None
            The model's input window (m), centred on the pad (``sample_grasp``'s); None: the whole grid.
        """
        segment = self.segment() if segment is None else segment
        why = segment.reason or segment.frame_reason
        if why:
            return SampledGrasp(reason=why)
        positions = sample_positions(segment, n_frames, 0)
        distinct, rows = np.unique(positions, return_inverse=True)
        frame_t = self._frame_times()
        reference_index = reference_indices(frame_t, segment.t_onset_s - REFERENCE_GUARD_S)
        keep = np.concatenate([reference_index, segment.frame_index[distinct], segment.hold_index])
        # measure_grasp on the grasp restricted to those frames, as sample_grasp runs it (the same
        # loading phase: only the frames differ).
        restricted = align_frames(self._load_phase(), frame_t[keep], n_frames=n_frames)
        m = self._measure(restricted, positions=keep)
        if m.features is None:
            return SampledGrasp(reason=m.tactile_reason or "tactile features were not measured")
        if m.t_s.size != distinct.size:
            return SampledGrasp(reason=f"{m.t_s.size} of the {distinct.size} sampled frames are usable")
        estimates = tuple(estimate_grasp(m, method, settings=self.settings) for method in ANALYTICAL_METHODS)
        # reduce_images of the loading frames' depths, image by image, each frame reduced once per size.
        reduced = np.stack([self._reduced_depth(int(i), size_px, window_m) for i in keep[restricted.frame_index]])
        return SampledGrasp(measurements=m, estimates=estimates, force_n=m.force_n[rows], width_m=m.width_m[rows],
                            depth_m=reduced[rows])

    def reduce_depths(self, size_px: tuple[int, int] | None, window_m: tuple[float, float] | None = None) -> None:
        """Reduce every depth computed so far to ``size_px`` now, as :meth:`sampled_grasp` will
        (between frames, so the final estimate reduces only the frames that came since)."""
        for position in self._depth:
            self._reduced_depth(position, size_px, window_m)

    def _reduced_depth(self, position: int, size_px: tuple[int, int] | None,
                       window_m: tuple[float, float] | None = None) -> np.ndarray:
        key = (position, size_px, window_m)
        if key not in self._reduced:
            self._reduced[key] = reduce_images(self._depth[position][None], size_px, pitch_m=self.grid.pixel_pitch_m,
                                               window_m=window_m)[0]
        return self._reduced[key]

    def _measure(self, segment: Segment, *, positions: np.ndarray | None = None) -> GraspMeasurements:
        """:class:`GraspMeasurements` of the loading (and hold) frames so far, as ``measure_grasp``
        builds them.

        ``positions`` maps the segment's frames to the frames received (None: they are the
        frames received). The depth maps stay in the cache (the model reads them reduced).
        """
        stiffness = self.settings.gripper.finger_stiffness_n_per_m
        frame_t = self._frame_times()
        positions = np.arange(frame_t.size) if positions is None else positions

        def approach(width_m: np.ndarray, force_n: np.ndarray) -> np.ndarray:
            return analytical.approach_per_finger(width_m, force_n, onset_width_m=segment.onset_width_m,
                                                  finger_stiffness_n_per_m=stiffness)

        measurements = GraspMeasurements(
            finger=self.finger, sensor=self.sensor, depth_binning=self.binning, segment=segment,
            finger_stiffness_n_per_m=stiffness,
            object_poisson=self.settings.sensing.object_poisson, t_s=segment.frame_t_s,
            force_n=segment.frame_force_n, width_m=segment.frame_width_m,
            approach_m=approach(segment.frame_width_m, segment.frame_force_n),
            hold_force_n=segment.hold_force_n, hold_approach_m=approach(segment.hold_width_m, segment.hold_force_n),
        )
        why = segment.reason or segment.frame_reason
        if not segment.reason:
            reference_index = reference_indices(frame_t[positions], segment.t_onset_s - REFERENCE_GUARD_S)
            if reference_index.size == 0:
                why = why or (f"no tactile frame before the contact onset at {segment.t_onset_s:.3f} s to "
                              "serve as the no-contact reference")
            else:
                self._use_reference(positions[reference_index])
                # Every frame from contact on, whether or not widths around it have come: each frame's
                # depth is computed when it arrives, not in a burst when the next width comes.
                for position in positions[frame_t[positions] >= segment.t_contact_s]:
                    self._frame_features(int(position))
        if why:
            return dataclasses.replace(measurements, tactile_reason=why)
        loading_positions = positions[segment.frame_index]
        loading = self._stacked_features(loading_positions)
        hold = (self._stacked_features(positions[segment.hold_index]) if segment.hold_index.size
                else loading.take(slice(0, 0)))
        return dataclasses.replace(measurements, features=loading, hold_features=hold,
                                   calibration_smoothing_px=self.calibration_smoothing_px)

    def _stacked_features(self, positions: np.ndarray) -> ContactFeatures:
        features = [self._frame_features(int(i)) for i in positions]
        return ContactFeatures(**{f.name: np.concatenate([getattr(x, f.name) for x in features])
                                  for f in dataclasses.fields(ContactFeatures)})

    def _use_reference(self, index: np.ndarray) -> None:
        key = tuple(int(i) for i in index)
        if key != self._reference_key:
            self._reference = median_frame(np.stack([self._images[i] for i in key]))
            self._reference_key = key
            self._features.clear()
            self._depth.clear()
            self._reduced.clear()

    def _frame_features(self, position: int) -> ContactFeatures:
        cached = self._features.get(position)
        if cached is None:
            depth, cached = measure_frame(self._images[position], self._reference, self.calibration, self.grid)
            self._features[position] = cached
            self._depth[position] = depth
        return cached

    # ------------------------------------------------------------------ export

    def to_record(self) -> GraspRecord:
        """What has arrived as a grasp record (source ``hardware``: data as the bus delivered it)."""
        fingers = {s.finger for s in self.settings.sensors}
        streams = tuple(
            FrameStream(finger, np.asarray(f.t_s), tuple(f.encoded), f.encoding or "jpeg")
            for finger, f in self._frames.items() if finger in fingers
        )
        return GraspRecord(
            sensors=self.settings.sensors, frames=streams, force_n=self._force.samples(),
            width_m=self._width.samples(), provenance=Provenance(source="hardware", extra={"grasp_id": self.grasp_id},
                                                           style="operator" if self._follow else "script"),
            events={} if self._loading_end_s is None else {GRASP_DONE_EVENT: self._loading_end_s},
        )
