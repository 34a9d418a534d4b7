"""Marker dots printed on the gel: find them and paint them out before the colour lookup.

Markers are small dark dots whose colour says nothing about the surface
slope. They move with the gel, so a frame and its no-contact reference show
them in different places and the colour difference is wrong at both; the
mask therefore covers the dots of both images.
"""

from __future__ import annotations

from numbers import Integral, Real

import cv2
import numpy as np

from estimator.errors import PerceptionError

__all__ = ["detect_markers", "inpaint_markers"]

# Sizes in pixels are bounded by the image's larger side, or by this (the default dot size) on
# smaller images: a dot or a rim cannot be wider than the image, and OpenCV's kernels grow with
# the square of the size.
_MIN_SIZE_LIMIT_PX = 11


def _check_bgr(name: str, image: np.ndarray, shape: tuple[int, ...] | None = None) -> None:
    if not isinstance(image, np.ndarray) or image.dtype != np.uint8 or image.ndim != 3 or image.shape[2] != 3:
        got = f"{image.dtype} {image.shape}" if isinstance(image, np.ndarray) else type(image).__name__
        raise PerceptionError(f"{name}: expected a uint8 BGR image (H, W, 3), got {got}")
    if 0 in image.shape[:2]:
        raise PerceptionError(f"{name}: expected a uint8 BGR image (H, W, 3) with H, W >= 1, got {image.shape}")
    if shape is not None and image.shape != shape:
        raise PerceptionError(f"{name}: expected shape {shape}, got {image.shape}")


def _size_px(name: str, value: object, *, lowest: int, limit: int) -> int:
    """``value`` as an int in ``[lowest, limit]`` (a numpy integer too, a bool not), else PerceptionError."""
    if not (isinstance(value, Integral) and not isinstance(value, bool) and lowest <= value <= limit):
        raise PerceptionError(f"{name}: expected an integer number of pixels in [{lowest}, {limit}] "
                              f"(at most the image's larger side, or {_MIN_SIZE_LIMIT_PX}), got {value!r}")
    return int(value)


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
        Largest dot diameter, pixels (>= 1); darker features wider than this are kept.
    min_darkness : float
        Relative darkening, in (0, 1), that marks a dot pixel.
    dilate_px : int
        Grow the mask by this many pixels (>= 0) to cover the dots' soft rims.

    Both sizes are at most ``max(H, W)`` (or 11 when the image is smaller).

    Returns
    -------
    ndarray of bool
        Shape (H, W); True where either image shows a dot.

    Raises
    ------
    PerceptionError
        An image is not a non-empty uint8 BGR image, the shapes differ, or an
        option is not a number in its range.
    """
    _check_bgr("frame", frame)
    _check_bgr("reference", reference, frame.shape)
    limit = max(frame.shape[0], frame.shape[1], _MIN_SIZE_LIMIT_PX)
    max_diameter_px = _size_px("max_diameter_px", max_diameter_px, lowest=1, limit=limit)
    if not (isinstance(min_darkness, Real) and not isinstance(min_darkness, bool) and 0.0 < min_darkness < 1.0):
        raise PerceptionError(f"min_darkness: expected a number in (0, 1), got {min_darkness!r}")
    dilate_px = _size_px("dilate_px", dilate_px, lowest=0, limit=limit)
    # The smallest odd size wider than a dot: an odd disc is centred on its anchor, so the closing
    # never darkens a pixel and reaches dots at the image border.
    size = max_diameter_px + 1 + max_diameter_px % 2
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
        uint8 BGR (H, W, 3), or a single-channel uint8 or float32 (H, W) image;
        H, W >= 1.
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
    if 0 in frame.shape[:2]:
        raise PerceptionError(f"frame: expected an image with H, W >= 1, got shape {frame.shape}")
    if not isinstance(mask, np.ndarray) or mask.dtype != bool or mask.shape != frame.shape[:2]:
        got = f"{mask.dtype} {mask.shape}" if isinstance(mask, np.ndarray) else type(mask).__name__
        raise PerceptionError(f"mask: expected a bool array of shape {frame.shape[:2]}, got {got}")
    if not radius_px > 0:
        raise PerceptionError(f"radius_px: expected a positive number, got {radius_px!r}")
    return cv2.inpaint(frame, mask.view(np.uint8), radius_px, cv2.INPAINT_TELEA)
