"""What the learned model reads: one grasp's sampled frames, measured and encoded as arrays.

Torch-free: the dataset builder (training) and the run-time estimator both use
this module, so a model sees at run time exactly what it was trained on.

Sampling
--------
A grasp's loading frames (contact to peak force, and the peak frame just after it, which
shows the peak state: :func:`~estimator.segment.segment_grasp`) are sampled at
``n_frames`` frames equidistant in time, exactly as the live
estimator samples it (``Segment.sample``). Augmentation ``shift = k`` starts the
sampling ``k`` loading frames later (the paper's "shifting the starting point by
one timestep"). Only those frames (with the no-contact frames before the onset,
for the reference, and the few hold frames at the peak force when the fits use
them) are decoded and measured (:func:`~estimator.measure.measure_tactile` with
``frames``), so depth is reconstructed for ``n_frames`` frames and the
analytical fits run over the frames the network sees.

Model inputs (float32, batch first)
-----------------------------------
``frames`` (B, N, C, h, w)
    Per sampled frame: gel depth in mm (``depth``) or the BGR difference to the
    no-contact frame in 8-bit levels / 64 (``rgb``); with ``markers`` the other
    finger's channels follow. Images are resampled from the depth grid (the sensor's
    image grid binned by ``estimator.depth_binning``; the marker finger's full grid) onto
    the model's input window (below) at ``size_px``, explicitly, once.
``force_width`` (B, 2N + 2), only with ``fw``
    Force at each frame on the reference gel (below) / 30 N, then gripper width / 0.08 m,
    then the rig: log2 of the gel's thickness over 3 mm and log10 of the finger stiffness
    over 200 kN/m (the record's settings; 0 where unknown): the network learns what the
    gel scale cannot carry (:func:`rig_features`).
``analytical`` (B, 6 x 4), only with ``analytical``
    Per method of :data:`ANALYTICAL_METHODS`: normalised log10 E on the reference gel
    (the bound's value for a bound, 0 for a refusal), interval width in decades / 9 (1
    for an open interval or a refusal) and the state one-hot (ok, lower_bound,
    upper_bound, insufficient_data).

Gel scale
---------
Linear elasticity has no modulus scale of its own: an object of modulus E pressed into a
gel of modulus E_gel by a force F takes the same shape as one of k E pressed into a gel of
k E_gel by k F (same Poisson ratios, same gel thickness). The model therefore works on the
reference gel, :data:`REFERENCE_GEL_MODULUS_PA` (the simulated Wedge's): a grasp measured
by a gel of modulus E_gel (its sensor's settings) has its forces and analytical moduli
multiplied by ``k = REFERENCE_GEL_MODULUS_PA / E_gel`` (:func:`gel_scale`), the network's
distribution is over k E, and the estimate is divided by k (training labels are
multiplied by it). The depth maps need no scaling. What the scale does not cover, a gel
of another thickness and the fingers' own compliance in the widths, the ``fw`` input's
rig features give the network.

Input window
------------
A model reads a fixed patch of gel, ``window_m`` = (height, width) in metres, at
``size_px`` = (rows, cols): its input pitch is ``window_m / size_px`` per axis, whatever
sensor measured the grasp (:attr:`Variant.window_m`; ``variant.window_m`` in the model's
``metadata.json``). The window is centred on the pad's centre: the depth grid is cut to the
window's extent in whole grid pixels (the extent rounded to the nearest pixel, the odd pixel
left over at the end), or, where the pad is smaller than the window, surrounded by zeros
(untouched gel: the model has no mask channel), and the result is area-averaged to
``size_px`` (``cv2.INTER_AREA``; :func:`~estimator.learned.window.window_images`, :func:`reduce_images`). The shipped
models' window is the simulated Wedge's pad (:func:`default_window_m`), so on that sensor
the window is the whole grid and the inputs are the grid area-averaged to ``size_px``, as
they always were. :func:`~estimator.learned.window.input_range` says whether a grasp's grid is within what a model was
trained on: a grid much coarser than the input pitch is refused, a pad covering little of
the window or a contact cut off by the edge of a pad smaller than the window widens the
interval.

Output scale
------------
log10 E in [3, 12] (:data:`LOG10_E_RANGE`), from 1 kPa (softer than any foam)
to 1 TPa (stiffer than any metal; the published labels span 5 kPa to 250 GPa):
the network's distribution is over bins of that range
(:mod:`estimator.learned.distribution`), so every estimate is a finite,
positive modulus.
"""

