"""The mirror-corner homography of a tactile sensor: raw camera pixels to its image grid.

A GelSight Wedge sees its gel through a mirror, so the gel appears as a quadrilateral in
the raw frame. :attr:`~teleop.settings.SensorSettings.warp_corners_px` (top-left,
top-right, bottom-left, bottom-right, raw px, x right and y down) map onto the corners
``(0, 0)``, ``(W, 0)``, ``(0, H)``, ``(W, H)`` of the ``warped_width_px`` x
``warped_height_px`` warped image (the GelSight SDK convention); ``crop_px`` is then cut
from every side, leaving the grid (:attr:`~teleop.settings.SensorSettings.image_shape`).

The one computation of it: the simulator renders through it
(:mod:`teleop.sim.camera_geometry`) and the estimator warps captured frames with it
(:mod:`estimator.perception.warp`).
"""

from __future__ import annotations

import functools

import cv2
import numpy as np

from teleop.errors import SettingsError
from teleop.settings import SensorSettings

__all__ = ["raw_to_grid_matrix", "raw_to_warped_matrix"]


@functools.lru_cache(maxsize=32)
def raw_to_warped_matrix(sensor: SensorSettings) -> np.ndarray:
    """Homography from raw camera pixels to the warped (uncropped) image.

    Returns
    -------
    ndarray, shape (3, 3), float64
        Read-only, one per sensor (cached); for ``cv2.warpPerspective(raw, M, (W, H))``.
        A raw point ``(x, y, 1)`` maps to ``M @ (x, y, 1)`` after division by the last
        coordinate.

    Raises
    ------
    SettingsError
        The corners do not form a quadrilateral (three on one line, say).
    """
    width, height = sensor.warped_width_px, sensor.warped_height_px
    src = np.asarray(sensor.warp_corners_px, dtype=np.float32)
    dst = np.array([[0, 0], [width, 0], [0, height], [width, height]], dtype=np.float32)
    singular = SettingsError(
        f"sensor {sensor.finger!r}: warp_corners_px {sensor.warp_corners_px} do not form a "
        "quadrilateral (three corners on one line?)"
    )
    try:
        matrix = cv2.getPerspectiveTransform(src, dst)
    except cv2.error as exc:
        raise singular from exc
    # OpenCV returns a meaningless matrix rather than failing on degenerate corners.
    mapped = cv2.perspectiveTransform(src[None].astype(np.float64), matrix)[0]
    if not (np.isfinite(mapped).all() and np.allclose(mapped, dst, atol=1e-3)):
        raise singular
    matrix.setflags(write=False)
    return matrix


@functools.lru_cache(maxsize=32)
def raw_to_grid_matrix(sensor: SensorSettings) -> np.ndarray:
    """Homography from raw camera pixels to the warped-and-cropped grid: :func:`raw_to_warped_matrix`
    followed by the crop, which shifts every point by ``-crop_px`` (read-only, cached per sensor).
    Raises SettingsError as :func:`raw_to_warped_matrix` does."""
    crop = sensor.crop_px
    shift = np.array([[1.0, 0.0, -crop], [0.0, 1.0, -crop], [0.0, 0.0, 1.0]])
    matrix = shift @ raw_to_warped_matrix(sensor)
    matrix.setflags(write=False)
    return matrix
