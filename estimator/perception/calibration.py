"""Colour-to-gradient calibration of a GelSight-style sensor from ball presses.

Model
-----
The gel's reflective skin is lit from several sides in different colours, so
the colour change of a pixel against the no-contact reference encodes the
local surface slope. The calibration is a lookup table over that change:

* feature: per channel the *relative* change ``(frame - reference) / reference``
  (dividing by the reference evens out the uneven illumination), quantised into
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

A lookup costs a few integer gathers per pixel (the 256 x 256 (reference,
value) pairs per channel are pre-quantised), no floating-point maths.

Training labels come from a ball of known radius ``R`` pressed into the gel.
Inside the contact circle (centre ``c``, radius ``a``) the gel follows the
ball, a cap ``z = sqrt(R^2 - r^2) - const``, so ``dz/dx = -(x - cx) /
sqrt(R^2 - r^2)`` and likewise for y (pixels per pixel, with R in pixels).
Pixels within ``inside_fraction * a`` of the centre are labelled so; the rim
is left out because the skin does not follow the ball exactly at the contact
edge. Pixels beyond ``outside_fraction * a`` and beyond the press's visible
colour change are labelled flat; the ring in between (where the gel is pulled
down around the ball) is not used.

Recorded press circles
----------------------
Press circles from a dataPack (``touch_center``, ``touch_radius``) are hand
annotations, and their conventions differ between sets: the GelSight set in
``taxim`` draws the contact a few pixels wider than it is, while the GelSight
Mini set scatters the centres by up to ~20 px around where the ball visibly
pressed and draws the radius at the edge of the whole visible dimple (34-57 px)
rather than of the contact (14-20 px, where the colour change peaks; the soft
Mini gel sinks in far around the ball). Labelling that dimple with the ball's
slopes teaches the table a depth-dependent mapping (shallow presses came out
as smaller spheres, deep ones as larger). By default (``refine_passes=1``) the
annotations therefore only seed the calibration: a first table is fitted with
them, every training press is reconstructed with it and its centre re-measured
with :func:`~estimator.perception.depth.fit_sphere` (sphere-fit centre, which
does not depend on the annotated radius), and its rings with
:func:`press_rings` around that centre, straight from the images: the contact
radius is the ring of largest mean colour change (the surface slope, and so
the colour change, peaks at the contact edge), and the flat gel starts where
the change has fallen to ``flat_fraction`` of that peak. The table is then
fitted again with the re-measured circles. A re-measured circle whose centre
moved further than the given radius ``a`` is discarded and the given one
kept. ``refine_passes=0`` uses the annotations as given. Flat labels always
start beyond both ``outside_fraction * a`` and the measured flat ring, so the
sunk-in gel around a press is never labelled flat. The circles actually used
are kept in the calibration's provenance. Circles detected in the images
(:func:`detect_press_circle`, for presses without annotations) are seeds of the
same kind.

File format
-----------
``.npz`` written with :meth:`Calibration.save` and read with
:func:`load_calibration` (``allow_pickle=False``): ``lut`` float32
``(tiles_y, tiles_x, bins, bins, bins, 2)``, ``image_shape`` int64 (2,),
``pixel_pitch_m``, ``ball_radius_m``, ``relative_range`` float64 scalars and
``meta`` (a JSON string: format name, version, provenance).
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import json
import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any, NamedTuple

import cv2
import numpy as np
import scipy.ndimage
from tqdm import tqdm

from estimator.errors import CalibrationError, PerceptionError
from estimator.perception.depth import fit_sphere, reconstruct_depth
from estimator.perception.warp import warp_and_crop, warp_matrix, warp_points
from teleop.settings import SensorSettings

__all__ = [
    "FORMAT_NAME",
    "FORMAT_VERSION",
    "Calibration",
    "PressRings",
    "PressSet",
    "detect_press_circle",
    "fit_calibration",
    "load_calibration",
    "load_presses",
    "press_rings",
    "split_presses",
]

FORMAT_NAME = "compliance-teleop.calibration"
FORMAT_VERSION = 1
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")
REFERENCE_NAME = re.compile(r"^(f0|ref|background)", re.IGNORECASE)


# --------------------------------------------------------------------------- lookup


@functools.lru_cache(maxsize=8)
def _channel_codes(bins: int, relative_range: float) -> np.ndarray:
    """Bin offsets per channel for every (reference, value) byte pair.

    Row ``c`` holds, at index ``reference * 256 + value``, the bin of the
    relative change in channel ``c`` times that channel's stride in the
    flattened ``(bins, bins, bins)`` table, so a lookup is a sum of gathers.
    """
    reference, value = np.divmod(np.arange(256 * 256, dtype=np.float64), 256.0)
    relative = (value - reference) / np.maximum(reference, 1.0)
    quantised = np.floor(relative * (bins / (2.0 * relative_range)) + 0.5) + bins // 2
    quantised = np.clip(quantised, 0, bins - 1).astype(np.int32)
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
    provenance : Mapping
        JSON-able record of how it was made (source, split, circles, date).
    """

    lut: np.ndarray
    image_shape: tuple[int, int]
    pixel_pitch_m: float
    ball_radius_m: float
    relative_range: float = 1.0
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
        codes = _channel_codes(self.bins, float(self.relative_range))
        offsets = _tile_offsets(self.image_shape, self.tiles, self.bins)
        slopes = self._flat_lut.take(_lut_index(frame, reference, codes, offsets))
        return slopes.real, slopes.imag

    def save(self, path: str | Path) -> Path:
        """Write the calibration as ``.npz`` (see the module notes); returns the path."""
        path = Path(path)
        meta = {"format": FORMAT_NAME, "version": FORMAT_VERSION, "provenance": dict(self.provenance)}
        try:
            with path.open("wb") as fh:
                np.savez_compressed(
                    fh,
                    lut=self.lut,
                    image_shape=np.asarray(self.image_shape, dtype=np.int64),
                    pixel_pitch_m=np.float64(self.pixel_pitch_m),
                    ball_radius_m=np.float64(self.ball_radius_m),
                    relative_range=np.float64(self.relative_range),
                    meta=np.array(json.dumps(meta, sort_keys=True)),
                )
        except OSError as exc:
            raise CalibrationError(f"cannot write calibration {path}: {exc.strerror or exc}") from exc
        return path