from __future__ import annotations

import math
import re
from collections.abc import Sequence
from dataclasses import dataclass, replace
from functools import lru_cache
from pathlib import Path
from typing import Protocol

import cv2
import numpy as np

from estimator.analytical import METHODS
from estimator.errors import ModelError
from estimator.estimate import STATES, Estimate
from estimator.learned.window import InputRange, input_range, window_images
from estimator.measure import (
    GraspMeasurements,
    calibration_path,
    estimate_grasp,
    measure_grasp,
    measure_tactile,
    no_contact_reference,
)
from estimator.perception.calibration import Calibration, load_calibration
from estimator.segment import Segment
from teleop.record import FrameStream, GraspRecord
from teleop.settings import SensorSettings, Settings

__all__ = [
    "ANALYTICAL_METHODS",
    "FEATURES_PER_METHOD",
    "LOG10_E_RANGE",
    "REFERENCE_FINGER_STIFFNESS_N_PER_M",
    "REFERENCE_GEL_MODULUS_PA",
    "REFERENCE_GEL_THICKNESS_M",
    "RIG_FEATURES",
    "MEASUREMENT_VERSION",
    "DecodedFrameStream",
    "SampledGrasp",
    "Variant",
    "analytical_features",
    "cached_calibration",
    "calibration_for",
    "decoded",
    "default_window_m",
    "distinct_frames",
    "encode",
    "gel_scale",
    "rig_features",
    "no_contact_reference",
    "reduce_images",
    "sample_grasp",
    "sample_positions",
    "sampled_input_range",
]

LOG10_E_RANGE = (3.0, 12.0)
#: The gel the model's forces and moduli refer to (Pa): the simulated Wedge's (module notes, "Gel scale").
REFERENCE_GEL_MODULUS_PA = 275e3
#: The rig features' reference gel thickness (m) and finger stiffness (N/m): the shipped settings'.
REFERENCE_GEL_THICKNESS_M = 3e-3
REFERENCE_FINGER_STIFFNESS_N_PER_M = 2e5
RIG_FEATURES = 2
ANALYTICAL_METHODS = METHODS
FEATURES_PER_METHOD = 2 + len(STATES)
FORCE_SCALE_N = 30.0
WIDTH_SCALE_M = 0.08
DEPTH_SCALE_M = 1e-3
RGB_SCALE = 64.0
IMAGES = ("depth", "rgb")
_VARIANT = re.compile(r"^(depth|rgb)((?:\+(?:markers|fw|analytical))*)$")
#: A window side outside this range (m) is not a gel pad.
WINDOW_RANGE_M = (1e-3, 0.2)

def default_window_m() -> tuple[float, float]:
    """(height, width) in m of the pad of the sensor the shipped models were trained on: the
    simulated GelSight Wedge of :class:`~teleop.settings.SensorSettings`'s defaults (250 x 350 px at
    1/11 mm, 22.73 x 31.82 mm). The window of a model whose metadata records none."""
    return SensorSettings().pad_size_m


# --------------------------------------------------------------------------- variant


