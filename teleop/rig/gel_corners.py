"""The gel's quadrilateral in a raw no-contact frame: a Wedge's mirror corners, measured.

A GelSight Wedge sees its lit gel through a mirror, a bright quadrilateral on the dark
housing of the raw frame (:mod:`teleop.geometry`). :func:`find_gel_corners` finds it:

1. the brightest channel of each pixel, closed over marker dots and dust and thresholded
   (Otsu), gives bright regions; the gel is the brightest large one (the Wedge's second
   mirror view beside it is dimmer), and must lie wholly inside the frame. Its contrast is
   the median brightness of a band just inside its border minus that of a band just outside
   it (morphological rings), so it holds whatever the border's shape;
2. its convex hull, simplified (``cv2.approxPolyDP``) to four corners, splits its outline into
   four sides, each roughly a line through the outline's points along it (away from the
   rounded corners);
3. each side is measured again to sub-pixel: the edge's position (the steepest rise of
   brightness, interpolated) along many short profiles across it, and a robust curve through
   them, a line plus a bow (a parabola), measured a second time across that curve. A
   wide-angle lens bows straight sides outward (the reference Wedge frame's left side by 12 px
   over 380, 3 %), so a line through a whole side would miss its ends by several pixels;
   adjacent sides' curves meet at the outline's corners.

The outline is the border of the lit region, which covers the warped image's pixels from the
outer edge of the first to the outer edge of the last: warped ``-0.5`` to ``W - 0.5``
in pixel-centre coordinates. :attr:`~teleop.settings.SensorSettings.warp_corners_px`
are the raw points of warped ``(0, 0)`` and ``(W, H)`` (:func:`teleop.geometry.raw_to_warped_matrix`),
so the corners returned are the outline's mapped through that half-pixel shift: half a
warped pixel inward at the top-left, outward at the bottom-right.

On a real Wedge the lit region takes in a rim around the gel: in the reference frame a band
about 20 px wide along the top, right and bottom, as bright as the gel but without the LEDs'
colour (a grey bezel on the right). The published calibration, clicked by hand, puts its corners
inside that rim, where the colour begins; no edge marks that line along a whole side (the
colour step fades toward the corners, and on the right there is none), so it cannot be told
apart from the gel's own shading, and the corners found here frame the lit region, rim and all.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import cv2
import numpy as np
from numpy.polynomial import polynomial

from teleop.errors import TeleopError

__all__ = ["CornerFit", "draw_corners", "find_gel_corners"]

CORNER_NAMES = ("top-left", "top-right", "bottom-left", "bottom-right")
SIDE_NAMES = ("top", "right", "bottom", "left")
# Profiles across each side: how far out and in they reach (raw px; past a rough line's distance
# from a bowed side), and how many per side.
PROFILE_HALF_PX = 10.0
PROFILES_PER_SIDE = 60
DOT_KERNEL_PX = 15  # wider than a marker dot or a speck of dust
MIN_EDGE_SHARE = 0.7  # of a side's profiles must find its edge, on its curve
SIDE_MARGIN = 0.12  # of a side's length next to each corner, where the outline rounds off
ROUGH_REACH = 0.15  # of a side's length: how far from its chord the outline's points along it may lie
OUTLIER_PX = 2.0  # an edge point farther than this from its side's curve is not on it
CORNER_EPSILON = 0.04  # of the outline's length: how far it may stray from its four-corner polygon (bows, cut corners)
CONTRAST_BAND_PX = (3, 10)  # the bands inside and outside the border whose brightness is compared


@dataclass(frozen=True)
class CornerFit:
    """The gel's corners found in a raw frame, or (falsy) why not.

    Attributes
    ----------
    corners_px : ndarray or None
        (4, 2) float64 raw pixels ``(x, y)``, x right and y down, in the order of
        ``warp_corners_px``: top-left, top-right, bottom-left, bottom-right.
    outline_px : ndarray or None
        (4, 2) the gel's border at those corners (before the half-pixel shift).
    edge_rms_px : float
        Root-mean-square distance of the measured edge points to their side's curve.
    contrast : float
        Median brightness (8-bit levels) just inside the gel's border minus just outside it.
    bow_px : float
        The bow (raw px) of the side most bowed for its length: how far its middle lies from the
        straight line between its corners, outward positive (a wide-angle lens bows sides outward).
    reason : str
        Empty when found; otherwise what was wrong, for a person.
    """

    corners_px: np.ndarray | None = None
    outline_px: np.ndarray | None = None
    edge_rms_px: float = float("nan")
    contrast: float = float("nan")
    bow_px: float = float("nan")
    reason: str = ""

    def __bool__(self) -> bool:
        return not self.reason

    def as_settings(self) -> list[list[float]]:
        """The corners as ``warp_corners_px`` holds them, rounded to 0.1 px."""
        return [[round(float(x), 1), round(float(y), 1)] for x, y in self.corners_px]


class _Side(NamedTuple):
    """A side from ``start`` to ``end`` (rough corners), bowed: its point at ``t`` (0 at ``start``,
    1 at ``end``) is ``start + t (end - start) + offset(t) inward``, ``offset`` a polynomial in ``t``
    (its coefficients, lowest degree first)."""

    start: np.ndarray
    end: np.ndarray
    inward: np.ndarray
    offset: np.ndarray

    def point(self, t: float | np.ndarray) -> np.ndarray:
        t = np.asarray(t, dtype=np.float64)[..., None]
        return self.start + t * (self.end - self.start) + polynomial.polyval(t, self.offset) * self.inward

    def tangent(self, t: float) -> np.ndarray:
        return self.end - self.start + polynomial.polyval(t, polynomial.polyder(self.offset)) * self.inward

    def along(self, points: np.ndarray) -> np.ndarray:
        """``t`` of points (..., 2) projected onto the chord."""
        chord = self.end - self.start
        return (points - self.start) @ chord / (chord @ chord)

    def bow(self, a: np.ndarray, b: np.ndarray) -> float:
        """How far the side's middle between its corners ``a`` and ``b`` lies outside their chord."""
        middle = 0.5 * (a + b)
        return float((middle - self.point(0.5 * (self.along(a) + self.along(b)))) @ self.inward)


