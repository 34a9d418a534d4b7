"""Colour-to-gradient calibration of a GelSight-style sensor: the table, its lookup and its file.

The table is fitted from ball presses by
:func:`~estimator.perception.calibration_fit.fit_calibration`.

Model
-----
The gel's reflective skin is lit from several sides in different colours, so
the colour change of a pixel against the no-contact reference encodes the
local surface slope. The calibration is a lookup table over that change:

* feature: per channel the *relative* change ``(frame - reference) / reference``
  (dividing by the reference evens out the uneven illumination) of the two images
  each smoothed by a Gaussian of ``smoothing_px`` pixels, in floating point, quantised into
  ``bins`` bins of width ``2 * relative_range / bins``, bin ``bins // 2``
  centred on no change (so sensor noise on an untouched pixel stays in one
  bin); changes beyond the range are clipped into the end bins;
* output: the mean surface gradient ``(dz/dx, dz/dy)`` (dimensionless, ``x``
  right, ``y`` down, ``z`` into the gel) of the calibration pixels that fell
  in the bin;
* position: the image is split into ``tiles`` (rows x cols) regions with a
  table each, because the light falls at different angles across the pad.
  Each tile's bin mean is shrunk towards the all-image mean with a prior
  weight of ``tile_prior_count`` pixels, so sparsely seen bins fall back on it;
  bins never seen anywhere take the value of the nearest seen bin.

Why smooth: a slope below ~0.05 changes an 8-bit pixel's colour by a grey level or two, the
size of the camera and JPEG noise, so pixel by pixel broad, shallow contacts read as flat.
Averaged over a few pixels in floating point, those changes stand out of the noise and land in
bins of their own; the table is then fitted on the same smoothed changes
(:mod:`~estimator.perception.calibration_fit`, which gives the figures and why the shipped
calibrations have none). With ``smoothing_px`` 0 (every file of format version 1) a lookup is a
few integer gathers per pixel (the 256 x 256 (reference, value) pairs per channel are
pre-quantised).

File format
-----------
``.npz`` written with :meth:`Calibration.save` and read with
:func:`load_calibration` (``allow_pickle=False``): ``lut`` float32
``(tiles_y, tiles_x, bins, bins, bins, 2)``, ``image_shape`` int64 (2,),
``pixel_pitch_m``, ``ball_radius_m``, ``relative_range``, ``smoothing_px`` float64
scalars and ``meta`` (a JSON string: format name, version, provenance). Version 1 files
have no ``smoothing_px`` and read as 0.
"""

from __future__ import annotations

import functools
import json
import math
import zipfile
import zlib
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from estimator.errors import CalibrationError, PerceptionError
from teleop.staging import staged

__all__ = ["FORMAT_NAME", "FORMAT_VERSION", "READABLE_VERSIONS", "Calibration", "load_calibration", "lut_index"]

FORMAT_NAME = "compliance-teleop.calibration"
FORMAT_VERSION = 2
#: Format versions :func:`load_calibration` reads (1: before ``smoothing_px``, read as 0).
READABLE_VERSIONS = (1, 2)


# --------------------------------------------------------------------------- lookup


def _bin_of(relative: np.ndarray, bins: int, relative_range: float) -> np.ndarray:
    """The bin (int32) of each relative colour change: ``bins`` bins over ``[-range, +range]``, bin
    ``bins // 2`` centred on no change, changes beyond the range in the end bins."""
    quantised = np.floor(relative * (bins / (2.0 * relative_range)) + 0.5) + bins // 2
    return np.clip(quantised, 0, bins - 1).astype(np.int32)


@functools.lru_cache(maxsize=8)
def _channel_codes(bins: int, relative_range: float) -> np.ndarray:
    """Bin offsets per channel for every (reference, value) byte pair.

    Row ``c`` holds, at index ``reference * 256 + value``, the bin of the
    relative change in channel ``c`` times that channel's stride in the
    flattened ``(bins, bins, bins)`` table, so a lookup is a sum of gathers.
    """
    reference, value = np.divmod(np.arange(256 * 256, dtype=np.float64), 256.0)
    quantised = _bin_of((value - reference) / np.maximum(reference, 1.0), bins, relative_range)
    codes = quantised[None, :] * np.array([bins * bins, bins, 1], dtype=np.int32)[:, None]
    codes.setflags(write=False)
    return codes