@dataclass(frozen=True)
class Variant:
    """Which inputs a model reads, at which resolution and frame count.

    Attributes
    ----------
    image : {"depth", "rgb"}
        Depth maps or colour-difference images.
    markers : bool
        Also the other finger's (marker) images, as extra channels.
    force_width : bool
        Force and width at each frame (the ``fw`` input).
    analytical : bool
        The analytical estimates (a hybrid model); False is the CNN alone.
    n_frames : int
        Frames sampled over the loading phase.
    size_px : (int, int)
        (rows, cols) the images are reduced to.
    window_m : (float, float) or None
        (height, width) in m of the gel patch the images show (module notes); None: the whole
        depth grid of whatever sensor measured the grasp (no fixed pitch).
    """

    image: str = "depth"
    markers: bool = False
    force_width: bool = True
    analytical: bool = True
    n_frames: int = 3
    size_px: tuple[int, int] = (64, 88)
    window_m: tuple[float, float] | None = None

    def __post_init__(self) -> None:
        if self.image not in IMAGES:
            raise ModelError(f"variant image {self.image!r}: expected one of {', '.join(IMAGES)}")
        if not 1 <= int(self.n_frames) <= 64:
            raise ModelError(f"variant n_frames {self.n_frames!r}: expected 1..64")
        rows, cols = (int(v) for v in self.size_px)
        if not (8 <= rows <= 250 and 8 <= cols <= 350):
            raise ModelError(f"variant size_px {self.size_px!r}: expected rows 8..250 and cols 8..350")
        object.__setattr__(self, "n_frames", int(self.n_frames))
        object.__setattr__(self, "size_px", (rows, cols))
        if self.window_m is not None:
            lo, hi = WINDOW_RANGE_M
            try:
                window = tuple(float(v) for v in self.window_m)
            except (TypeError, ValueError):
                window = ()
            if len(window) != 2 or not all(math.isfinite(v) and lo <= v <= hi for v in window):
                raise ModelError(f"variant window_m {self.window_m!r}: expected (height, width) in m, each "
                                 f"{lo:g}..{hi:g}")
            object.__setattr__(self, "window_m", window)

    @property
    def input_pitch_m(self) -> tuple[float, float] | None:
        """(row, column) pitch of the image inputs on the gel (m): ``window_m / size_px``; None without a window."""
        if self.window_m is None:
            return None
        return (self.window_m[0] / self.size_px[0], self.window_m[1] / self.size_px[1])

    @classmethod
    def parse(cls, text: str, *, n_frames: int = 3, size_px: tuple[int, int] = (64, 88),
              window_m: tuple[float, float] | None = None) -> Variant:
        """``IMAGE[+markers][+fw][+analytical]``, e.g. ``depth+fw+analytical`` or ``rgb+markers``."""
        match = _VARIANT.match(text.strip())
        if not match:
            raise ModelError(
                f"variant {text!r}: expected depth or rgb followed by any of +markers, +fw, "
                "+analytical (e.g. depth+fw+analytical)"
            )
        flags = set(filter(None, match.group(2).split("+")))
        return cls(image=match.group(1), markers="markers" in flags, force_width="fw" in flags,
                   analytical="analytical" in flags, n_frames=n_frames, size_px=size_px, window_m=window_m)

    @property
    def name(self) -> str:
        """The variant as :meth:`parse` reads it."""
        flags = [f for f, on in (("markers", self.markers), ("fw", self.force_width),
                                  ("analytical", self.analytical)) if on]
        return "+".join([self.image, *flags])

    @property
    def method(self) -> str:
        """Estimate method name: ``hybrid`` with analytical inputs, ``cnn`` without."""
        return "hybrid" if self.analytical else "cnn"

    @property
    def channels(self) -> int:
        """Image channels per frame."""
        per_finger = 1 if self.image == "depth" else 3
        return per_finger * (2 if self.markers else 1)

    @property
    def input_shapes(self) -> dict[str, tuple[int, ...]]:
        """Model input name -> shape without the batch axis, in call order."""
        shapes: dict[str, tuple[int, ...]] = {"frames": (self.n_frames, self.channels, *self.size_px)}
        if self.force_width:
            shapes["force_width"] = (2 * self.n_frames + RIG_FEATURES,)
        if self.analytical:
            shapes["analytical"] = (FEATURES_PER_METHOD * len(ANALYTICAL_METHODS),)
        return shapes


def gel_scale(gel_modulus_pa: float | None) -> float:
    """``k``, the factor that takes a grasp's forces and moduli onto the reference gel (module notes,
    "Gel scale"); 1 where the gel's modulus is unknown (samples from before it was recorded)."""
    return 1.0 if gel_modulus_pa is None else REFERENCE_GEL_MODULUS_PA / gel_modulus_pa


