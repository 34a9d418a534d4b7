"""Perspective warp of a raw tactile camera frame onto the gel's rectangle, then crop.

A GelSight Wedge looks at its gel through a mirror, so the gel appears as a
quadrilateral in the raw 640x480 frame. The sensor's mirror-corner calibration
(:attr:`~teleop.settings.SensorSettings.warp_corners_px`: top-left, top-right,
bottom-left, bottom-right, raw pixels, x right and y down) maps onto the
corners of a ``warped_width_px`` x ``warped_height_px`` rectangle, and
``crop_px`` is then removed from every side. The estimator works in that
warped-and-cropped pixel frame (:attr:`~teleop.settings.SensorSettings.image_shape`).

The warp is a fixed lookup per sensor geometry, so it is tabulated once
(:func:`warp_maps`: the raw position of every pixel that survives the crop, in
OpenCV's fixed-point remap format) and each frame is only resampled with
``cv2.remap``, about twice as fast as ``cv2.warpPerspective`` re-deriving the
positions per frame.

With ``binning`` K the same warp lands on a K times coarser grid (each output pixel
standing for a K x K block of the warped-and-cropped image) from a raw frame decoded K
times smaller: the estimator's binned depth grid (:mod:`estimator.perception.grid`).
"""

from __future__ import annotations

import functools

import cv2
import numpy as np

from estimator.errors import PerceptionError
from estimator.settings import depth_binning_problem
from teleop.errors import SettingsError
from teleop.geometry import raw_to_grid_matrix
from teleop.settings import SensorSettings

__all__ = ["check_binning", "check_raw_frame", "warp_and_crop", "warp_maps", "warp_matrix", "warp_points"]


def warp_matrix(sensor: SensorSettings) -> np.ndarray:
    """Homography from raw camera pixels to the warped-and-cropped image
    (:func:`teleop.geometry.raw_to_grid_matrix`).

    Parameters
    ----------
    sensor : SensorSettings
        Supplies the mirror corners (TL, TR, BL, BR in raw px), the warped size
        and the crop.

    Returns
    -------
    ndarray
        3 x 3 float64, read-only (cached per sensor). A raw point ``(x, y, 1)``
        maps to ``M @ (x, y, 1)`` in cropped pixels after division by the last
        coordinate. The corners land on ``(0, 0)``, ``(W, 0)``, ``(0, H)`` and
        ``(W, H)`` of the warped image, so the crop shifts them by ``-crop_px``.

    Raises
    ------
    PerceptionError
        The corners do not form a quadrilateral.
    """
    try:
        return raw_to_grid_matrix(sensor)
    except SettingsError as exc:
        raise PerceptionError(str(exc)) from exc


def check_binning(sensor: SensorSettings | None, binning: int, *,
                  grid_shape: tuple[int, int] | None = None) -> None:
    """Raise PerceptionError where :func:`~estimator.settings.depth_binning_problem` refuses
    ``binning`` for ``sensor`` (its image grid, raw frame and markers) or ``grid_shape``."""
    problem = depth_binning_problem(binning, sensor, grid_shape=grid_shape)
    if problem:
        raise PerceptionError(f"binning {binning!r}: {problem}")


