"""Marker dots printed on the gel: find them and paint them out before the colour lookup.

Markers are small dark dots whose colour says nothing about the surface
slope. They move with the gel, so a frame and its no-contact reference show
them in different places and the colour difference is wrong at both; the
mask therefore covers the dots of both images.
"""

from __future__ import annotations

import cv2
import numpy as np

from estimator.errors import PerceptionError

__all__ = ["detect_markers", "inpaint_markers"]


def _check_bgr(name: str, image: np.ndarray, shape: tuple[int, ...] | None = None) -> None:
    if not isinstance(image, np.ndarray) or image.dtype != np.uint8 or image.ndim != 3 or image.shape[2] != 3:
        got = f"{image.dtype} {image.shape}" if isinstance(image, np.ndarray) else type(image).__name__
        raise PerceptionError(f"{name}: expected a uint8 BGR image (H, W, 3), got {got}")
    if shape is not None and image.shape != shape:
        raise PerceptionError(f"{name}: expected shape {shape}, got {image.shape}")


def _dark_dots(image: np.ndarray, kernel: np.ndarray, min_darkness: float, max_diameter_px: int) -> np.ndarray:
    """Dot-shaped blobs darker than their closed (dot-free) surroundings by ``min_darkness``.

    Dark blobs that do not fit a ``max_diameter_px`` box or fill less than
    half of their bounding box (the dark rim of a press, a scratch) are not dots.
    """
    gray = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    background = cv2.morphologyEx(gray, cv2.MORPH_CLOSE, kernel)
    # gray <= background by construction; compare in float to keep the ratio exact.
    dark = ((background.astype(np.float32) - gray) > min_darkness * np.maximum(background, 1)).view(np.uint8)
    _, labels, stats, _ = cv2.connectedComponentsWithStats(dark, connectivity=8)
    width, height = stats[:, cv2.CC_STAT_WIDTH], stats[:, cv2.CC_STAT_HEIGHT]
    dot = (np.maximum(width, height) <= max_diameter_px) & (stats[:, cv2.CC_STAT_AREA] >= 0.5 * width * height)
    dot[0] = False  # background label
    return dot[labels]


def detect_markers(
    frame: np.ndarray,
    reference: np.ndarray,
    *,
    max_diameter_px: int = 11,
    min_darkness: float = 0.2,
    dilate_px: int = 1,
) -> np.ndarray:
    """Mask of marker-dot pixels in a frame or in its no-contact reference.

    A morphological closing with a disc wider than the dots fills them in and
    leaves broader shading alone; pixels darker than that closed image by more
    than ``min_darkness`` of its brightness form candidate blobs, and blobs
    that fit within ``max_diameter_px`` and fill at least half of their
    bounding box are dots.

    Parameters
    ----------
    frame, reference : ndarray
        uint8 BGR, same shape (H, W, 3), same pixel frame.
    max_diameter_px : int
        Largest dot diameter, pixels; darker features wider than this are kept.
    min_darkness : float
        Relative darkening, in (0, 1), that marks a dot pixel.
    dilate_px : int
        Grow the mask by this many pixels to cover the dots' soft rims.

    Returns
    -------
    ndarray of bool
        Shape (H, W); True where either image shows a dot.
    """
    _check_bgr("frame", frame)
    _check_bgr("reference", reference, frame.shape)
    if not (isinstance(max_diameter_px, int) and max_diameter_px >= 1):
        raise PerceptionError(f"max_diameter_px: expected a positive integer, got {max_diameter_px!r}")
    if not 0.0 < min_darkness < 1.0:
        raise PerceptionError(f"min_darkness: expected a value in (0, 1), got {min_darkness!r}")
    if not (isinstance(dilate_px, int) and dilate_px >= 0):
        raise PerceptionError(f"dilate_px: expected a non-negative integer, got {dilate_px!r}")
    size = max_diameter_px + 2 - max_diameter_px % 2  # odd, wider than a dot
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (size, size))
    mask = (_dark_dots(frame, kernel, min_darkness, max_diameter_px)
            | _dark_dots(reference, kernel, min_darkness, max_diameter_px))
    if dilate_px:
        grow = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * dilate_px + 1, 2 * dilate_px + 1))
        mask = cv2.dilate(mask.view(np.uint8), grow).view(bool)
    return mask


def inpaint_markers(frame: np.ndarray, mask: np.ndarray, *, radius_px: float = 2.0) -> np.ndarray:
    """Fill masked pixels from their surroundings (``cv2.inpaint``, Telea's method).

    Parameters
    ----------
    frame : ndarray
        uint8 BGR (H, W, 3), or a single-channel uint8 or float32 (H, W) image.
    mask : ndarray of bool
        Shape (H, W); True where to fill.
    radius_px : float
        Neighbourhood radius considered around each filled pixel.

    Returns
    -------
    ndarray
        A new image, same shape and dtype as ``frame``.
    """
    if not isinstance(frame, np.ndarray) or not (
        (frame.dtype == np.uint8 and (frame.ndim == 2 or (frame.ndim == 3 and frame.shape[2] == 3)))
        or (frame.dtype == np.float32 and frame.ndim == 2)
    ):
        got = f"{frame.dtype} {frame.shape}" if isinstance(frame, np.ndarray) else type(frame).__name__
        raise PerceptionError(
            f"frame: expected uint8 BGR (H, W, 3) or a uint8/float32 (H, W) image, got {got}"
        )
    if not isinstance(mask, np.ndarray) or mask.dtype != bool or mask.shape != frame.shape[:2]:
        got = f"{mask.dtype} {mask.shape}" if isinstance(mask, np.ndarray) else type(mask).__name__
        raise PerceptionError(f"mask: expected a bool array of shape {frame.shape[:2]}, got {got}")
    if not radius_px > 0:
        raise PerceptionError(f"radius_px: expected a positive number, got {radius_px!r}")
    return cv2.inpaint(frame, mask.view(np.uint8), radius_px, cv2.INPAINT_TELEA)