def rig_features(gel_thickness_m: float | None, finger_stiffness_n_per_m: float | None) -> np.ndarray:
    """The rig part of the ``force_width`` input (module notes), float32 (2,); 0 for an unknown value."""
    thickness = 0.0 if gel_thickness_m is None else math.log2(gel_thickness_m / REFERENCE_GEL_THICKNESS_M)
    stiffness = (0.0 if finger_stiffness_n_per_m is None
                 else math.log10(finger_stiffness_n_per_m / REFERENCE_FINGER_STIFFNESS_N_PER_M))
    return np.array([thickness, stiffness], dtype=np.float32)


def analytical_features(estimates: Sequence[Estimate], *, scale: float = 1.0) -> np.ndarray:
    """The ``analytical`` input of one grasp (see the module notes), float32; ``scale`` is the
    grasp's :func:`gel_scale`.

    A method missing from ``estimates`` is encoded as a refusal.
    """
    by_method = {e.method: e for e in estimates}
    out = np.zeros((len(ANALYTICAL_METHODS), FEATURES_PER_METHOD), dtype=np.float32)
    lo, hi = LOG10_E_RANGE
    for row, method in zip(out, ANALYTICAL_METHODS, strict=True):
        est = by_method.get(method)
        state = est.state if est is not None else "insufficient_data"
        row[2 + STATES.index(state)] = 1.0
        row[1] = 1.0
        if est is None or est.e_pa is None:
            continue
        row[0] = np.clip((math.log10(est.e_pa * scale) - lo) / (hi - lo), -0.5, 1.5)
        low, high = est.interval_pa
        if low is not None and high is not None:
            row[1] = min(math.log10(high / low) / (hi - lo), 1.0)
    return out.ravel()


def distinct_frames(force_n: np.ndarray) -> int:
    """How many distinct frames a sample set holds, from the force at each sampled frame.

    A short loading phase repeats frames (:func:`sample_positions`); a repeated frame repeats
    its force exactly, while distinct frames are interpolated at distinct times.
    """
    return int(np.unique(np.asarray(force_n)).size)


def reduce_images(images: np.ndarray, size_px: tuple[int, int] | None, *, pitch_m: float | None = None,
                  window_m: tuple[float, float] | None = None) -> np.ndarray:
    """Area-average each image of a stack to ``size_px`` (rows, cols), float32.

    ``images`` is (n, H, W) or (n, H, W, 3); one ``cv2.resize`` per image. With ``window_m``
    (height, width; m) the images (at ``pitch_m``) are first cut or padded to that window
    (:func:`~estimator.learned.window.window_images`); without it they are reduced whole. ``size_px`` None keeps the size
    (and ignores the window).
    """
    if size_px is None:
        return images.astype(np.float32, copy=False)
    if window_m is not None:
        if pitch_m is None:
            raise ModelError("reduce_images: a window needs the images' pixel pitch")
        images = window_images(images, pitch_m, window_m)
    rows, cols = size_px
    out = np.empty((images.shape[0], rows, cols, *images.shape[3:]), dtype=np.float32)
    for i, image in enumerate(images):
        out[i] = cv2.resize(image.astype(np.float32, copy=False), (cols, rows), interpolation=cv2.INTER_AREA)
    return out


class ModelInputs(Protocol):
    """What :func:`encode` reads (a :class:`SampledGrasp` or a TrainingSample)."""

    depth_m: np.ndarray
    rgb_diff: np.ndarray | None
    depth_markers_m: np.ndarray | None
    rgb_diff_markers: np.ndarray | None
    force_n: np.ndarray
    width_m: np.ndarray
    estimates: tuple[Estimate, ...]
    gel_modulus_pa: float | None
    gel_thickness_m: float | None
    finger_stiffness_n_per_m: float | None