def load_calibration(path: str | Path) -> Calibration:
    """Read a calibration written by :meth:`Calibration.save`.

    Raises
    ------
    CalibrationError
        The file is missing, not an ``.npz``, lacks a member, or holds values
        a calibration cannot have; the message names the file and member.
    """
    path = Path(path)
    try:
        with np.load(path, allow_pickle=False) as data:
            members = {name: data[name] for name in data.files}
    except FileNotFoundError as exc:
        raise CalibrationError(f"calibration file {path} does not exist") from exc
    except (OSError, ValueError, EOFError) as exc:
        raise CalibrationError(f"{path}: not a calibration .npz: {exc}") from exc
    missing = sorted({"lut", "image_shape", "pixel_pitch_m", "ball_radius_m", "relative_range", "meta"} - set(members))
    if missing:
        raise CalibrationError(f"{path}: missing member(s) {', '.join(missing)}")
    try:
        meta = json.loads(str(members["meta"]))
    except json.JSONDecodeError as exc:
        raise CalibrationError(f"{path}: member 'meta' is not JSON: {exc}") from exc
    if not isinstance(meta, dict) or meta.get("format") != FORMAT_NAME:
        raise CalibrationError(f"{path}: member 'meta' does not name format {FORMAT_NAME!r}")
    if meta.get("version") != FORMAT_VERSION:
        raise CalibrationError(
            f"{path}: calibration format version {meta.get('version')!r}, this software reads {FORMAT_VERSION}"
        )
    try:
        return Calibration(
            lut=members["lut"],
            image_shape=tuple(int(v) for v in members["image_shape"]),
            pixel_pitch_m=float(members["pixel_pitch_m"]),
            ball_radius_m=float(members["ball_radius_m"]),
            relative_range=float(members["relative_range"]),
            provenance=meta.get("provenance", {}),
        )
    except (CalibrationError, TypeError, ValueError) as exc:
        raise CalibrationError(f"{path}: {exc}") from exc


# --------------------------------------------------------------------------- fitting


