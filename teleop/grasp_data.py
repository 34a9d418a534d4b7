"""What one grasp record holds, in memory: its sample and frame streams, label and provenance.

:mod:`teleop.record` writes and reads these as the versioned ``.grasp`` file (its docstring
documents the format byte by byte) and re-exports every name here.
"""

from __future__ import annotations

import io
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from importlib import metadata
from typing import Any

import cv2
import numpy as np
from PIL import Image

from teleop.clikit import DISTRIBUTION
from teleop.errors import RecordError
from teleop.labels import LABEL_SOURCES
from teleop.settings import GripperSettings, SensorSettings

__all__ = [
    "GRASP_DONE_EVENT",
    "STYLES",
    "FrameStream",
    "GraspRecord",
    "Label",
    "Provenance",
    "Samples",
    "decode_image",
    "reduce_image",
    "software_version",
]

# Provenance.style: how the grasp was driven (module notes); version 1 knew only the first.
STYLES = ("script", "operator")
# Event: the gripper's grasp command completed (fingers stopped at the target force, held until release).
GRASP_DONE_EVENT = "grasp_done"
ENCODINGS = {"jpeg": ".jpg", "png": ".png"}
# Reductions OpenCV decodes straight to (a JPEG through its scaled inverse DCT, a fraction of the work).
_DECODE_REDUCED = {1: cv2.IMREAD_COLOR, 2: cv2.IMREAD_REDUCED_COLOR_2, 4: cv2.IMREAD_REDUCED_COLOR_4,
                   8: cv2.IMREAD_REDUCED_COLOR_8}