def check_raw_frame(image: object, sensor: SensorSettings, *, binning: int, name: str) -> None:
    """PerceptionError naming ``name`` unless ``image`` is a uint8 BGR frame of ``sensor``'s raw size
    decoded ``binning`` times smaller; the message gives the size the frame was captured at."""
    expected = (sensor.raw_height_px // binning, sensor.raw_width_px // binning, 3)
    if isinstance(image, np.ndarray) and image.dtype == np.uint8 and image.shape == expected:
        return
    got = f"{image.dtype} {image.shape}" if isinstance(image, np.ndarray) else type(image).__name__
    if binning > 1 and isinstance(image, np.ndarray) and image.ndim >= 2:  # name the frame as captured
        got += (f", binned from a frame of about {image.shape[1] * binning}x{image.shape[0] * binning} px "
                f"for the sensor's {sensor.raw_width_px}x{sensor.raw_height_px}")
    raise PerceptionError(f"{name}: expected a uint8 BGR frame of shape {expected} (sensor {sensor.finger!r}"
                          f"{f', binning {binning}' if binning > 1 else ''}), got {got}")


@functools.lru_cache(maxsize=32)
def warp_maps(sensor: SensorSettings, binning: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Fixed-point ``cv2.remap`` maps of the warp-and-crop, cached per sensor and binning.

    Parameters
    ----------
    sensor : SensorSettings
        Supplies the warp (see :func:`warp_matrix`) and ``image_shape``.
    binning : int
        Output grid ``binning`` times coarser than ``image_shape``, read from a raw
        frame ``binning`` times smaller (both must divide by it).

    Returns
    -------
    xy, fraction : ndarray
        OpenCV's ``CV_16SC2`` / ``CV_16UC1`` pair (read-only), shape
        ``image_shape // binning``: the integer raw pixel ``(x, y)`` of every output pixel
        and its sub-pixel position in 1/32 px (``cv2.convertMaps`` of the raw
        positions, computed in float64). A binned pixel samples the warp at the centre of
        its block, in the reduced raw frame (pixel centres at ``(i + 0.5) * binning - 0.5``
        of the full one).

    Raises
    ------
    PerceptionError
        ``binning`` does not divide the image grid and the raw frame, or is above 1 for a
        sensor with markers (:func:`check_binning`).
    """
    check_binning(sensor, binning)
    rows, cols = (side // binning for side in sensor.image_shape)
    centre = (binning - 1) / 2.0  # of a block, in full-grid pixels
    x_out, y_out = np.meshgrid(np.arange(cols, dtype=np.float64) * binning + centre,
                               np.arange(rows, dtype=np.float64) * binning + centre)
    out_points = np.stack([x_out, y_out], axis=-1).reshape(1, -1, 2)
    raw = cv2.perspectiveTransform(out_points, np.linalg.inv(warp_matrix(sensor)))[0]
    if binning > 1:
        raw = (raw + 0.5) / binning - 0.5
    xy, fraction = cv2.convertMaps(raw.astype(np.float32).reshape(rows, cols, 2), None, cv2.CV_16SC2)
    xy.setflags(write=False)
    fraction.setflags(write=False)
    return xy, fraction


def warp_and_crop(raw_bgr: np.ndarray, sensor: SensorSettings, *, binning: int = 1) -> np.ndarray:
    """Warp a raw camera frame onto the gel rectangle and crop its border.

    Parameters
    ----------
    raw_bgr : ndarray
        uint8, shape ``(raw_height_px, raw_width_px, 3) // binning``, BGR as captured
        (decoded ``binning`` times smaller).
    sensor : SensorSettings
        The sensor that took the frame.
    binning : int
        Land on the ``binning`` times coarser grid (:func:`warp_maps`).

    Returns
    -------
    ndarray
        uint8, shape ``sensor.image_shape // binning + (3,)``, bilinear interpolation at
        1/32 px (as ``cv2.warpPerspective``) through the cached :func:`warp_maps`;
        pixels that map outside the raw frame are black.

    Raises
    ------
    PerceptionError
        ``raw_bgr`` is not a uint8 BGR image of the sensor's raw size over ``binning``, or
        ``binning`` does not divide it.
    """
    xy, fraction = warp_maps(sensor, binning)
    check_raw_frame(raw_bgr, sensor, binning=binning, name="raw_bgr")
    return cv2.remap(raw_bgr, xy, fraction, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)


def warp_points(points_px: np.ndarray, sensor: SensorSettings) -> np.ndarray:
    """Map raw-pixel points ``(x, y)`` into the warped-and-cropped frame.

    Parameters
    ----------
    points_px : array_like
        Shape ``(N, 2)``, raw pixel coordinates, x right and y down.
    sensor : SensorSettings
        The sensor whose warp applies.

    Returns
    -------
    ndarray
        float64, shape ``(N, 2)``, cropped-image pixel coordinates.
    """
    points = np.asarray(points_px, dtype=np.float64)
    if points.ndim != 2 or points.shape[1] != 2:
        raise PerceptionError(f"points_px: expected shape (N, 2), got {points.shape}")
    return cv2.perspectiveTransform(points[None], warp_matrix(sensor))[0]