def _images(item: ModelInputs, variant: Variant, where: str) -> np.ndarray:
    """(N, C, h, w) image input of one item."""
    names = ("depth_m", "depth_markers_m") if variant.image == "depth" else ("rgb_diff", "rgb_diff_markers")
    names = names if variant.markers else names[:1]
    parts = []
    for name in names:
        image = getattr(item, name)
        if image is None:
            raise ModelError(f"{where}: variant {variant.name} needs {name}, which is missing")
        if image.shape[:3] != (variant.n_frames, *variant.size_px):
            raise ModelError(f"{where}: {name} has shape {image.shape}; variant {variant.name} expects "
                             f"{variant.n_frames} frames of {variant.size_px[0]} x {variant.size_px[1]} px")
        if variant.image == "depth":
            parts.append(image[:, None] / DEPTH_SCALE_M)
        else:
            parts.append(np.moveaxis(image, -1, 1) / RGB_SCALE)
    return np.concatenate(parts, axis=1)


def encode(variant: Variant, items: Sequence[ModelInputs], *, where: str = "model input"
           ) -> dict[str, np.ndarray]:
    """Batch the model inputs of ``items`` (module notes), float32, keyed by input name.

    Raises
    ------
    ModelError
        An item lacks what the variant reads, or its images are not of the
        variant's frame count and size.
    """
    if not items:
        raise ModelError(f"{where}: nothing to encode")
    batch = {"frames": np.stack([_images(item, variant, where) for item in items]).astype(np.float32)}
    scales = [gel_scale(item.gel_modulus_pa) for item in items]
    if variant.force_width:
        batch["force_width"] = np.stack([
            np.concatenate([item.force_n * k / FORCE_SCALE_N, item.width_m / WIDTH_SCALE_M,
                            rig_features(item.gel_thickness_m, item.finger_stiffness_n_per_m)])
            for item, k in zip(items, scales, strict=True)
        ]).astype(np.float32)
    if variant.analytical:
        batch["analytical"] = np.stack([analytical_features(item.estimates, scale=k)
                                        for item, k in zip(items, scales, strict=True)])
    return batch


# --------------------------------------------------------------------------- sampling