def _disc(radius_px: int) -> np.ndarray:
    return cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius_px + 1, 2 * radius_px + 1))


def _bright_region(value: np.ndarray, *, min_area_fraction: float) -> tuple[np.ndarray | None, np.ndarray, str]:
    """Outline (N, 2) and filled uint8 mask of the brightest large region, or None and why."""
    _, mask = cv2.threshold(value, 0, 255, cv2.THRESH_BINARY | cv2.THRESH_OTSU)
    specks = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (DOT_KERNEL_PX, DOT_KERNEL_PX))
    mask = cv2.morphologyEx(mask, cv2.MORPH_OPEN, specks)
    contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    rows, cols = value.shape
    big = [c for c in contours if cv2.contourArea(c) >= min_area_fraction * rows * cols]
    if not big:
        return None, mask, (f"no bright region of at least {min_area_fraction:.0%} of the frame: is the camera "
                            "looking at the gel with its lights on?")

    def filled(contour: np.ndarray) -> np.ndarray:
        region = np.zeros_like(mask)
        cv2.drawContours(region, [contour], -1, 255, cv2.FILLED)
        return region

    gel = max(big, key=lambda contour: cv2.mean(value, mask=filled(contour))[0])
    x, y, w, h = cv2.boundingRect(gel)
    if x <= 1 or y <= 1 or x + w >= cols - 1 or y + h >= rows - 1:
        return None, mask, "the bright gel runs off the frame's edge: its corners are not all in view"
    return gel[:, 0, :], filled(gel), ""


def _border_levels(value: np.ndarray, region: np.ndarray) -> tuple[float, float]:
    """Median brightness of the bands ``CONTRAST_BAND_PX`` inside and outside the region's border."""
    near, far = (_disc(r) for r in CONTRAST_BAND_PX)
    inside = cv2.subtract(cv2.erode(region, near), cv2.erode(region, far))
    outside = cv2.subtract(cv2.dilate(region, far), cv2.dilate(region, near))
    return float(np.median(value[inside > 0])), float(np.median(value[outside > 0]))