@functools.lru_cache(maxsize=8)
def _tile_offsets(shape: tuple[int, int], tiles: tuple[int, int], bins: int) -> np.ndarray:
    """Per pixel, the start of its tile's table in the flattened LUT (int32, read-only)."""
    rows, cols = shape
    tile_row = np.arange(rows) * tiles[0] // rows
    tile_col = np.arange(cols) * tiles[1] // cols
    offsets = ((tile_row[:, None] * tiles[1] + tile_col[None, :]) * bins**3).astype(np.int32)
    offsets.setflags(write=False)
    return offsets


def _lut_index(frame: np.ndarray, reference: np.ndarray, codes: np.ndarray, offsets: np.ndarray) -> np.ndarray:
    """Flat LUT index of every pixel (int32, H x W)."""
    pair = reference.astype(np.uint16)
    pair <<= 8
    pair |= frame
    index = codes[0].take(pair[..., 0])
    index += codes[1].take(pair[..., 1])
    index += codes[2].take(pair[..., 2])
    index += offsets
    return index


def lut_index(frame: np.ndarray, reference: np.ndarray, *, bins: int, relative_range: float,
              offsets: np.ndarray, smoothing_px: float) -> np.ndarray:
    """Flat LUT index (int32, H x W) of every pixel: its tile's start in ``offsets`` plus the bin of
    its relative colour change, the images smoothed by a Gaussian of ``smoothing_px`` (module notes;
    0: the 8-bit pairs as they are)."""
    if smoothing_px == 0:
        return _lut_index(frame, reference, _channel_codes(bins, relative_range), offsets)
    value = cv2.GaussianBlur(frame.astype(np.float32), (0, 0), smoothing_px)
    base = cv2.GaussianBlur(reference.astype(np.float32), (0, 0), smoothing_px)
    value -= base
    value /= np.maximum(base, 1.0)
    quantised = _bin_of(value, bins, relative_range)
    return offsets + quantised[..., 0] * (bins * bins) + quantised[..., 1] * bins + quantised[..., 2]


def _check_image(name: str, image: Any, shape: tuple[int, int] | None, error: type[Exception]) -> None:
    if not isinstance(image, np.ndarray) or image.dtype != np.uint8 or image.ndim != 3 or image.shape[2] != 3:
        got = f"{image.dtype} {image.shape}" if isinstance(image, np.ndarray) else type(image).__name__
        raise error(f"{name}: expected a uint8 BGR image (H, W, 3), got {got}")
    if shape is not None and image.shape[:2] != tuple(shape):
        raise error(f"{name}: expected {shape[0]} x {shape[1]} pixels, got {image.shape[0]} x {image.shape[1]}")


# --------------------------------------------------------------------------- calibration


