"""One grasp's sampled frames, measured as the learned model reads them.

Sampling
--------
A grasp's loading frames (contact to peak force, and the peak frame just after it, which
shows the peak state: :func:`~estimator.segment.segment_grasp`) are sampled at
``n_frames`` frames equidistant in time (along an operator's loading envelope: in approach,
:mod:`estimator.segment`), exactly as the live
estimator samples it (``Segment.sample``). Augmentation ``shift = k`` starts the
sampling ``k`` loading frames later (the paper's "shifting the starting point by
one timestep"). Only those frames (with the no-contact frames before the onset,
for the reference) are decoded and measured
(:meth:`~estimator.stream.GraspStream.measurements` with ``frames``), so depth is reconstructed
for ``n_frames`` frames and the analytical fits run over the frames the network sees.

One path: :func:`sample_stream` samples a :class:`~estimator.stream.GraspStream`, live (the
estimator service's stream, from the depths it cached for the provisional estimates) and offline
(:func:`sample_grasp`: a record fed through a stream), so the model reads the same floats both ways.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from functools import lru_cache
from pathlib import Path

import numpy as np

from estimator.errors import ModelError
from estimator.estimate import Estimate
from estimator.inference.inputs import ANALYTICAL_METHODS, Variant, reduce_images
from estimator.inference.window import InputRange, input_range
from estimator.measure import finger_sensor
from estimator.measurements import GraspMeasurements, calibration_path, estimate_measurements
from estimator.perception.calibration import Calibration, load_calibration
from estimator.segment import Segment, sampling_axis
from estimator.settings import estimator_settings
from estimator.stream import GraspStream
from teleop.record import FrameStream, GraspRecord
from teleop.settings import SensorSettings, Settings

__all__ = [
    "DecodedFrameStream",
    "SampledGrasp",
    "cached_calibration",
    "calibration_for",
    "decoded",
    "record_stream",
    "sample_grasp",
    "sample_positions",
    "sample_stream",
    "sampled_input_range",
]


class DecodedFrameStream(FrameStream):
    """A frame stream that also holds its frames decoded ``reduce`` times smaller (``frame(i, reduce=reduce)``
    is a lookup; other reductions decode).

    Used to time the estimator from decoded frames, as a live camera delivers them.
    """

    def __init__(self, stream: FrameStream, images: np.ndarray, *, reduce: int = 1):
        super().__init__(stream.finger, stream.t_s, stream.encoded, stream.encoding,
                         stream.jpeg_quality, stream.shape)
        object.__setattr__(self, "images", images)
        object.__setattr__(self, "reduce", reduce)

    def frame(self, index: int, *, reduce: int = 1) -> np.ndarray:
        return self.images[index] if reduce == self.reduce else super().frame(index, reduce=reduce)


def decoded(record: GraspRecord, *, reduce: int = 1) -> GraspRecord:
    """``record`` with every frame stream decoded once, up front, ``reduce`` times smaller (as the
    estimator reads them with that depth binning)."""
    return replace(record, frames=tuple(DecodedFrameStream(s, s.frames(reduce=reduce), reduce=reduce)
                                        for s in record.frames))


def sample_positions(segment: Segment, n_frames: int, shift: int) -> np.ndarray | str:
    """Positions (within the loading frames) of the sample set ``shift``, or why there is none.

    The loading frame nearest to each of ``n_frames`` times (along a loading envelope, an
    operator's grasp: approaches, :func:`~estimator.segment.sampling_axis`) spread evenly from the
    contact (``shift = 0``, the live sampling) or from loading frame ``shift`` to the
    last loading frame (the peak frame when there is one). A short loading phase (a
    stiff object loads within a frame or two) repeats frames; a shifted set must have
    ``n_frames`` distinct frames.
    """
    t, contact = sampling_axis(segment)
    if shift == 0:
        start = contact
    elif t.size - shift < n_frames:
        return f"shift {shift} leaves {max(t.size - shift, 0)} of the {n_frames} loading frames it needs"
    else:
        start = float(t[shift])
    targets = np.linspace(start, float(t[-1]), n_frames)
    return np.abs(t[None, :] - targets[:, None]).argmin(axis=1)


@dataclass(frozen=True)
class SampledGrasp:
    """One grasp's ``n`` sampled frames, measured as the model reads them; falsy with a reason.

    Attributes
    ----------
    reason : str
        Why the grasp cannot be sampled (empty when it can).
    measurements : GraspMeasurements or None
        Measurements of the sampled frames (the analytical fits' input).
    estimates : tuple of Estimate
        Every analytical method over the sampled frames.
    force_n, width_m : ndarray, shape (n,)
        Force (N) and gripper width (m) at each sampled frame.
    depth_m : ndarray, float32, shape (n, h, w)
        Gel depth (m), reduced to ``size_px``.
    rgb_diff : ndarray, float32, shape (n, h, w, 3), or None
        Frame minus the no-contact frame (BGR, 8-bit levels), reduced; None unless asked.
    depth_markers_m, rgb_diff_markers : ndarray or None
        The same from the other (marker) finger, when asked.
    gel_modulus_pa, gel_thickness_m : float or None
        Young's modulus (Pa) and thickness (m) of the measuring finger's gel (the rig's sensor:
        the record's, or live the settings').
    finger_stiffness_n_per_m : float or None
        The fingers' bending stiffness the fits used (the rig's gripper).
    """

    reason: str = ""
    measurements: GraspMeasurements | None = None
    estimates: tuple[Estimate, ...] = ()
    force_n: np.ndarray | None = None
    width_m: np.ndarray | None = None
    depth_m: np.ndarray | None = None
    rgb_diff: np.ndarray | None = None
    depth_markers_m: np.ndarray | None = None
    rgb_diff_markers: np.ndarray | None = None
    gel_modulus_pa: float | None = None
    gel_thickness_m: float | None = None
    finger_stiffness_n_per_m: float | None = None

    def __bool__(self) -> bool:
        return not self.reason


@lru_cache(maxsize=8)
def cached_calibration(path: str) -> Calibration:
    """:func:`~estimator.perception.calibration.load_calibration`, once per path and process."""
    return load_calibration(path)


def calibration_for(sensor: SensorSettings, calibration: Calibration | str | Path | None) -> Calibration:
    """``calibration`` when loaded; else the file it (or ``sensor``) names, loaded once per process."""
    if isinstance(calibration, Calibration):
        return calibration
    return cached_calibration(str(calibration_path(sensor, calibration)))


def _sampled(stream: GraspStream, *, n_frames: int, shift: int, size_px: tuple[int, int] | None, rgb: bool,
             window_m: tuple[float, float] | None) -> SampledGrasp:
    """The sample set ``shift`` of ``stream``'s finger: its frames measured, every analytical method over them."""
    segment = stream.segment(n_frames=n_frames)
    why = segment.reason or segment.frame_reason
    if why:
        return SampledGrasp(reason=why)
    positions = sample_positions(segment, n_frames, shift)
    if isinstance(positions, str):
        return SampledGrasp(reason=positions)
    distinct, rows = np.unique(positions, return_inverse=True)
    m = stream.measurements(segment, frames=distinct)
    if m.features is None:
        return SampledGrasp(reason=m.tactile_reason or "tactile features were not measured")
    depth = stream.reduced_depths(segment.frame_index[distinct], size_px, window_m)[rows]
    diff = None
    if rgb:
        diff = reduce_images(m.image_bgr.astype(np.float32) - m.reference_bgr.astype(np.float32), size_px,
                             pitch_m=m.grid.pixel_pitch_m, window_m=window_m)[rows]
    return SampledGrasp(measurements=m, estimates=tuple(estimate_measurements(m, method) for method in ANALYTICAL_METHODS),
                        force_n=m.force_n[rows], width_m=m.width_m[rows], depth_m=depth, rgb_diff=diff,
                        gel_modulus_pa=m.sensor.gel_modulus_pa, gel_thickness_m=m.sensor.gel_thickness_m,
                        finger_stiffness_n_per_m=m.finger_stiffness_n_per_m)


def sample_stream(
    stream: GraspStream,
    *,
    n_frames: int,
    size_px: tuple[int, int] | None,
    shift: int = 0,
    rgb: bool = False,
    markers: bool = False,
    marker_calibration: Calibration | str | Path | None = None,
    window_m: tuple[float, float] | None = None,
) -> SampledGrasp:
    """Measure one sample set of what ``stream`` has received: depth, force, width and analytical estimates.

    Parameters
    ----------
    stream : GraspStream
        Its finger is read, on its rig, with its calibration; depths it has computed are not
        computed again.
    n_frames : int
        Frames sampled over the loading phase.
    size_px : (int, int) or None
        (rows, cols) the images are reduced to; None keeps the depth grid.
    shift : int
        Augmentation: start the sampling this many loading frames late (0 = live sampling).
    rgb : bool
        Also the colour-difference images (of the frames measured for depth, against their reference).
    markers : bool
        Also the other finger's images (the sensor with markers), measured on its full grid
        (:meth:`~estimator.stream.GraspStream.for_finger`).
    marker_calibration : Calibration, path or None
        The marker finger's calibration (None: the file its sensor names), loaded once per process.
    window_m : (float, float) or None
        (height, width) in m of the gel patch the images show, centred on the pad
        (:mod:`estimator.inference.inputs`, "Input window": cut from a larger pad, zero-padded
        around a smaller one); None: the whole depth grid.

    Returns
    -------
    SampledGrasp
        Falsy with a reason when the grasp has no usable loading phase, too few
        loading frames for ``n_frames`` (after ``shift``) or unusable frames.
    """
    if shift < 0 or n_frames < 1:
        raise ModelError(f"shift {shift} and n_frames {n_frames}: expected shift >= 0 and n_frames >= 1")
    common = dict(n_frames=n_frames, shift=shift, size_px=size_px, rgb=rgb, window_m=window_m)
    sampled = stream.skipping_bad_frames(lambda: _sampled(stream, **common))
    if not sampled or not markers:
        return sampled
    other = next((s for s in stream.sensors if s.finger != stream.finger and s.markers), None)
    if other is None:
        return SampledGrasp(reason=f"no finger with markers besides {stream.finger!r} in the record")
    marker_stream = stream.for_finger(other.finger, calibration=calibration_for(other, marker_calibration))
    marker = marker_stream.skipping_bad_frames(lambda: _sampled(marker_stream, **common))
    if not marker:
        return SampledGrasp(reason=f"marker finger {other.finger!r}: {marker.reason}")
    return replace(sampled, depth_markers_m=marker.depth_m, rgb_diff_markers=marker.rgb_diff)


def sample_grasp(
    record: GraspRecord,
    *,
    settings: Settings,
    calibration: Calibration | str | Path | None,
    n_frames: int,
    size_px: tuple[int, int] | None,
    shift: int = 0,
    rgb: bool = False,
    markers: bool = False,
    marker_calibration: Calibration | str | Path | None = None,
    window_m: tuple[float, float] | None = None,
) -> SampledGrasp:
    """Measure one sample set of a grasp record: :func:`sample_stream` of the record fed through a
    :class:`~estimator.stream.GraspStream` (:func:`record_stream`).

    Parameters
    ----------
    record : GraspRecord
    settings : Settings
        ``sensing.finger`` is the finger read; the rest as for :func:`~estimator.measure.measure_grasp`.
    calibration : Calibration, path or None
        That finger's colour-to-gradient calibration (None: the file its sensor names);
        files are loaded once per process (:func:`cached_calibration`).
    n_frames, size_px, shift, rgb, markers, marker_calibration, window_m
        See :func:`sample_stream`.

    Returns
    -------
    SampledGrasp
    """
    return sample_stream(record_stream(record, settings=settings, calibration=calibration), n_frames=n_frames,
                         size_px=size_px, shift=shift, rgb=rgb, markers=markers,
                         marker_calibration=marker_calibration, window_m=window_m)


def record_stream(record: GraspRecord, *, settings: Settings,
                  calibration: Calibration | str | Path | None) -> GraspStream:
    """``record`` fed through a :class:`~estimator.stream.GraspStream` for sampling: its finger's
    calibration loaded at once (once per process), on its full grid when the record's sensor has
    markers (their dots are found there only).

    Raises RecordError when ``record`` has no sensor or no frames on the settings' finger
    (:func:`~estimator.measure.finger_sensor`).
    """
    sensor = finger_sensor(record, settings.sensing.finger)
    cal = calibration_for(sensor, calibration)
    est = estimator_settings(settings)
    if sensor.markers and est.depth_binning != 1:
        settings = settings.with_section(replace(est, depth_binning=1))
    return GraspStream.from_record(record, settings=settings, calibration=cal)


def sampled_input_range(sampled: SampledGrasp, variant: Variant) -> InputRange:
    """:func:`~estimator.inference.window.input_range` of a sampled grasp's depth grid (the estimator's finger) for a model of
    ``variant``: the grid's pitch and shape, and whether the contact reaches its border in any
    sampled frame. In range (``InputRange()``) when the sample carries no measurements (its images
    were made at the model's size elsewhere) or the variant has no window."""
    m = sampled.measurements
    if m is None or variant.window_m is None:
        return InputRange()
    grid = m.grid
    shape = m.depth_m.shape[1:3] if m.depth_m is not None else grid.image_shape
    touches = m.features is not None and bool(np.any(m.features.touches_edge))
    return input_range(variant.window_m, variant.size_px, pitch_m=grid.pixel_pitch_m, grid_shape=shape,
                       touches_edge=touches)
