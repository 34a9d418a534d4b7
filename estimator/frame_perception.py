"""What a grasp's frames of the estimator's finger give, each computed once: the per-frame cache of a
:class:`~estimator.stream.GraspStream`.

:class:`FramePerception` keeps each frame decoded and warped onto the depth grid
(:func:`~estimator.perception.grid.frame_on_grid`), the no-contact reference (the median of the last
frames before the onset: :func:`~estimator.measurements.reference_indices`), each frame's depth and
contact features against it (:func:`~estimator.measurements.measure_frame`; dropped when the
reference moves) and its depth reduced to a learned model's input
(:func:`~estimator.inference.inputs.reduce_images`, once per size and window). The frames themselves
(:class:`~estimator.received.Frames`) stay the stream's: they are passed in where one is decoded.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from estimator.errors import PerceptionError
from estimator.faults import camera_fault
from estimator.features import ContactFeatures
from estimator.inference.inputs import reduce_images
from estimator.measurements import (
    REFERENCE_GUARD_S,
    GraspMeasurements,
    measure_frame,
    median_frame,
    reference_indices,
)
from estimator.perception.calibration import Calibration
from estimator.perception.grid import DepthGrid
from estimator.received import Frames
from estimator.segment import Segment
from teleop.errors import RecordError
from teleop.settings import SensorSettings

__all__ = ["FramePerception"]


class FramePerception:
    """The estimator finger's frames of one grasp on the depth grid, and their depth and features
    against the no-contact reference (see the module docstring).

    ``images`` (frame position -> frame on the depth grid) is filled by the stream live, as frames
    arrive, and here on first use otherwise (``undecodable``: a record's frames that do not decode ->
    why); ``reference`` is the no-contact reference in use;
    ``depth`` (frame position -> depth, m) holds the frames measured against it.
    """

    def __init__(self, *, finger: str, sensor: SensorSettings, binning: int, grid: DepthGrid, grasp_id: str):
        self.finger, self.sensor, self.binning, self.grid, self.grasp_id = finger, sensor, binning, grid, grasp_id
        self.images: dict[int, np.ndarray] = {}
        self.undecodable: dict[int, str] = {}  # a record's frames skipped -> why (decode)
        self.reference: np.ndarray | None = None
        self._reference_key: tuple[int, ...] | None = None
        self._features: dict[int, ContactFeatures] = {}  # frame position -> features of that frame
        self.depth: dict[int, np.ndarray] = {}
        self._reduced: dict[tuple, np.ndarray] = {}  # (position, size, window) -> reduced depth

    def image(self, frames: Frames, position: int) -> np.ndarray:
        """Frame ``position`` of ``frames`` (the estimator finger's) on the depth grid, decoded once."""
        image = self.images.get(position)
        if image is None:
            where = f"grasp {self.grasp_id!r} frame {position} of finger {self.finger!r}"
            image = self.images[position] = frames.on_grid(position, self.sensor, binning=self.binning, where=where)
        return image

    def drop_first(self) -> None:
        """Forget the first frame (the stream dropped it: :meth:`~estimator.received.Frames.make_room`): the
        others' positions move down by one, and the reference goes when it was among its frames."""
        self.images = {i - 1: image for i, image in self.images.items() if i}
        self.undecodable = {i - 1: why for i, why in self.undecodable.items() if i}
        if self._reference_key is not None and 0 in self._reference_key:
            self.reference, self._reference_key = None, None
            self._features.clear()
            self.depth.clear()
            self._reduced.clear()
        elif self._reference_key is not None:
            self._reference_key = tuple(i - 1 for i in self._reference_key)
        self._features = {i - 1: f for i, f in self._features.items() if i}
        self.depth = {i - 1: depth for i, depth in self.depth.items() if i}
        self._reduced = {(key[0] - 1, *key[1:]): depth for key, depth in self._reduced.items() if key[0]}

    def times(self, frames: Frames) -> np.ndarray:
        """Capture times of ``frames``, NaN for those that do not decode (the segmentation skips them)."""
        times = frames.times()
        times[list(self.undecodable)] = np.nan
        return times

    def decode(self, frames: Frames) -> bool:
        """Decode a record's ``frames`` not decoded yet: whether one that does not decode (or has the wrong
        size) was newly skipped (``undecodable``); the error when none decodes."""
        count = len(frames.t_s) if frames.source is not None else 0
        before = len(self.undecodable)
        for position in sorted(set(range(count)) - self.images.keys() - self.undecodable.keys()):
            try:
                self.image(frames, position)
            except (RecordError, PerceptionError) as exc:
                self.undecodable[position] = str(exc)
                if len(self.undecodable) == count:
                    raise  # not one frame decodes: the record's stream is broken, not a frame of it
        return len(self.undecodable) > before

    def reference_index(self, frame_t: np.ndarray, segment: Segment) -> np.ndarray:
        """The frames the no-contact reference is the median of: the last ones before the onset."""
        return reference_indices(frame_t, segment.t_onset_s - REFERENCE_GUARD_S)

    def reference_reason(self, frame_t: np.ndarray, segment: Segment) -> str:
        """Why no frame (capture times ``frame_t``) can serve as the no-contact reference; empty when one can."""
        return "" if self.reference_index(frame_t, segment).size else (
            f"no tactile frame before the contact onset at {segment.t_onset_s:.3f} s to serve as the no-contact reference")

    def use_reference(self, frames: Frames, frame_t: np.ndarray, segment: Segment) -> None:
        """Measure against the reference of ``segment``: when it moved, the frames measured are dropped."""
        key = tuple(int(i) for i in self.reference_index(frame_t, segment))
        if key != self._reference_key:
            self.reference = median_frame(np.stack([self.image(frames, i) for i in key]))
            self._reference_key = key
            self._features.clear()
            self.depth.clear()
            self._reduced.clear()

    def features(self, frames: Frames, position: int, calibration: Calibration) -> ContactFeatures:
        """Contact features of frame ``position`` against the reference in use (its depth kept), computed once."""
        cached = self._features.get(position)
        if cached is None:
            depth, cached = measure_frame(self.image(frames, position), self.reference, calibration, self.grid)
            self._features[position] = cached
            self.depth[position] = depth
        return cached

    def measured(self, m: GraspMeasurements, frames: Frames, frame_t: np.ndarray, segment: Segment,
                 loading_index: np.ndarray, hold_index: np.ndarray, calibration: Calibration, *,
                 calibration_smoothing_px: float | None) -> GraspMeasurements:
        """``m`` with the depth and contact features of its loading frames (``loading_index``) and of the hold
        frames at ``hold_index``, against the reference of ``segment``; with ``tactile_reason`` on a camera fault."""
        self.use_reference(frames, frame_t, segment)
        loading = [int(i) for i in loading_index]
        images = [self.image(frames, i) for i in loading]
        if why := camera_fault(self.reference, images, m.t_s, self.finger):
            return dataclasses.replace(m, tactile_reason=why)
        features = ContactFeatures.concatenate([self.features(frames, i, calibration) for i in loading])
        hold = [self.features(frames, int(i), calibration) for i in hold_index]
        return dataclasses.replace(
            m, features=features, depth_m=np.stack([self.depth[i] for i in loading]),
            hold_features=ContactFeatures.concatenate(hold) if hold else None,
            image_bgr=np.stack(images), reference_bgr=self.reference, calibration_smoothing_px=calibration_smoothing_px,
        )

    def reduce_depths(self, size_px: tuple[int, int] | None, window_m: tuple[float, float] | None = None) -> None:
        """Reduce every depth computed so far to ``size_px`` now, as :meth:`reduced_depths` will."""
        for position in self.depth:
            self._reduced_depth(position, size_px, window_m)

    def reduced_depths(self, positions: np.ndarray, size_px: tuple[int, int] | None,
                       window_m: tuple[float, float] | None = None) -> np.ndarray:
        """Depth of the frames at ``positions`` (measured) reduced to the model's input, float32 (n, rows, cols)."""
        return np.stack([self._reduced_depth(int(i), size_px, window_m) for i in positions])

    def _reduced_depth(self, position: int, size_px: tuple[int, int] | None,
                       window_m: tuple[float, float] | None = None) -> np.ndarray:
        key = (position, size_px, window_m)
        if key not in self._reduced:
            self._reduced[key] = reduce_images(self.depth[position][None], size_px, pitch_m=self.grid.pixel_pitch_m,
                                               window_m=window_m)[0]
        return self._reduced[key]
