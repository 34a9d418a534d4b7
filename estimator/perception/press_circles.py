"""Ball-press circles measured from the colour change alone: a first guess and the rings.

:func:`detect_press_circle` finds a press's circle where no annotation gives one;
:func:`press_rings` measures the contact and flat-gel radii around a known centre.
How :func:`~estimator.perception.calibration_fit.fit_calibration` uses both is in
its module notes ("Recorded press circles").
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import NamedTuple

import cv2
import numpy as np
import scipy.ndimage

from estimator.errors import CalibrationError
from estimator.perception.calibration import _check_image

__all__ = ["CLIPPED_SHARE", "VISIBLE_CHANGE", "PressRings", "change_inside_circle", "clipped_presses",
           "clipped_share", "detect_press_circle", "press_rings"]

# The smallest largest relative colour change that counts as a visible press (real presses: 0.45 and up).
VISIBLE_CHANGE = 0.1
# An image with a channel clipped at 0 or 255 over more than this share of its pixels shows no gel's
# colours there (overexposed or dark: real presses clip none); a table fitted on it reads every press wrong.
CLIPPED_SHARE = 0.5


def detect_press_circle(
    image: np.ndarray, reference: np.ndarray, *, blur_px: float = 2.0, threshold: float = 0.5,
    min_change: float = VISIBLE_CHANGE, max_radius_px: float | None = None,
) -> tuple[tuple[float, float], float]:
    """Find the pressed circle in a ball-press image from its colour change.

    The relative colour change to the reference (Euclidean over B, G, R of
    ``(image - reference) / reference`` after a Gaussian blur, the same
    feature the calibration bins) is thresholded at ``threshold`` times its
    maximum; the largest connected region, holes filled, gives the centre (its
    centroid) and radius (of the circle with its area). This is a starting
    estimate: shadows and the pulled-down gel around the ball bias it, and
    :func:`~estimator.perception.calibration_fit.fit_calibration` re-measures it.

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


def change_inside_circle(image: np.ndarray, reference: np.ndarray, center_px: tuple[float, float],
                         radius_px: float, *, blur_px: float = 2.0) -> float:
    """The largest relative colour change of ``image`` against ``reference`` within the circle (0 when
    the circle covers no pixel): below ``VISIBLE_CHANGE``, the circle holds no press."""
    magnitude = _change_magnitude(image, reference, blur_px)
    rows, cols = np.ogrid[: magnitude.shape[0], : magnitude.shape[1]]
    inside = (cols - center_px[0]) ** 2 + (rows - center_px[1]) ** 2 <= radius_px**2
    return float(magnitude[inside].max()) if inside.any() else 0.0


def clipped_share(image: np.ndarray) -> float:
    """Share of the pixels of uint8 BGR ``image`` with a channel clipped at 0 or 255."""
    clipped = ((image == 0) | (image == 255)).any(axis=-1)
    return float(np.count_nonzero(clipped)) / clipped.size


def clipped_presses(images: Sequence[np.ndarray], indices: Sequence[int]) -> str:
    """Why presses ``images`` (numbered ``indices``) cannot calibrate: those with a channel clipped over
    more than :data:`CLIPPED_SHARE` of their pixels, each as ``index (share)``; '' when none is."""
    clipped = [(int(i), share) for i, image in zip(indices, images, strict=True)
               if (share := clipped_share(image)) > CLIPPED_SHARE]
    if not clipped:
        return ""
    listed = ", ".join(f"{i} ({share:.0%})" for i, share in clipped[:5]) + (", ..." if len(clipped) > 5 else "")
    return (f"{len(clipped)} of the {len(indices)} presses to calibrate on are clipped at 0 or 255 over most of "
            f"the image, overexposed or dark (press index, share of pixels with a channel clipped; expected at "
            f"most {CLIPPED_SHARE:.0%}): {listed}")


class PressRings(NamedTuple):
    """Rings of one ball press measured from its colour change, pixels from its centre."""

    contact_px: float
    """Radius of the contact circle: the middle of the ring of largest mean colour change."""
    flat_px: float
    """Where the gel is flat again: the first ring beyond the contact whose mean change is at most
    ``flat_fraction`` of the peak (the end of the profile when none is)."""


def press_rings(
    image: np.ndarray, reference: np.ndarray, center_px: Sequence[float], *, max_radius_px: float,
    blur_px: float = 2.0, flat_fraction: float = 0.1, min_change: float = VISIBLE_CHANGE,
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
