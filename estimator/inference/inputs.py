"""What the learned model reads: the variants, the input scales, and the encoding of sampled grasps.

Torch-free: the dataset builder (training) and the run-time estimator both use
this module (and :mod:`estimator.inference.sampling`, which measures a grasp's sampled
frames), so a model sees at run time exactly what it was trained on.

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
``size_px`` (``cv2.INTER_AREA``; :func:`~estimator.inference.window.window_images`, :func:`reduce_images`). The shipped
models' window is the simulated Wedge's pad (:func:`default_window_m`), so on that sensor
the window is the whole grid and the inputs are the grid area-averaged to ``size_px``, as
they always were. :func:`~estimator.inference.window.input_range` says whether a grasp's grid is within what a model was
trained on: a grid much coarser than the input pitch is refused, a pad covering little of
the window or a contact cut off by the edge of a pad smaller than the window widens the
interval.

Output scale
------------
log10 E in [3, 12] (:data:`LOG10_E_RANGE`), from 1 kPa (softer than any foam)
to 1 TPa (stiffer than any metal; the published labels span 5 kPa to 250 GPa):
the network's distribution is over bins of that range
(:mod:`estimator.inference.distribution`), so every estimate is a finite,
positive modulus.
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Protocol

import cv2
import numpy as np

from estimator.analytical import METHODS
from estimator.errors import ModelError
from estimator.estimate import STATES, Estimate
from estimator.inference.window import window_images
from teleop.settings import SensorSettings

__all__ = [
    "ANALYTICAL_METHODS",
    "FEATURES_PER_METHOD",
    "LOG10_E_RANGE",
    "REFERENCE_FINGER_STIFFNESS_N_PER_M",
    "REFERENCE_GEL_MODULUS_PA",
    "REFERENCE_GEL_THICKNESS_M",
    "RIG_FEATURES",
    "RIG_QUANTITIES",
    "MEASUREMENT_VERSION",
    "SIZE_PX_RANGE",
    "Variant",
    "analytical_features",
    "analytical_floor",
    "calibration_smoothings",
    "default_window_m",
    "distinct_frames",
    "encode",
    "gel_scale",
    "rig_features",
    "reduce_images",
    "smoothings_text",
]

LOG10_E_RANGE = (3.0, 12.0)
#: The gel the model's forces and moduli refer to (Pa): the simulated Wedge's (module notes, "Gel scale").
REFERENCE_GEL_MODULUS_PA = 275e3
#: The rig features' reference gel thickness (m) and finger stiffness (N/m): the shipped settings'.
REFERENCE_GEL_THICKNESS_M = 3e-3
REFERENCE_FINGER_STIFFNESS_N_PER_M = 2e5
RIG_FEATURES = 2
#: What a grasp records of the rig that measured it (a sample's fields, a model's ``data.rig_range``).
RIG_QUANTITIES = ("gel_modulus_pa", "gel_thickness_m", "finger_stiffness_n_per_m")
ANALYTICAL_METHODS = METHODS
#: The analytical methods whose lower bounds a hybrid model takes as a floor on its distribution
#: (:func:`analytical_floor`): on the shipped models' validation grasps they held for 99.2 % (no_tactile,
#: 390 bounds) and 99.7 % (series, 796); the elastic fit's for 91 %.
FLOOR_METHODS = ("no_tactile", "series")
FEATURES_PER_METHOD = 2 + len(STATES)
FORCE_SCALE_N = 30.0
WIDTH_SCALE_M = 0.08
DEPTH_SCALE_M = 1e-3
RGB_SCALE = 64.0
IMAGES = ("depth", "rgb")
_VARIANT = re.compile(r"^(depth|rgb)((?:\+(?:markers|fw|analytical))*)$")
#: A window side outside this range (m) is not a gel pad.
WINDOW_RANGE_M = (1e-3, 0.2)
#: The ``size_px`` a model may read, ((min, max) rows, (min, max) cols); the maxima are the
#: simulated Wedge's 250 x 350 grid. ``estimator build-dataset --size`` refuses the same.
SIZE_PX_RANGE = ((8, 250), (8, 350))


def size_px_ok(rows: int, cols: int) -> bool:
    """Whether a model may read images of ``rows`` x ``cols`` (:data:`SIZE_PX_RANGE`)."""
    (row_lo, row_hi), (col_lo, col_hi) = SIZE_PX_RANGE
    return row_lo <= rows <= row_hi and col_lo <= cols <= col_hi


def size_px_range_text() -> str:
    """:data:`SIZE_PX_RANGE` in words, for error messages."""
    (row_lo, row_hi), (col_lo, col_hi) = SIZE_PX_RANGE
    return f"rows {row_lo}..{row_hi} and cols {col_lo}..{col_hi}"


def calibration_smoothings(data: Mapping[str, Any]) -> tuple[float, ...]:
    """The colour smoothings (Gaussian sigma, px of the calibration's images) of the calibrations whose
    depth a dataset holds or a model was trained on (``calibration_smoothing_px`` of ``dataset.json``
    or of ``metadata.json`` ``data``). A dataset or model without the key had none: calibrations
    could not smooth when it was made."""
    return tuple(sorted(float(v) for v in (data.get("calibration_smoothing_px") or [0.0])))


def smoothings_text(smoothings: Sequence[float]) -> str:
    """Calibration smoothings in words: ``"0 px"``, ``"0 and 2 px"``."""
    return " and ".join(f"{v:g}" for v in smoothings) + " px"


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
        if not size_px_ok(rows, cols):
            raise ModelError(f"variant size_px {self.size_px!r}: expected {size_px_range_text()}")
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
        """``IMAGE[+markers][+fw][+analytical]``, e.g. ``depth+fw+analytical`` or ``rgb+markers``: the parts
        in any order, each at most once (ModelError otherwise)."""
        match = _VARIANT.match(text.strip())
        if not match:
            raise ModelError(
                f"variant {text!r}: expected depth or rgb followed by any of +markers, +fw, "
                "+analytical (e.g. depth+fw+analytical)"
            )
        parts = [p for p in match.group(2).split("+") if p]
        twice = sorted({p for p in parts if parts.count(p) > 1})
        if twice:
            raise ModelError(f"variant {text!r}: {', '.join('+' + p for p in twice)} given more than once; name "
                             "each part once (e.g. depth+fw+analytical)")
        flags = set(parts)
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


def analytical_floor(estimates: Sequence[Estimate], *, methods: Sequence[str] = FLOOR_METHODS, scale: float = 1.0
                     ) -> tuple[float, str | None]:
    """The highest lower bound among ``methods``' estimates, as log10 of the modulus (Pa) times ``scale``
    (the grasp's :func:`gel_scale`), and the method that gives it; ``(-inf, None)`` when none bounds it."""
    bounds = [(math.log10(e.interval_pa[0] * scale), e.method) for e in estimates
              if e.method in methods and e.state == "lower_bound"]
    return max(bounds, default=(-math.inf, None))


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
    (:func:`~estimator.inference.window.window_images`); without it they are reduced whole. ``size_px`` None keeps the size
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


#: Version of the measurement that turns a record into model inputs (segmentation, depth, contact
#: features, analytical fits, sampling). Raise it with any change that alters the inputs; a model
#: records the version its data was measured with (``data.measurement_version``), and
#: :mod:`estimator.inference.reference` checks that its recorded inputs on a fixed reference record
#: still come out the same, so a change that alters them without a raised version fails a test.
MEASUREMENT_VERSION = 4