def reduce_image(image: np.ndarray, reduce: int) -> np.ndarray:
    """``image`` (H x W [x C]) averaged over ``reduce`` x ``reduce`` px blocks (``cv2.INTER_AREA``), same
    dtype; ValueError unless ``reduce`` is a whole number >= 1 dividing both sides."""
    rows, cols = image.shape[:2]
    if isinstance(reduce, bool) or not isinstance(reduce, int) or reduce < 1 or rows % reduce or cols % reduce:
        raise ValueError(f"reduce {reduce!r}: expected a whole number >= 1 dividing both sides of a "
                         f"{rows} x {cols} px image")
    if reduce == 1:
        return image
    return cv2.resize(image, (cols // reduce, rows // reduce), interpolation=cv2.INTER_AREA)


def decode_image(data: bytes | np.ndarray, *, reduce: int = 1,
                 shape: tuple[int, int] | None = None) -> np.ndarray | None:
    """A JPEG or PNG image as uint8 H x W x 3 BGR, ``reduce`` times smaller on each side; None when the
    bytes do not decode.

    Reductions of 2, 4 and 8 are decoded at that size (for PNG, the same as averaging the decoded
    image over blocks; for JPEG, within a few levels of it); others decode the full image and
    average it (:func:`reduce_image`, which raises ValueError when they do not divide its sides).

    ``shape``: the (rows, cols) the image must have, checked in its header before anything is
    decoded (ValueError naming both sizes otherwise): a few bytes may declare an image of gigabytes.
    """
    buffer = np.frombuffer(data, dtype=np.uint8) if isinstance(data, bytes | bytearray) else np.asarray(data)
    if shape is not None:
        rows, cols = shape
        try:
            declared = _declared_size(buffer)
        except Image.DecompressionBombError as exc:  # Pillow's own limit, far above any frame's size
            raise ValueError(f"image refused before decoding, expected {cols}x{rows} px: {exc}") from exc
        if declared is None:
            return None
        if declared != (cols, rows):
            raise ValueError(f"image declares {declared[0]}x{declared[1]} px, expected {cols}x{rows} px: "
                             "refused before decoding")
    try:
        image = cv2.imdecode(buffer, _DECODE_REDUCED.get(reduce, cv2.IMREAD_COLOR))
    except cv2.error:  # an empty or malformed buffer
        return None
    if image is None or reduce in _DECODE_REDUCED:
        return image
    return reduce_image(image, reduce)


def _declared_size(buffer: np.ndarray) -> tuple[int, int] | None:
    """(width, height) the JPEG or PNG header in ``buffer`` declares, read without decoding; None
    when it has none. Raises Image.DecompressionBombError for a size above Pillow's limit."""
    try:
        with Image.open(io.BytesIO(buffer), formats=("JPEG", "PNG")) as image:
            return image.size
    except OSError:  # no JPEG or PNG header, or a broken one (UnidentifiedImageError is one)
        return None


def software_version() -> str:
    """Installed version of the ``compliance-teleop`` distribution (:data:`~teleop.clikit.DISTRIBUTION`)."""
    try:
        return metadata.version(DISTRIBUTION)
    except metadata.PackageNotFoundError:
        return "0+unknown"


@dataclass(frozen=True)
class Samples:
    """A timestamped scalar stream: ``t_s`` (s) and ``value`` (unit in the owner's name)."""

    t_s: np.ndarray
    value: np.ndarray

    def __post_init__(self) -> None:
        t = np.asarray(self.t_s, dtype=np.float64)
        v = np.asarray(self.value, dtype=np.float64)
        if t.ndim != 1 or v.ndim != 1 or t.shape != v.shape:
            raise ValueError(
                f"Samples: t_s and value must be 1-D of one length, got shapes {t.shape} and {v.shape}"
            )
        object.__setattr__(self, "t_s", t)
        object.__setattr__(self, "value", v)

    def __len__(self) -> int:
        return int(self.t_s.shape[0])


@dataclass(frozen=True)
class FrameStream:
    """Tactile frames of one finger, kept encoded exactly as captured.

    Parameters
    ----------
    finger : str
        Finger name; matches a sensor in the record.
    t_s : ndarray, shape (n,)
        Capture time of each frame, seconds.
    encoded : tuple of bytes
        One JPEG or PNG image per frame.
    encoding : {"jpeg", "png"}
    jpeg_quality : int or None
        Quality the frames were compressed with, when ``encoding == "jpeg"`` and known.
    """

    finger: str
    t_s: np.ndarray
    encoded: tuple[bytes, ...]
    encoding: str = "png"
    jpeg_quality: int | None = None
    shape: tuple[int, int, int] | None = None

    def __post_init__(self) -> None:
        t = np.asarray(self.t_s, dtype=np.float64)
        if t.ndim != 1 or t.shape[0] != len(self.encoded):
            raise ValueError(
                f"FrameStream {self.finger!r}: {len(self.encoded)} frames but t_s has shape {t.shape}"
            )
        if self.encoding not in ENCODINGS:
            raise ValueError(f"FrameStream {self.finger!r}: encoding {self.encoding!r} is not one of {sorted(ENCODINGS)}")
        object.__setattr__(self, "t_s", t)
        object.__setattr__(self, "encoded", tuple(bytes(b) for b in self.encoded))

    def __len__(self) -> int:
        return len(self.encoded)

    @classmethod
    def from_frames(
        cls,
        finger: str,
        t_s: Sequence[float] | np.ndarray,
        frames: Iterable[np.ndarray],
        *,
        encoding: str = "png",
        jpeg_quality: int = 90,
    ) -> FrameStream:
        """Encode uint8 H x W x 3 BGR frames (``png``: lossless; ``jpeg``: at ``jpeg_quality``)."""
        if encoding not in ENCODINGS:
            raise ValueError(f"encoding {encoding!r} is not one of {sorted(ENCODINGS)}")
        params = [cv2.IMWRITE_JPEG_QUALITY, int(jpeg_quality)] if encoding == "jpeg" else [cv2.IMWRITE_PNG_COMPRESSION, 1]
        encoded = []
        shape = None
        for i, frame in enumerate(frames):
            frame = np.asarray(frame)
            if frame.dtype != np.uint8 or frame.ndim != 3 or frame.shape[2] != 3:
                raise ValueError(
                    f"frame {i} of finger {finger!r}: expected uint8 H x W x 3, got {frame.dtype} {frame.shape}"
                )
            shape = frame.shape
            ok, buf = cv2.imencode(ENCODINGS[encoding], frame, params)
            if not ok:
                raise ValueError(f"frame {i} of finger {finger!r}: OpenCV could not encode it as {encoding}")
            encoded.append(buf.tobytes())
        return cls(
            finger=finger,
            t_s=np.asarray(t_s, dtype=np.float64),
            encoded=tuple(encoded),
            encoding=encoding,
            jpeg_quality=int(jpeg_quality) if encoding == "jpeg" else None,
            shape=tuple(shape) if shape is not None else None,
        )

    def frame(self, index: int, *, reduce: int = 1) -> np.ndarray:
        """Decode frame ``index`` to uint8 H x W x 3 BGR, ``reduce`` times smaller on each side
        (:func:`decode_image`)."""
        image = decode_image(self.encoded[index], reduce=reduce)
        if image is None:
            raise RecordError(f"finger {self.finger!r} frame {index}: {self.encoding} data does not decode")
        return image

    def frames(self, indices: Iterable[int] | None = None, *, reduce: int = 1) -> np.ndarray:
        """Decode frames (all by default) to an (n, H, W, 3) uint8 array, ``reduce`` times smaller on each side."""
        idx = range(len(self)) if indices is None else list(indices)
        decoded = [self.frame(i, reduce=reduce) for i in idx]
        if not decoded:
            rows, cols, channels = self.shape or (0, 0, 3)
            return np.zeros((0, rows // reduce, cols // reduce, channels), dtype=np.uint8)
        return np.stack(decoded)


@dataclass(frozen=True)
class Label:
    """What was grasped: ground truth for training and evaluation.

    ``source``: where the modulus comes from, one of :data:`teleop.labels.LABEL_SOURCES`
    (``"catalogue"``: the object's catalogue entry; ``"durometer"``: a Shore hardness converted to a
    modulus; ...); ``detail``: free text about it (e.g. the reading and the conversion used).
    """

    object_name: str
    modulus_pa: float | None = None
    material: str = ""
    shape: str = ""
    extra: Mapping[str, Any] = field(default_factory=dict)
    source: str = "catalogue"
    detail: str = ""

    def __post_init__(self) -> None:
        if self.modulus_pa is not None and not (np.isfinite(self.modulus_pa) and self.modulus_pa > 0):
            raise ValueError(f"Label {self.object_name!r}: modulus_pa must be finite and > 0, got {self.modulus_pa}")
        if self.source not in LABEL_SOURCES:
            raise ValueError(f"Label {self.object_name!r}: source {self.source!r} is not one of "
                             f"{', '.join(LABEL_SOURCES)}")
        if not isinstance(self.detail, str):
            raise ValueError(f"Label {self.object_name!r}: detail must be text, got {self.detail!r}")


@dataclass(frozen=True)
class Provenance:
    """Where a record came from, and how the grasp was driven (``style``, one of :data:`STYLES`)."""

    source: str  # "simulated", "hardware" or "imported"
    software_version: str = field(default_factory=software_version)
    seed: int | None = None
    model: str = ""  # which physical model or capture path produced it
    created_utc: str = ""
    extra: Mapping[str, Any] = field(default_factory=dict)
    style: str = "script"

    def __post_init__(self) -> None:
        if self.source not in ("simulated", "hardware", "imported"):
            raise ValueError(f"Provenance.source {self.source!r}: expected simulated, hardware or imported")
        if self.style not in STYLES:
            raise ValueError(f"Provenance.style {self.style!r}: expected {' or '.join(STYLES)}")


@dataclass(frozen=True)
class GraspRecord:
    """One grasp: frames per finger, forces and widths, each with its own timestamps.

    ``gripper``: the gripper's settings as configured for this grasp, when the record
    carries them (None: unknown; use the reader's settings).

    ``calibration_files``: finger -> the bytes of that sensor's calibration file, for a record that
    carries them (format version 3, module notes); written inside the record, and on reading the
    sensor's ``calibration`` names a copy of them (:func:`calibration_cache`).
    """

    sensors: tuple[SensorSettings, ...]
    frames: tuple[FrameStream, ...]
    force_n: Samples
    width_m: Samples
    provenance: Provenance
    label: Label | None = None
    events: Mapping[str, float] = field(default_factory=dict)
    calibration: Mapping[str, np.ndarray] = field(default_factory=dict)
    gripper: GripperSettings | None = None
    calibration_files: Mapping[str, bytes] = field(default_factory=dict)

    def __post_init__(self) -> None:
        fingers = {s.finger for s in self.sensors}
        for stream in self.frames:
            if stream.finger not in fingers:
                raise ValueError(f"frames for finger {stream.finger!r} but no sensor on it (sensors: {sorted(fingers)})")
        for finger in self.calibration_files:
            if finger not in fingers:
                raise ValueError(f"a calibration file for finger {finger!r} but no sensor on it "
                                 f"(sensors: {sorted(fingers)})")

    def sensor(self, finger: str) -> SensorSettings:
        for s in self.sensors:
            if s.finger == finger:
                return s
        raise KeyError(f"no sensor on finger {finger!r}; record has {[s.finger for s in self.sensors]}")

    def stream(self, finger: str) -> FrameStream:
        for s in self.frames:
            if s.finger == finger:
                return s
        raise KeyError(f"no frames from finger {finger!r}; record has {[s.finger for s in self.frames]}")