#: Version of the measurement that turns a record into model inputs (segmentation, depth, contact
#: features, analytical fits, sampling). Raise it with any change that alters the inputs; a model
#: records the version its data was measured with (``data.measurement_version``), and
#: :mod:`estimator.learned.reference` checks that its recorded inputs on a fixed reference record
#: still come out the same, so a change that alters them without a raised version fails a test.
MEASUREMENT_VERSION = 4


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

    The loading frame nearest to each of ``n_frames`` times spread evenly from the
    contact (``shift = 0``, the live sampling) or from loading frame ``shift`` to the
    last loading frame (the peak frame when there is one). A short loading phase (a
    stiff object loads within a frame or two) repeats frames; a shifted set must have
    ``n_frames`` distinct frames.
    """
    t = segment.frame_t_s
    if shift == 0:
        start = segment.t_contact_s
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
        Young's modulus (Pa) and thickness (m) of the measuring finger's gel (the record's
        sensor settings).
    finger_stiffness_n_per_m : float or None
        The fingers' bending stiffness the fits used (the record's gripper, else the settings').
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


def calibration_for(record: GraspRecord, finger: str, calibration: Calibration | str | Path | None) -> Calibration:
    """``calibration`` when loaded; else the file it (or ``finger``'s sensor) names, loaded once per process."""
    if isinstance(calibration, Calibration):
        return calibration
    return cached_calibration(str(calibration_path(record.sensor(finger), calibration)))


def _marker_finger(record: GraspRecord, finger: str) -> str | None:
    return next((s.finger for s in record.sensors if s.finger != finger and s.markers), None)


def _measure_finger(
    record: GraspRecord, finger: str, *, settings: Settings, calibration: Calibration, n_frames: int,
    shift: int, size_px: tuple[int, int] | None, rgb: bool, window_m: tuple[float, float] | None,
) -> SampledGrasp:
    """Measure the sample set ``shift`` of one finger (no estimates, no markers)."""
    # A marker finger's dots are found on its full grid.
    binning = 1 if record.sensor(finger).markers else settings.estimator.depth_binning
    settings = replace(settings, estimator=replace(settings.estimator, finger=finger, n_frames=n_frames,
                                                   depth_binning=binning))
    first = measure_grasp(record, settings=settings, tactile=False)
    segment = first.segment
    why = segment.reason or segment.frame_reason
    if why:
        return SampledGrasp(reason=why)
    positions = sample_positions(segment, n_frames, shift)
    if isinstance(positions, str):
        return SampledGrasp(reason=positions)
    distinct, rows = np.unique(positions, return_inverse=True)
    m = measure_tactile(record, first, calibration=calibration, frames=distinct)
    if m.features is None or m.depth_m is None:
        return SampledGrasp(reason=m.tactile_reason or "tactile features were not measured")
    window = dict(pitch_m=m.grid.pixel_pitch_m, window_m=window_m)
    depth = reduce_images(m.depth_m, size_px, **window)[rows]
    diff = None
    if rgb:
        diff = reduce_images(m.image_bgr.astype(np.float32) - m.reference_bgr.astype(np.float32), size_px,
                             **window)[rows]
    return SampledGrasp(measurements=m, force_n=m.force_n[rows], width_m=m.width_m[rows], depth_m=depth,
                        rgb_diff=diff)


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
    """Measure one sample set of a grasp: depth, force, width and analytical estimates.

    Parameters
    ----------
    record : GraspRecord
    settings : Settings
        ``estimator.finger`` is the finger read; the rest as for :func:`measure_grasp`.
    calibration : Calibration, path or None
        That finger's colour-to-gradient calibration (None: the file its sensor names);
        files are loaded once per process (:func:`cached_calibration`).
    n_frames : int
        Frames sampled over the loading phase.
    size_px : (int, int) or None
        (rows, cols) the images are reduced to; None keeps the depth grid.
    shift : int
        Augmentation: start the sampling this many loading frames late (0 = live sampling).
    rgb : bool
        Also the colour-difference images (of the frames measured for depth, against their reference).
    markers : bool
        Also the other finger's images (the sensor with markers); needs its calibration.
    marker_calibration : Calibration, path or None
        The marker finger's calibration (None: the file its sensor names).
    window_m : (float, float) or None
        (height, width) in m of the gel patch the images show, centred on the pad (module
        notes: cut from a larger pad, zero-padded around a smaller one); None: the whole depth
        grid.

    Returns
    -------
    SampledGrasp
        Falsy with a reason when the grasp has no usable loading phase, too few
        loading frames for ``n_frames`` (after ``shift``) or unusable frames.
    """
    if shift < 0 or n_frames < 1:
        raise ModelError(f"shift {shift} and n_frames {n_frames}: expected shift >= 0 and n_frames >= 1")
    finger = settings.estimator.finger
    cal = calibration_for(record, finger, calibration)
    common = dict(settings=settings, n_frames=n_frames, shift=shift, size_px=size_px, rgb=rgb, window_m=window_m)
    sampled = _measure_finger(record, finger, calibration=cal, **common)
    if not sampled:
        return sampled
    if markers:
        other = _marker_finger(record, finger)
        if other is None:
            return SampledGrasp(reason=f"no finger with markers besides {finger!r} in the record")
        other_cal = calibration_for(record, other, marker_calibration)
        marker = _measure_finger(record, other, calibration=other_cal, **common)
        if not marker:
            return SampledGrasp(reason=f"marker finger {other!r}: {marker.reason}")
        sampled = replace(sampled, depth_markers_m=marker.depth_m, rgb_diff_markers=marker.rgb_diff)
    estimates = tuple(estimate_grasp(sampled.measurements, method, settings=settings)
                      for method in ANALYTICAL_METHODS)
    gel = record.sensor(finger)
    return replace(sampled, estimates=estimates, gel_modulus_pa=gel.gel_modulus_pa, gel_thickness_m=gel.gel_thickness_m,
                   finger_stiffness_n_per_m=sampled.measurements.finger_stiffness_n_per_m)


def sampled_input_range(sampled: SampledGrasp, variant: Variant) -> InputRange:
    """:func:`~estimator.learned.window.input_range` of a sampled grasp's depth grid (the estimator's finger) for a model of
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