def _press_labels(
    grid: tuple[np.ndarray, np.ndarray], center: np.ndarray, radius_px: float, flat_px: float,
    ball_px: float, inside_fraction: float, outside_fraction: float, markers: np.ndarray | None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Labelled pixels of one press, marker pixels left out.

    Returns the on-ball mask, its ``dz/dx`` and ``dz/dy`` (flat over that
    mask), and the flat-gel mask (beyond both ``outside_fraction * radius_px``
    and ``flat_px``); ``grid`` is ``np.indices`` (rows, cols).
    """
    dx, dy = grid[1] - center[0], grid[0] - center[1]
    r2 = dx * dx + dy * dy
    on_ball = r2 < (inside_fraction * radius_px) ** 2
    flat = r2 > max(outside_fraction * radius_px, flat_px) ** 2
    if markers is not None:
        on_ball &= ~markers
        flat &= ~markers
    cap = np.sqrt(np.maximum(ball_px**2 - r2[on_ball], 1e-12))
    return on_ball, -dx[on_ball] / cap, -dy[on_ball] / cap, flat


def _fit_table(
    reference: np.ndarray, presses: Sequence[np.ndarray], centers: np.ndarray, radii: np.ndarray,
    flat_radii: np.ndarray, markers: Sequence[np.ndarray | None], *, ball_px: float, bins: int, tiles: tuple[int, int], relative_range: float,
    inside_fraction: float, outside_fraction: float, tile_prior_count: float,
) -> np.ndarray:
    """Accumulate labelled pixels into bins and build the filled, tiled table."""
    shape = reference.shape[:2]
    n_tiles, n_colours = tiles[0] * tiles[1], bins**3
    codes = _channel_codes(bins, relative_range)
    offsets = _tile_offsets(shape, tiles, bins)
    grid = np.indices(shape, dtype=np.float64)
    count = np.zeros(n_tiles * n_colours)
    ball_index, ball_gx, ball_gy = [], [], []
    for press, center, radius, flat_px, mask in zip(presses, centers, radii, flat_radii, markers,
                                                   strict=True):
        on_ball, gx, gy, flat = _press_labels(grid, center, radius, flat_px, ball_px, inside_fraction,
                                              outside_fraction, mask)
        index = _lut_index(press, reference, codes, offsets)
        count += np.bincount(index[on_ball | flat], minlength=count.size)
        ball_index.append(index[on_ball])
        ball_gx.append(gx)
        ball_gy.append(gy)
    labelled_on_ball = sum(len(i) for i in ball_index)
    # Flat-gel pixels add to the counts only: their gradient is zero.
    sum_x = np.bincount(np.concatenate(ball_index), np.concatenate(ball_gx), minlength=count.size)
    sum_y = np.bincount(np.concatenate(ball_index), np.concatenate(ball_gy), minlength=count.size)
    if labelled_on_ball == 0:
        raise CalibrationError("centers_px/radii_px: no press circle covers any pixel of the images")
    sum_x, sum_y, count = (a.reshape(n_tiles, n_colours) for a in (sum_x, sum_y, count))
    seen = count.sum(axis=0)
    populated = seen > 0
    global_x = np.where(populated, sum_x.sum(axis=0) / np.maximum(seen, 1), 0.0)
    global_y = np.where(populated, sum_y.sum(axis=0) / np.maximum(seen, 1), 0.0)
    nearest = scipy.ndimage.distance_transform_edt(
        ~populated.reshape(bins, bins, bins), return_distances=False, return_indices=True
    )
    nearest_flat = np.ravel_multi_index(tuple(nearest), (bins, bins, bins)).ravel()
    global_x, global_y = global_x[nearest_flat], global_y[nearest_flat]
    lut_x = (sum_x + tile_prior_count * global_x) / (count + tile_prior_count)
    lut_y = (sum_y + tile_prior_count * global_y) / (count + tile_prior_count)
    lut = np.stack([lut_x, lut_y], axis=-1).astype(np.float32)
    return lut.reshape(tiles[0], tiles[1], bins, bins, bins, 2)


def _validate_presses(
    reference: Any, presses: Any, centers_px: Any, radii_px: Any, ball_px: float,
) -> tuple[list[np.ndarray], np.ndarray, np.ndarray]:
    _check_image("reference", reference, None, CalibrationError)
    shape = reference.shape[:2]
    as_stack = isinstance(presses, np.ndarray) and presses.ndim == 4
    as_list = isinstance(presses, Sequence) and not isinstance(presses, str | bytes)
    if as_stack or as_list:
        press_list = list(presses)
    else:
        raise CalibrationError(
            f"presses: expected a sequence of uint8 BGR images or an (N, H, W, 3) array, got "
            f"{getattr(presses, 'shape', type(presses).__name__)}"
        )
    if not press_list:
        raise CalibrationError("presses: empty; at least one ball press is needed")
    for i, press in enumerate(press_list):
        _check_image(f"presses[{i}]", press, shape, CalibrationError)
    n = len(press_list)
    centers = np.asarray(centers_px, dtype=np.float64)
    radii = np.asarray(radii_px, dtype=np.float64)
    if centers.shape != (n, 2):
        raise CalibrationError(f"centers_px: expected shape ({n}, 2) (x, y per press), got {centers.shape}")
    if radii.shape != (n,):
        raise CalibrationError(f"radii_px: expected shape ({n},), got {radii.shape}")
    if not (np.isfinite(centers).all() and np.isfinite(radii).all()):
        raise CalibrationError("centers_px/radii_px: contain NaN or infinite values")
    if (radii <= 0).any():
        raise CalibrationError(f"radii_px: expected positive contact radii, got {radii[radii <= 0][:5]}")
    if (radii >= ball_px).any():
        raise CalibrationError(
            f"radii_px: a contact radius of {radii.max():.1f} px is not smaller than the ball's "
            f"{ball_px:.1f} px; check ball_radius_m and pixel_pitch_m"
        )
    return press_list, centers, radii


def fit_calibration(
    reference: np.ndarray,
    presses: Sequence[np.ndarray] | np.ndarray,
    centers_px: Sequence[Sequence[float]] | np.ndarray,
    radii_px: Sequence[float] | np.ndarray,
    *,
    ball_radius_m: float,
    pixel_pitch_m: float,
    bins: int = 48,
    tiles: tuple[int, int] = (3, 3),
    relative_range: float = 1.0,
    inside_fraction: float = 0.95,
    outside_fraction: float = 2.0,
    flat_fraction: float = 0.1,
    tile_prior_count: float = 5.0,
    refine_passes: int = 1,
    marker_masks: Sequence[np.ndarray] | None = None,
    provenance: Mapping[str, Any] | None = None,
    progress: bool = False,
) -> Calibration:
    """Fit the colour-to-gradient table from presses of a ball of known radius.

    Parameters
    ----------
    reference : ndarray
        uint8 BGR no-contact frame (H, W, 3).
    presses : sequence of ndarray or ndarray
        uint8 BGR frames of the pressed ball, each (H, W, 3), same pixel frame.
    centers_px : array_like
        (N, 2) contact centres ``(x, y)``, pixels.
    radii_px : array_like
        (N,) contact radii, pixels; each must be below the ball radius.
    ball_radius_m : float
        Ball radius, metres.
    pixel_pitch_m : float
        Gel surface per pixel, metres.
    bins : int
        Bins per colour channel.
    tiles : (int, int)
        Position tiles (rows, cols), each with its own table.
    relative_range : float
        Relative colour change covered by the bins.
    inside_fraction, outside_fraction : float
        Label pixels within ``inside_fraction * a`` with the sphere's gradient
        and beyond ``outside_fraction * a`` as flat.
    flat_fraction : float
        In (0, 1): pixels are labelled flat only beyond the ring where the
        press's mean colour change has fallen to this share of its peak
        (:func:`press_rings`).
    tile_prior_count : float
        Weight (in pixels) pulling each tile's bin towards the all-image bin.
    refine_passes : int
        Times to re-measure the press circles (centre from the reconstruction
        with the current table, radius from :func:`press_rings`) and fit the
        table again (module notes); 0 uses the given circles as they are.
    marker_masks : sequence of ndarray, optional
        Per press, bool (H, W) marker-dot pixels (from
        :func:`~estimator.perception.markers.detect_markers`): left out of the
        table, and inpainted when the circles are re-measured.
    provenance : Mapping, optional
        Extra JSON-able facts recorded with the result.
    progress : bool
        Show a tqdm bar on stderr.

    Returns
    -------
    Calibration

    Raises
    ------
    CalibrationError
        An input has the wrong type, shape or dtype, the press list is empty,
        a radius is not positive or not below the ball's, or an option is out
        of range; the message names the input.
    """
    for name, value in (("ball_radius_m", ball_radius_m), ("pixel_pitch_m", pixel_pitch_m),
                        ("relative_range", relative_range), ("inside_fraction", inside_fraction),
                        ("tile_prior_count", tile_prior_count)):
        if not (isinstance(value, int | float) and math.isfinite(value) and value > 0):
            raise CalibrationError(f"{name}: expected a positive number, got {value!r}")
    if not (isinstance(refine_passes, int) and refine_passes >= 0):
        raise CalibrationError(f"refine_passes: expected a non-negative integer, got {refine_passes!r}")
    if not (isinstance(bins, int) and 2 <= bins <= 128):
        raise CalibrationError(f"bins: expected an integer in [2, 128], got {bins!r}")
    if not (isinstance(flat_fraction, int | float) and 0.0 < flat_fraction < 1.0):
        raise CalibrationError(f"flat_fraction: expected a value in (0, 1), got {flat_fraction!r}")
    if not outside_fraction > inside_fraction:
        raise CalibrationError(
            f"outside_fraction = {outside_fraction!r}: expected more than inside_fraction = {inside_fraction!r}"
        )
    ball_px = ball_radius_m / pixel_pitch_m
    press_list, centers, radii = _validate_presses(reference, presses, centers_px, radii_px, ball_px)
    tiles = tuple(int(t) for t in tiles)
    shape = reference.shape[:2]
    if len(tiles) != 2 or min(tiles) < 1 or tiles[0] > shape[0] or tiles[1] > shape[1]:
        raise CalibrationError(f"tiles: expected (rows, cols) between 1 and the image size, got {tiles}")
    options = dict(ball_px=ball_px, bins=bins, tiles=tiles, relative_range=float(relative_range),
                   inside_fraction=inside_fraction, outside_fraction=outside_fraction,
                   tile_prior_count=tile_prior_count)
    if marker_masks is None:
        masks = [None] * len(press_list)
    else:
        masks = list(marker_masks)
        if len(masks) != len(press_list) or any(
            not isinstance(m, np.ndarray) or m.dtype != bool or m.shape != shape for m in masks
        ):
            raise CalibrationError(
                f"marker_masks: expected {len(press_list)} bool arrays of shape {shape}, one per press"
            )

    def measured_rings(i: int, center: np.ndarray) -> PressRings | None:
        try:
            return press_rings(press_list[i], reference, center, max_radius_px=0.98 * ball_px,
                               flat_fraction=flat_fraction, marker_mask=masks[i])
        except CalibrationError:  # no visible change around that centre: keep what was given
            return None

    seeds = [measured_rings(i, center) for i, center in enumerate(centers)]
    flat_radii = np.array([0.0 if rings is None else rings.flat_px for rings in seeds])
    lut = _fit_table(reference, press_list, centers, radii, flat_radii, masks, **options)
    used_centers, used_radii = centers.copy(), radii.copy()
    refined = np.zeros(len(press_list), dtype=bool)
    bar = tqdm(total=refine_passes * len(press_list), desc="refining press circles", unit="press",
               disable=not progress)
    for _ in range(refine_passes):
        current = Calibration(lut, shape, pixel_pitch_m, ball_radius_m, relative_range)
        for i, press in enumerate(press_list):
            bar.update()
            depth = reconstruct_depth(press, reference, current, marker_mask=masks[i])
            fit = fit_sphere(depth, pixel_pitch_m=pixel_pitch_m, center_px=tuple(used_centers[i]))
            if not fit or math.dist(fit.center_px, centers[i]) > radii[i]:
                continue
            rings = measured_rings(i, np.array(fit.center_px))
            if rings is not None:
                used_centers[i], used_radii[i], flat_radii[i] = fit.center_px, rings.contact_px, rings.flat_px
                refined[i] = True
        lut = _fit_table(reference, press_list, used_centers, used_radii, flat_radii, masks, **options)
    bar.close()
    record = {
        "created_utc": datetime.now(UTC).isoformat(timespec="seconds"),
        "n_presses_used": len(press_list),
        "press_centers_px": used_centers.round(2).tolist(),
        "press_radii_px": used_radii.round(2).tolist(),
        "press_flat_radii_px": flat_radii.round(2).tolist(),
        "circles_refined": refined.tolist(),
        "markers_masked": marker_masks is not None,
        "inside_fraction": inside_fraction,
        "outside_fraction": outside_fraction,
        "flat_fraction": flat_fraction,
        "tile_prior_count": tile_prior_count,
        **dict(provenance or {}),
    }
    return Calibration(lut, shape, pixel_pitch_m, ball_radius_m, float(relative_range), record)


# --------------------------------------------------------------------------- press sets


def split_presses(n_presses: int, train_fraction: float) -> np.ndarray:
    """Deterministic, evenly spread training indices (the rest are held out).

    ``round(train_fraction * n)`` indices (at least one), spread over the
    sequence so both halves cover the pad alike: 0.5 takes every other press.
    """
    if not (isinstance(n_presses, int) and n_presses >= 1):
        raise CalibrationError(f"n_presses: expected a positive integer, got {n_presses!r}")
    if not (isinstance(train_fraction, int | float) and 0.0 < train_fraction <= 1.0):
        raise CalibrationError(f"train_fraction: expected a value in (0, 1], got {train_fraction!r}")
    n_train = max(1, round(train_fraction * n_presses))
    return np.unique(np.arange(n_train) * n_presses // n_train)


@dataclass(frozen=True, eq=False)
class PressSet:
    """Ball presses ready for calibration, all in one pixel frame.

    Attributes
    ----------
    reference : ndarray
        uint8 BGR no-contact frame.
    images : ndarray
        uint8 (N, H, W, 3) presses.
    centers_px, radii_px : ndarray or None
        (N, 2) contact centres ``(x, y)`` and (N,) radii, pixels; None until
        known (a folder of images records none).
    circles : str
        ``"recorded"`` (annotations from the file), ``"detected"`` (found by
        :func:`detect_press_circle`) or ``"none"``.
    frame : str
        ``"raw"`` or ``"warped_cropped"``: the pixel frame of the circles (and
        of the images once :meth:`in_sensor_frame` has run).
    mm_per_px, ball_radius_mm : float or None
        Pixel pitch and ball radius stated by the file, if any.
    source : str
        Where it was read from.
    sha256 : str
        Fingerprint of the reference and images as read (before any warp).
    warped : bool
        Whether the images are in the sensor's warped-and-cropped frame.
    """

    reference: np.ndarray
    images: np.ndarray
    centers_px: np.ndarray | None
    radii_px: np.ndarray | None
    circles: str
    frame: str
    mm_per_px: float | None
    ball_radius_mm: float | None
    source: str
    sha256: str
    warped: bool = False

    def __len__(self) -> int:
        return len(self.images)

    def in_sensor_frame(self, sensor: SensorSettings, *, progress: bool = False) -> PressSet:
        """The same presses warped and cropped with ``sensor`` (circles mapped along).

        Raw-size images are warped; images already of ``sensor.image_shape``
        are kept only when the set says ``frame = "warped_cropped"``. Circles
        recorded in the raw frame are mapped through the warp, radii scaled by
        its local magnification (square root of the Jacobian determinant).
        """
        raw_shape = (sensor.raw_height_px, sensor.raw_width_px)
        shape = self.reference.shape[:2]
        if shape == sensor.image_shape and self.frame == "warped_cropped":
            return dataclasses.replace(self, warped=True)
        if shape != raw_shape:
            raise CalibrationError(
                f"{self.source}: images are {shape[0]} x {shape[1]}; sensor {sensor.finger!r} expects raw "
                f"{raw_shape[0]} x {raw_shape[1]} frames (or {sensor.image_shape} with frame = 'warped_cropped')"
            )
        images = np.stack([warp_and_crop(im, sensor) for im in tqdm(
            self.images, desc="warping presses", unit="press", disable=not progress)])
        centers, radii = self.centers_px, self.radii_px
        if self.frame == "raw" and centers is not None:
            centers = warp_points(self.centers_px, sensor)
            scale = np.sqrt(np.abs(np.linalg.det(_warp_jacobian(warp_matrix(sensor), self.centers_px))))
            radii = self.radii_px * scale
        return dataclasses.replace(
            self, reference=warp_and_crop(self.reference, sensor), images=images,
            centers_px=centers, radii_px=radii, frame="warped_cropped", warped=True,
        )

    def with_detected_circles(self, *, max_radius_px: float | None = None, progress: bool = False) -> PressSet:
        """The same presses with circles found by :func:`detect_press_circle` in the images."""
        centers, radii = [], []
        for i, image in enumerate(tqdm(self.images, desc="detecting press circles", unit="press",
                                       disable=not progress)):
            try:
                center, radius = detect_press_circle(image, self.reference, max_radius_px=max_radius_px)
            except CalibrationError as exc:
                raise CalibrationError(f"{self.source}: press {i}: {exc}") from exc
            centers.append(center)
            radii.append(radius)
        return dataclasses.replace(
            self, centers_px=np.array(centers), radii_px=np.array(radii), circles="detected",
            frame="warped_cropped" if self.warped else "raw",
        )


def _warp_jacobian(matrix: np.ndarray, points: np.ndarray) -> np.ndarray:
    """(N, 2, 2) Jacobians of the homography at raw points (x, y)."""
    homogeneous = np.column_stack([points, np.ones(len(points))]) @ matrix.T
    w = homogeneous[:, 2:3]
    mapped = homogeneous[:, :2] / w
    # d(u_i)/d(x_j) = (M_ij - u_i * M_2j) / w
    return (matrix[None, :2, :2] - mapped[:, :, None] * matrix[None, 2:3, :2]) / w[:, :, None]


def detect_press_circle(
    image: np.ndarray, reference: np.ndarray, *, blur_px: float = 2.0, threshold: float = 0.5,
    min_change: float = 0.1, max_radius_px: float | None = None,
) -> tuple[tuple[float, float], float]:
    """Find the pressed circle in a ball-press image from its colour change.

    The relative colour change to the reference (Euclidean over B, G, R of
    ``(image - reference) / reference`` after a Gaussian blur, the same
    feature the calibration bins) is thresholded at ``threshold`` times its
    maximum; the largest connected region, holes filled, gives the centre (its
    centroid) and radius (of the circle with its area). This is a starting
    estimate: shadows and the pulled-down gel around the ball bias it, and
    :func:`fit_calibration` re-measures it.

    Parameters
    ----------
    image, reference : ndarray
        uint8 BGR, same shape.
    blur_px : float
        Gaussian sigma, pixels.
    threshold : float
        Fraction of the largest change that belongs to the press.
    min_change : float
        Smallest largest-change (relative) that counts as a visible press.
    max_radius_px : float, optional
        Cap on the returned radius (a contact circle is smaller than the ball).

    Returns
    -------
    ((x, y), radius)
        Pixels.

    Raises
    ------
    CalibrationError
        No relative colour change of at least ``min_change`` (no press visible).
    """
    _check_image("image", image, None, CalibrationError)
    _check_image("reference", reference, image.shape[:2], CalibrationError)
    magnitude = _change_magnitude(image, reference, blur_px)
    peak = float(magnitude.max())
    if peak < min_change:
        raise CalibrationError(
            f"image: no press visible (largest relative colour change {peak:.3f} < {min_change})"
        )
    region = scipy.ndimage.binary_fill_holes(magnitude >= threshold * peak).astype(np.uint8)
    _, _, stats, centroids = cv2.connectedComponentsWithStats(region)
    largest = 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
    radius = math.sqrt(float(stats[largest, cv2.CC_STAT_AREA]) / math.pi)
    if max_radius_px is not None:
        radius = min(radius, max_radius_px)
    cx, cy = (float(v) for v in centroids[largest])
    return (cx, cy), radius


def _change_magnitude(image: np.ndarray, reference: np.ndarray, blur_px: float) -> np.ndarray:
    """Euclidean norm over B, G, R of the relative change ``(image - reference) / reference``, blurred."""
    background = cv2.GaussianBlur(reference.astype(np.float32), (0, 0), blur_px)
    change = cv2.GaussianBlur(image.astype(np.float32), (0, 0), blur_px) - background
    return np.linalg.norm(change / np.maximum(background, 1.0), axis=2)


class PressRings(NamedTuple):
    """Rings of one ball press measured from its colour change, pixels from its centre."""

    contact_px: float
    """Radius of the contact circle: the middle of the ring of largest mean colour change."""
    flat_px: float
    """Where the gel is flat again: the first ring beyond the contact whose mean change is at most
    ``flat_fraction`` of the peak (the end of the profile when none is)."""


def press_rings(
    image: np.ndarray, reference: np.ndarray, center_px: Sequence[float], *, max_radius_px: float,
    blur_px: float = 2.0, flat_fraction: float = 0.1, min_change: float = 0.1,
    marker_mask: np.ndarray | None = None,
) -> PressRings:
    """Contact and flat-gel radii of a ball press around a known centre, from the images alone.

    The relative colour change (the feature the calibration bins, see
    :func:`detect_press_circle`) is averaged over 1 px rings around the
    centre. The gel's slope is largest at the contact edge (it follows the
    ball inside and relaxes outside), and so is the colour change, so the
    ring of largest mean change is the contact circle; this holds whatever
    convention a recorded circle follows and whatever the table has learnt.

    Parameters
    ----------
    image, reference : ndarray
        uint8 BGR, same shape.
    center_px : (float, float)
        Press centre ``(x, y)``, pixels.
    max_radius_px : float
        Largest contact radius searched (below the ball's radius in pixels).
    blur_px : float
        Gaussian sigma of the colour change, pixels.
    flat_fraction : float
        In (0, 1): share of the peak change below which the gel counts as flat.
    min_change : float
        Smallest peak ring-mean relative change that counts as a visible press.
    marker_mask : ndarray of bool, optional
        (H, W) marker-dot pixels, left out of the ring means.

    Returns
    -------
    PressRings
        ``contact_px`` and ``flat_px``, pixels.

    Raises
    ------
    CalibrationError
        An input has the wrong type or shape, or no ring within
        ``max_radius_px`` changes by ``min_change`` (no press visible there).
    """
    _check_image("image", image, None, CalibrationError)
    _check_image("reference", reference, image.shape[:2], CalibrationError)
    center = np.asarray(center_px, dtype=np.float64)
    if center.shape != (2,) or not np.isfinite(center).all():
        raise CalibrationError(f"center_px: expected finite (x, y) pixels, got {center_px!r}")
    if not 0.0 < flat_fraction < 1.0:
        raise CalibrationError(f"flat_fraction: expected a value in (0, 1), got {flat_fraction!r}")
    if not max_radius_px > 3:
        raise CalibrationError(f"max_radius_px: expected more than 3 pixels, got {max_radius_px!r}")
    if marker_mask is not None and (not isinstance(marker_mask, np.ndarray) or marker_mask.dtype != bool
                                    or marker_mask.shape != image.shape[:2]):
        raise CalibrationError(f"marker_mask: expected a bool array of shape {image.shape[:2]}")
    magnitude = _change_magnitude(image, reference, blur_px)
    rows, cols = np.indices(magnitude.shape, dtype=np.float32)
    ring = np.hypot(cols - center[0], rows - center[1]).astype(np.intp).ravel()
    weight = None if marker_mask is None else (~marker_mask).ravel().astype(np.float64)
    counts = np.bincount(ring, weight)
    sums = np.bincount(ring, magnitude.ravel() if weight is None else magnitude.ravel() * weight)
    profile = np.divide(sums, counts, out=np.full(counts.shape, np.nan), where=counts > 0)
    search = profile[2:min(int(max_radius_px), len(profile))]  # the centre rings are a few pixels
    if not np.isfinite(search).any() or np.nanmax(search) < min_change:
        raise CalibrationError(
            f"image: no press visible around ({center[0]:.1f}, {center[1]:.1f}) within "
            f"{max_radius_px:.1f} px (largest ring-mean relative colour change below {min_change})"
        )
    peak_ring = 2 + int(np.nanargmax(search))
    beyond = np.flatnonzero(profile[peak_ring:] <= flat_fraction * profile[peak_ring])
    flat_ring = peak_ring + int(beyond[0]) if beyond.size else len(profile)
    return PressRings(contact_px=peak_ring + 0.5, flat_px=float(flat_ring))


def _fingerprint(reference: np.ndarray, images: Sequence[np.ndarray]) -> str:
    digest = hashlib.sha256(reference.tobytes())
    for image in images:
        digest.update(image.tobytes())
    return digest.hexdigest()


def _read_image(path: Path) -> np.ndarray:
    image = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if image is None:
        raise CalibrationError(f"{path}: not a readable image")
    return image


def load_presses(path: str | Path, *, progress: bool = False) -> PressSet:
    """Read ball presses from a taxim-style dataPack ``.npz`` or a folder of images.

    ``.npz`` members: ``f0`` (no-contact frame), ``imgs`` (N, H, W, 3) uint8,
    ``touch_center`` (N, 2) ``(x, y)`` px, ``touch_radius`` (N,) px; optional
    ``frame`` (``"raw"`` default, or ``"warped_cropped"``) and ``mm_per_px``.
    A folder holds one no-contact image named ``f0*``, ``ref*`` or
    ``background*`` and the press images (any other image file, sorted by
    name); it records no circles (see :meth:`PressSet.with_detected_circles`).
    Optional ``.npz`` members ``mm_per_px`` and ``ball_radius_mm`` are read
    into the set.

    Raises
    ------
    CalibrationError
        The path is missing or unreadable, a member or the reference image is
        missing, or shapes and dtypes do not fit; the message names the file.
    """
    path = Path(path)
    if path.is_dir():
        return _load_folder(path, progress)
    try:
        with np.load(path, allow_pickle=False) as data:
            members = {name: data[name] for name in data.files}
    except FileNotFoundError as exc:
        raise CalibrationError(f"presses {path} do not exist") from exc
    except (OSError, ValueError, EOFError) as exc:
        raise CalibrationError(f"{path}: not a press .npz (or a folder of images): {exc}") from exc
    missing = sorted({"f0", "imgs", "touch_center", "touch_radius"} - set(members))
    if missing:
        raise CalibrationError(f"{path}: missing member(s) {', '.join(missing)} (a taxim-style dataPack needs f0, imgs, touch_center, touch_radius)")
    reference, images = members["f0"], members["imgs"]
    _check_image(f"{path}: f0", reference, None, CalibrationError)
    if images.dtype != np.uint8 or images.ndim != 4 or images.shape[1:] != reference.shape:
        raise CalibrationError(
            f"{path}: imgs: expected uint8 (N, {', '.join(map(str, reference.shape))}), got {images.dtype} {images.shape}"
        )
    frame = str(members.get("frame", "raw"))
    if frame not in ("raw", "warped_cropped"):
        raise CalibrationError(f"{path}: frame = {frame!r}: expected 'raw' or 'warped_cropped'")
    stated = {}
    for name in ("mm_per_px", "ball_radius_mm"):
        if name in members:
            try:
                stated[name] = float(members[name])
            except (TypeError, ValueError) as exc:
                raise CalibrationError(f"{path}: {name} is not a number") from exc
            if not (math.isfinite(stated[name]) and stated[name] > 0):
                raise CalibrationError(f"{path}: {name} = {stated[name]!r}: expected a positive number")
    centers = np.asarray(members["touch_center"], dtype=np.float64)
    radii = np.asarray(members["touch_radius"], dtype=np.float64)
    if centers.shape != (len(images), 2) or radii.shape != (len(images),):
        raise CalibrationError(
            f"{path}: touch_center {centers.shape} / touch_radius {radii.shape} do not match {len(images)} images"
        )
    return PressSet(reference, images, centers, radii, "recorded", frame, stated.get("mm_per_px"),
                    stated.get("ball_radius_mm"), str(path), _fingerprint(reference, images))


def _load_folder(path: Path, progress: bool) -> PressSet:
    files = sorted(p for p in path.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
    references = [p for p in files if REFERENCE_NAME.match(p.name)]
    if len(references) != 1:
        raise CalibrationError(
            f"{path}: expected exactly one no-contact image named f0*, ref* or background*, found "
            f"{[p.name for p in references] or 'none'}"
        )
    press_files = [p for p in files if p != references[0]]
    if not press_files:
        raise CalibrationError(f"{path}: no press images beside {references[0].name}")
    reference = _read_image(references[0])
    images = []
    for file in tqdm(press_files, desc="reading presses", unit="image", disable=not progress):
        image = _read_image(file)
        if image.shape != reference.shape:
            raise CalibrationError(f"{file}: {image.shape} differs from the reference's {reference.shape}")
        images.append(image)
    stack = np.stack(images)
    return PressSet(reference, stack, None, None, "none", "raw", None, None, str(path),
                    _fingerprint(reference, stack))
