"""Where a simulated tactile camera looks: its raw pixels and the sensor's grid.

Frames
------
The mechanics work on the *grid*: the image the estimator sees, ``sensor.image_shape``
= (rows, cols) pixels of ``sensor.pixel_pitch_m``, x (columns) to the right, y (rows)
down, z toward the camera. The camera sees the *raw* frame (``raw_height_px`` x
``raw_width_px``, 480 x 640). :func:`pad_view` relates the two. A Wedge
(``model = "wedge"``) sees its pad in a mirror: the mirror-corner homography
(:func:`~teleop.geometry.raw_to_warped_matrix`: the raw corners TL, TR, BL, BR go to
the corners of the ``warped_width_px`` x ``warped_height_px`` image), after which
``crop_px`` pixels are cut from every side (250 x 350). A flat sensor
(``model = "mini"``) looks straight at its gel: the raw frame is the grid, unwarped
and uncropped, as the estimator reads it (:func:`estimator.perception.grid.to_grid`);
its corners, warped size and crop are not read.

:func:`warp_to_grid` takes a raw frame to the grid. The renderers
(:mod:`teleop.sim.optics`) go the other way: each raw pixel of the pad
(:func:`raw_footprint`) samples warped-image fields (the uncropped grid, of
:func:`pad_view`'s size) where it sees them (:func:`sample_warped`).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import cv2
import numpy as np

from teleop.errors import SimulationError
from teleop.geometry import raw_to_warped_matrix
from teleop.settings import SensorSettings

__all__ = [
    "PadView",
    "pad_view",
    "raw_footprint",
    "read_only",
    "sample_warped",
    "warp_to_grid",
    "warped_coordinates",
]


@dataclass(frozen=True, eq=False)
class PadView:
    """How a sensor's camera sees its pad: the warped image and the homography to it.

    Attributes
    ----------
    width_px, height_px : int
        Size of the warped (uncropped) image.
    crop_px : int
        Pixels cut from every side of the warped image to give the grid.
    raw_to_warped : ndarray, shape (3, 3), float64
        Homography from raw pixels to the warped image (read-only).
    mirrored : bool
        Whether the camera sees the pad in a mirror (a Wedge); else the raw frame is the
        grid and the homography the identity.
    """

    width_px: int
    height_px: int
    crop_px: int
    raw_to_warped: np.ndarray
    mirrored: bool


@functools.lru_cache(maxsize=8)
def pad_view(sensor: SensorSettings) -> PadView:
    """The :class:`PadView` of ``sensor``: its mirror corners, warped size and crop for a Wedge;
    the identity for a flat sensor (``model = "mini"``), whose raw frame is its grid.

    Raises
    ------
    SettingsError
        A Wedge's corners do not form a quadrilateral.
    """
    if sensor.model == "mini":
        return PadView(sensor.raw_width_px, sensor.raw_height_px, 0, read_only(np.eye(3)), mirrored=False)
    return PadView(sensor.warped_width_px, sensor.warped_height_px, sensor.crop_px,
                   raw_to_warped_matrix(sensor), mirrored=True)


def warp_to_grid(raw: np.ndarray, sensor: SensorSettings) -> np.ndarray:
    """Warp a raw frame to the warped image and crop it to the grid (a flat sensor's: a copy).

    Parameters
    ----------
    raw : ndarray, shape (raw_height_px, raw_width_px[, C])
        Raw camera frame, any dtype OpenCV warps (dtype is kept).
    sensor : SensorSettings
        Supplies the :func:`pad_view`.

    Returns
    -------
    ndarray, shape sensor.image_shape (+ channels)
        Bilinear resampling; same dtype as ``raw``.
    """
    if raw.shape[:2] != (sensor.raw_height_px, sensor.raw_width_px):
        raise SimulationError(
            f"raw frame has shape {raw.shape}: expected "
            f"({sensor.raw_height_px}, {sensor.raw_width_px}[, channels]) for sensor {sensor.finger!r}"
        )
    view = pad_view(sensor)
    if not view.mirrored:
        return raw.copy()
    warped = cv2.warpPerspective(raw, view.raw_to_warped, (view.width_px, view.height_px),
                                 flags=cv2.INTER_LINEAR)
    c = view.crop_px
    return warped[c:warped.shape[0] - c, c:warped.shape[1] - c]


def warped_coordinates(sensor: SensorSettings) -> tuple[np.ndarray, np.ndarray]:
    """Pixel-centre coordinates (x, y) of the full warped image, float32 (H, W) each."""
    view = pad_view(sensor)
    return np.meshgrid(np.arange(view.width_px, dtype=np.float32), np.arange(view.height_px, dtype=np.float32))


def read_only(array: np.ndarray) -> np.ndarray:
    """Cached arrays are shared by every camera of a sensor: forbid writes."""
    array.flags.writeable = False
    return array


@functools.lru_cache(maxsize=8)
def raw_footprint(sensor: SensorSettings) -> tuple[tuple[slice, slice], np.ndarray, np.ndarray]:
    """The raw pixels that see the warped image: their bounding box and warped coordinates.

    Returns
    -------
    box : (slice, slice)
        Rows and columns of the raw frame holding every pixel within one warped
        pixel of the warped image.
    map_x, map_y : ndarray, float32, the box's shape
        Warped (x, y) of each raw pixel centre in the box, for ``cv2.remap``.
    """
    view = pad_view(sensor)
    w, h = view.width_px, view.height_px
    to_raw = np.linalg.inv(view.raw_to_warped)
    reach = np.array([[[-1.0, -1.0]], [[w, -1.0]], [[-1.0, h]], [[w, h]]])
    corners = cv2.perspectiveTransform(reach, to_raw)[:, 0]
    x0, y0 = np.maximum(np.floor(corners.min(axis=0)).astype(int), 0)
    x1 = min(int(np.ceil(corners[:, 0].max())) + 1, sensor.raw_width_px)
    y1 = min(int(np.ceil(corners[:, 1].max())) + 1, sensor.raw_height_px)
    xs, ys = np.meshgrid(np.arange(x0, x1, dtype=np.float64), np.arange(y0, y1, dtype=np.float64))
    warped = cv2.perspectiveTransform(np.dstack([xs, ys]), view.raw_to_warped).astype(np.float32)
    return ((slice(y0, y1), slice(x0, x1)), read_only(np.ascontiguousarray(warped[..., 0])),
            read_only(np.ascontiguousarray(warped[..., 1])))


def sample_warped(field: np.ndarray, map_x: np.ndarray, map_y: np.ndarray) -> np.ndarray:
    """Bilinear samples of a warped-image ``field`` at raw pixels; zero beyond the field."""
    return cv2.remap(field, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0.0)