def _order(points: np.ndarray) -> np.ndarray:
    """Four points as top-left, top-right, bottom-left, bottom-right (x right, y down)."""
    s, d = points.sum(axis=1), points[:, 0] - points[:, 1]
    return points[[np.argmin(s), np.argmax(d), np.argmin(d), np.argmax(s)]]


def _side_points(value: np.ndarray, side: _Side, *, min_rise: float) -> np.ndarray:
    """Sub-pixel edge points (M, 2) along ``side``: the steepest step of each profile across it
    (along its inward normal), interpolated by a parabola. A profile that does not rise by
    ``min_rise`` levels from its outer to its inner end, or whose steepest step is at an end,
    has no edge within reach and gives no point."""
    along = np.linspace(SIDE_MARGIN, 1.0 - SIDE_MARGIN, PROFILES_PER_SIDE)
    offsets = np.arange(-PROFILE_HALF_PX, PROFILE_HALF_PX + 0.25, 0.25)
    base = side.point(along)
    samples = base[:, None, :] + offsets[None, :, None] * side.inward[None, None, :]
    profiles = cv2.remap(value, samples[..., 0].astype(np.float32), samples[..., 1].astype(np.float32),
                         cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    step = np.gradient(profiles, axis=1)
    peak = np.clip(np.argmax(step, axis=1), 1, offsets.size - 2)
    rows = np.arange(len(peak))
    left, mid, right = step[rows, peak - 1], step[rows, peak], step[rows, peak + 1]
    curvature = left - 2.0 * mid + right
    shift = np.where(curvature < 0, 0.5 * (left - right) / np.where(curvature < 0, curvature, -1.0), 0.0)
    position = (peak + np.clip(shift, -0.5, 0.5)) * 0.25 - PROFILE_HALF_PX
    edge = (profiles[:, -1] - profiles[:, 0] >= min_rise) & (peak > 1) & (peak < offsets.size - 2)
    return (base + position[:, None] * side.inward[None])[edge]


def _fit_side(side: _Side, points: np.ndarray, *, degree: int = 2) -> tuple[_Side, np.ndarray]:
    """``side`` through ``points``: a polynomial across its chord (a parabola: a line and its
    bow), fitted by iteratively reweighted least squares (Huber weights, so stray points barely
    pull it); and the points' distances from it."""
    t, offset = side.along(points), (points - side.start) @ side.inward
    weights = np.ones_like(t)
    for _ in range(10):
        coefficients = polynomial.polyfit(t, offset, degree, w=np.sqrt(weights))
        residual = offset - polynomial.polyval(t, coefficients)
        weights = np.minimum(1.0, 0.5 * OUTLIER_PX / np.maximum(np.abs(residual), 1e-6))
    return side._replace(offset=coefficients), residual


def _rough_side(start: np.ndarray, end: np.ndarray, inward: np.ndarray, outline: np.ndarray) -> _Side:
    """The straight side from corner ``start`` to corner ``end`` through the outline's points
    along it, away from the rounded corners."""
    side = _Side(start, end, inward, np.zeros(3))
    t, offset = side.along(outline), (outline - start) @ inward
    on = (t > SIDE_MARGIN) & (t < 1.0 - SIDE_MARGIN) & (np.abs(offset) < ROUGH_REACH * np.linalg.norm(end - start))
    return _fit_side(side, outline[on].astype(np.float64), degree=1)[0] if on.sum() >= 3 else side


def _meet(a: _Side, b: _Side, guess: np.ndarray) -> np.ndarray:
    """Where the curves of sides ``a`` and ``b`` meet near ``guess``: their tangents there, intersected,
    a few times over."""
    for _ in range(3):
        (pa, da), (pb, db) = ((s.point(s.along(guess)), s.tangent(s.along(guess))) for s in (a, b))
        ta, _ = np.linalg.solve(np.column_stack([da, -db]), pb - pa)
        guess = pa + ta * da
    return guess


def _half_pixel_shift(outline: np.ndarray, warped_size_px: tuple[int, int]) -> np.ndarray:
    """Raw points of warped (0, 0) ... (W, H), given the outline spanning warped -0.5 ... W - 0.5."""
    w, h = warped_size_px
    border = np.array([[-0.5, -0.5], [w - 0.5, -0.5], [-0.5, h - 0.5], [w - 0.5, h - 0.5]], np.float32)
    to_raw = cv2.getPerspectiveTransform(border, outline.astype(np.float32))
    target = np.array([[[0.0, 0.0], [w, 0.0], [0.0, h], [w, h]]])
    return cv2.perspectiveTransform(target, to_raw)[0]


def find_gel_corners(
    raw_bgr: np.ndarray, *, warped_size_px: tuple[int, int], min_area_fraction: float = 0.05,
    min_contrast: float = 20.0, max_edge_rms_px: float = 1.0, max_bow: float = 0.06,
) -> CornerFit:
    """The mirror corners of a Wedge from one raw no-contact frame (module notes).

    Parameters
    ----------
    raw_bgr : ndarray
        uint8 (H, W, 3) raw camera frame, BGR, the gel untouched.
    warped_size_px : (int, int)
        ``(warped_width_px, warped_height_px)`` the corners will be warped onto.
    min_area_fraction : float
        Smallest gel area, as a share of the frame.
    min_contrast : float
        Smallest brightness step (8-bit levels) from the housing to the gel.
    max_edge_rms_px : float
        Largest RMS scatter (raw px) of the edge points about their sides' curves.
    max_bow : float
        Largest bow of a side, as a share of its length (the reference Wedge frame's lens bows
        its left side by 3 %).

    Returns
    -------
    CornerFit
        Falsy with the reason when no gel quadrilateral is found, it is faint, or its
        sides are ragged or bent.
    """
    if not (isinstance(raw_bgr, np.ndarray) and raw_bgr.dtype == np.uint8 and raw_bgr.ndim == 3
            and raw_bgr.shape[2] == 3):
        got = f"{raw_bgr.dtype} {raw_bgr.shape}" if isinstance(raw_bgr, np.ndarray) else type(raw_bgr).__name__
        raise TeleopError(f"raw_bgr: expected a uint8 (H, W, 3) BGR frame, got {got}")
    # Closing fills marker dots and dust (dark spots smaller than the kernel) and keeps straight edges.
    dots = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (DOT_KERNEL_PX, DOT_KERNEL_PX))
    value = cv2.GaussianBlur(cv2.morphologyEx(raw_bgr.max(axis=2), cv2.MORPH_CLOSE, dots), (0, 0), 1.0)
    outline, region, reason = _bright_region(value, min_area_fraction=min_area_fraction)
    if outline is None:
        return CornerFit(reason=reason)
    inside, outside = _border_levels(value, region)
    contrast = inside - outside
    if contrast < min_contrast:
        return CornerFit(contrast=contrast, reason=(
            f"the gel is only {contrast:.0f} levels brighter than the housing around it ({inside:.0f} against "
            f"{outside:.0f}; at least {min_contrast:.0f} needed): lights on, exposure right?"))
    hull = cv2.convexHull(outline)
    approx = cv2.approxPolyDP(hull, CORNER_EPSILON * cv2.arcLength(hull, True), True)[:, 0, :]
    if len(approx) != 4:
        return CornerFit(contrast=contrast, reason=f"the bright gel's outline has {len(approx)} corners, not 4: "
                                                   "is all of it in view, unobstructed?")
    rough = _order(approx.astype(np.float64))
    value_f = value.astype(np.float32)
    centre = rough.mean(axis=0)
    ends = ((0, 1), (1, 3), (3, 2), (2, 0))  # top, right, bottom, left: indices of their corners
    sides, residuals = [], []
    for name, (i, j) in zip(SIDE_NAMES, ends, strict=True):
        direction = (rough[j] - rough[i]) / np.linalg.norm(rough[j] - rough[i])
        inward = np.array([-direction[1], direction[0]])
        inward = inward if np.dot(centre - rough[i], inward) > 0 else -inward
        side = _rough_side(rough[i], rough[j], inward, outline)
        for _ in range(2):  # measured across the rough side, then again across the curve found
            points = _side_points(value_f, side, min_rise=min_contrast / 2)
            side, residual = _fit_side(side, points) if len(points) >= 3 else (side, np.zeros(0))
        on_side = residual[np.abs(residual) <= OUTLIER_PX]
        if len(on_side) < MIN_EDGE_SHARE * PROFILES_PER_SIDE:
            return CornerFit(contrast=contrast, reason=(
                f"the gel's {name} side is not straight: along {1 - len(on_side) / PROFILES_PER_SIDE:.0%} of it, "
                f"no edge lies within {OUTLIER_PX:g} px of a smooth curve; something in view?"))
        sides.append(side)
        residuals.append(on_side)
    top, right, bottom, left = sides
    outline_px = np.array([_meet(top, left, rough[0]), _meet(top, right, rough[1]),
                           _meet(bottom, left, rough[2]), _meet(bottom, right, rough[3])])
    bows = np.array([side.bow(outline_px[i], outline_px[j]) for side, (i, j) in zip(sides, ends, strict=True)])
    lengths = np.array([np.linalg.norm(outline_px[j] - outline_px[i]) for i, j in ends])
    worst = int(np.argmax(np.abs(bows) / lengths))
    edge_rms = float(np.sqrt(np.mean(np.concatenate(residuals) ** 2)))
    common = {"outline_px": outline_px, "edge_rms_px": edge_rms, "contrast": contrast, "bow_px": float(bows[worst])}
    if edge_rms > max_edge_rms_px:
        return CornerFit(**common, reason=f"the gel's sides are not straight: edge points scatter {edge_rms:.2f} px "
                                          f"about their curves (at most {max_edge_rms_px} px); something in view?")
    if abs(bows[worst]) > max_bow * lengths[worst]:
        return CornerFit(**common, reason=(
            f"the gel's {SIDE_NAMES[worst]} side is not straight: it bows {abs(bows[worst]):.0f} px over its "
            f"{lengths[worst]:.0f} px (at most {max_bow:.0%}); something in view or pressing on the gel?"))
    return CornerFit(corners_px=_half_pixel_shift(outline_px, warped_size_px), **common)