@dataclass(frozen=True, eq=False)
class Calibration:
    """Colour-to-gradient lookup table of one sensor, in one pixel frame.

    Attributes
    ----------
    lut : ndarray
        float32 ``(tiles_y, tiles_x, bins, bins, bins, 2)``: mean
        ``(dz/dx, dz/dy)`` per tile and (B, G, R) relative-change bin.
    image_shape : (int, int)
        (rows, cols) of the frames it applies to.
    pixel_pitch_m : float
        Gel surface per pixel of those frames, metres.
    ball_radius_m : float
        Radius of the calibration ball, metres.
    relative_range : float
        Relative colour change covered by the bins, ``[-range, +range]``.
    smoothing_px : float
        Gaussian sigma (pixels of those frames) the images are smoothed by before the lookup.
    provenance : Mapping
        JSON-able record of how it was made (source, split, circles, date).
    """

    lut: np.ndarray
    image_shape: tuple[int, int]
    pixel_pitch_m: float
    ball_radius_m: float
    relative_range: float = 1.0
    smoothing_px: float = 0.0
    provenance: Mapping[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        lut = self.lut
        if not isinstance(lut, np.ndarray) or lut.dtype != np.float32 or lut.ndim != 6 or lut.shape[-1] != 2:
            got = f"{lut.dtype} {lut.shape}" if isinstance(lut, np.ndarray) else type(lut).__name__
            raise CalibrationError(f"lut: expected float32 (tiles_y, tiles_x, bins, bins, bins, 2), got {got}")
        if not lut.shape[2] == lut.shape[3] == lut.shape[4] >= 2:
            raise CalibrationError(f"lut: colour axes must have equal length >= 2, got {lut.shape}")
        if not np.isfinite(lut).all():
            raise CalibrationError("lut: contains NaN or infinite gradients")
        shape = tuple(int(v) for v in self.image_shape)
        if len(shape) != 2 or min(shape) < 3:
            raise CalibrationError(f"image_shape: expected (rows, cols) of at least 3, got {self.image_shape}")
        if lut.shape[0] > shape[0] or lut.shape[1] > shape[1]:
            raise CalibrationError(f"lut: {lut.shape[:2]} tiles do not fit a {shape} image")
        for name in ("pixel_pitch_m", "ball_radius_m", "relative_range"):
            value = getattr(self, name)
            if not (isinstance(value, int | float) and math.isfinite(value) and value > 0):
                raise CalibrationError(f"{name}: expected a positive number, got {value!r}")
        if not (isinstance(self.smoothing_px, int | float) and math.isfinite(self.smoothing_px)
                and self.smoothing_px >= 0):
            raise CalibrationError(f"smoothing_px: expected a number of pixels >= 0, got {self.smoothing_px!r}")
        frozen = np.ascontiguousarray(lut)
        if frozen is lut:
            frozen = lut.copy()
        frozen.setflags(write=False)
        object.__setattr__(self, "lut", frozen)
        object.__setattr__(self, "image_shape", shape)
        object.__setattr__(self, "provenance", dict(self.provenance))

    @property
    def bins(self) -> int:
        """Bins per colour channel."""
        return int(self.lut.shape[2])

    @property
    def tiles(self) -> tuple[int, int]:
        """(rows, cols) of position tiles."""
        return (int(self.lut.shape[0]), int(self.lut.shape[1]))

    @functools.cached_property
    def _flat_lut(self) -> np.ndarray:
        # One complex64 per bin: a single gather fetches both gradients.
        return self.lut.reshape(-1, 2).view(np.complex64).ravel()

    def gradients(self, frame: np.ndarray, reference: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Surface gradients of a frame against its no-contact reference.

        Parameters
        ----------
        frame, reference : ndarray
            uint8 BGR, shape ``image_shape + (3,)``, same pixel frame as the
            calibration.

        Returns
        -------
        gx, gy : ndarray
            float32 (rows, cols): ``dz/dx`` (along columns) and ``dz/dy``
            (along rows), dimensionless, z into the gel.
        """
        _check_image("frame", frame, self.image_shape, PerceptionError)
        _check_image("reference", reference, self.image_shape, PerceptionError)
        offsets = _tile_offsets(self.image_shape, self.tiles, self.bins)
        index = lut_index(frame, reference, bins=self.bins, relative_range=float(self.relative_range),
                          offsets=offsets, smoothing_px=float(self.smoothing_px))
        slopes = self._flat_lut.take(index)
        return slopes.real, slopes.imag

    def save(self, path: str | Path) -> Path:
        """Write the calibration as ``.npz`` (see the module notes); returns the path."""
        path = Path(path)
        meta = {"format": FORMAT_NAME, "version": FORMAT_VERSION, "provenance": dict(self.provenance)}
        try:
            # Written under a staged name and renamed over ``path`` once complete: an interrupted
            # save leaves the calibration there as it was.
            with staged(path) as partial, partial.open("wb") as fh:
                np.savez_compressed(
                    fh,
                    lut=self.lut,
                    image_shape=np.asarray(self.image_shape, dtype=np.int64),
                    pixel_pitch_m=np.float64(self.pixel_pitch_m),
                    ball_radius_m=np.float64(self.ball_radius_m),
                    relative_range=np.float64(self.relative_range),
                    smoothing_px=np.float64(self.smoothing_px),
                    meta=np.array(json.dumps(meta, sort_keys=True)),
                )
        except OSError as exc:
            raise CalibrationError(f"cannot write calibration {path}: {exc.strerror or exc}") from exc
        return path


def read_npz(path: Path, *, missing: str, kind: str) -> dict[str, np.ndarray]:
    """Every member of the ``.npz`` at ``path`` (no pickles); CalibrationError saying ``missing``
    when there is no file, and that it is not ``kind`` when it cannot be read."""
    expected = "expected a zip archive of numpy arrays, as numpy.savez writes"
    try:
        with open(path, "rb") as file:
            zipped = file.read(4) == b"PK\x03\x04"
    except FileNotFoundError as exc:
        raise CalibrationError(missing) from exc
    except OSError as exc:
        raise CalibrationError(f"{path}: not {kind}: {exc}") from exc
    if not zipped:  # numpy would read it as a pickle, or as one array
        raise CalibrationError(f"{path}: not {kind}: {expected}, and the file is not one")
    try:
        with np.load(path, allow_pickle=False) as data:
            return {name: data[name] for name in data.files}
    except ValueError as exc:
        if "allow_pickle" in str(exc):  # an object member: reading it would run pickled code
            raise CalibrationError(f"{path}: not {kind}: a member holds pickled Python objects ({expected})") from exc
        raise CalibrationError(f"{path}: not {kind}: {expected}; this one does not read ({exc})") from exc
    except (OSError, EOFError, zipfile.BadZipFile, zlib.error) as exc:  # zlib: a damaged compressed member
        raise CalibrationError(f"{path}: not {kind}: {expected}; this one does not read ({exc})") from exc


def load_calibration(path: str | Path) -> Calibration:
    """Read a calibration written by :meth:`Calibration.save`.

    Raises
    ------
    CalibrationError
        The file is missing, not an ``.npz``, lacks a member, or holds values
        a calibration cannot have; the message names the file and member.
    """
    path = Path(path)
    members = read_npz(path, missing=f"calibration file {path} does not exist", kind="a calibration .npz")
    missing = sorted({"lut", "image_shape", "pixel_pitch_m", "ball_radius_m", "relative_range", "meta"} - set(members))
    if missing:
        raise CalibrationError(f"{path}: missing member(s) {', '.join(missing)}")
    try:
        meta = json.loads(str(members["meta"]))
    except json.JSONDecodeError as exc:
        raise CalibrationError(f"{path}: member 'meta' is not JSON: {exc}") from exc
    if not isinstance(meta, dict) or meta.get("format") != FORMAT_NAME:
        raise CalibrationError(f"{path}: member 'meta' does not name format {FORMAT_NAME!r}")
    version = meta.get("version")
    if version not in READABLE_VERSIONS:
        raise CalibrationError(f"{path}: calibration format version {version!r}, this software reads "
                               f"{' and '.join(map(str, READABLE_VERSIONS))}")
    if version >= 2 and "smoothing_px" not in members:
        raise CalibrationError(f"{path}: missing member smoothing_px (format version {version})")
    try:
        return Calibration(
            lut=members["lut"],
            image_shape=_image_shape(members["image_shape"]),
            pixel_pitch_m=_scalar("pixel_pitch_m", members["pixel_pitch_m"]),
            ball_radius_m=_scalar("ball_radius_m", members["ball_radius_m"]),
            relative_range=_scalar("relative_range", members["relative_range"]),
            smoothing_px=_scalar("smoothing_px", members.get("smoothing_px", np.float64(0.0)), what="a scalar float >= 0"),
            provenance=meta.get("provenance", {}),
        )
    except (CalibrationError, TypeError, ValueError) as exc:
        raise CalibrationError(f"{path}: {exc}") from exc


def _kind(value: np.ndarray) -> str:
    """How a member that is not what was expected looks, for the message."""
    return f"a {value.ndim}-D array of {value.dtype}" if value.ndim else f"a scalar of {value.dtype} ({value!s:.20})"


def _scalar(name: str, value: np.ndarray, *, what: str = "a positive scalar float") -> float:
    """A number member as :meth:`Calibration.save` writes it: one real number (a 0-D array).

    float() itself would say "only 0-dimensional arrays ..." or "could not convert string ...",
    naming neither the member nor what it should hold."""
    if value.ndim != 0 or value.dtype.kind not in "iuf":
        raise CalibrationError(f"{name}: expected {what}, got {_kind(value)}")
    return float(value)


def _image_shape(value: np.ndarray) -> tuple[int, ...]:
    """Member ``image_shape`` as :meth:`Calibration.save` writes it: whole numbers (rows, cols)."""
    if value.ndim != 1 or value.dtype.kind not in "iu":
        raise CalibrationError(f"image_shape: expected whole numbers (rows, cols), got {_kind(value)}")
    return tuple(int(v) for v in value)