def draw_corners(raw_bgr: np.ndarray, fit: CornerFit) -> np.ndarray:
    """A copy of ``raw_bgr`` with the fitted quadrilateral and its corners labelled, for a person to check.

    A falsy ``fit`` is written across the frame as its reason.
    """
    canvas = raw_bgr.copy()
    if not fit:
        cv2.putText(canvas, fit.reason[:80], (8, 24), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 255), 1, cv2.LINE_AA)
        return canvas
    shift = 4  # fixed-point bits: lines drawn at sub-pixel positions
    corners = np.rint(fit.corners_px * (1 << shift)).astype(np.int32)
    cv2.polylines(canvas, [corners[[0, 1, 3, 2]]], True, (0, 255, 255), 1, cv2.LINE_AA, shift)
    for (x, y), name, point in zip(fit.corners_px, CORNER_NAMES, corners, strict=True):
        cv2.circle(canvas, tuple(int(v) for v in point), 3 << shift, (0, 0, 255), 1, cv2.LINE_AA, shift)
        label = f"{name} ({x:.1f}, {y:.1f})"
        (width, height), _ = cv2.getTextSize(label, cv2.FONT_HERSHEY_SIMPLEX, 0.4, 1)
        at = (int(np.clip(x + 6, 0, canvas.shape[1] - width)), int(np.clip(y - 6, height, canvas.shape[0] - 1)))
        cv2.putText(canvas, label, at, cv2.FONT_HERSHEY_SIMPLEX, 0.4, (255, 255, 255), 1, cv2.LINE_AA)
    return canvas
