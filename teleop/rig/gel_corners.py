"""The gel's quadrilateral in a raw no-contact frame: a Wedge's mirror corners, measured.

A GelSight Wedge sees its lit gel through a mirror, a bright quadrilateral on the dark
housing of the raw frame (:mod:`teleop.geometry`). :func:`find_gel_corners` finds it:

1. the brightest channel of each pixel, thresholded (Otsu) and closed over marker dots
   and dust, gives bright regions; the gel is the brightest large one (the Wedge's
   second mirror view beside it is dimmer), and must lie wholly inside the frame;
2. its outline, simplified (``cv2.approxPolyDP``) to four corners, gives the sides;
3. each side is measured again to sub-pixel: the edge's position (the steepest intensity
   step, interpolated) along many short profiles across it, a robust line through them
   (``cv2.fitLine``); adjacent lines meet at the outline's corners.

The outline is the border of the gel, which covers the warped image's pixels from the
outer edge of the first to the outer edge of the last: warped ``-0.5`` to ``W - 0.5``
in pixel-centre coordinates. :attr:`~teleop.settings.SensorSettings.warp_corners_px`
are the raw points of warped ``(0, 0)`` and ``(W, H)`` (:func:`teleop.geometry.raw_to_warped_matrix`),
so the corners returned are the outline's mapped through that half-pixel shift: half a
warped pixel inward at the top-left, outward at the bottom-right.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from teleop.errors import TeleopError

__all__ = ["CornerFit", "draw_corners", "find_gel_corners"]

CORNER_NAMES = ("top-left", "top-right", "bottom-left", "bottom-right")
# Profiles across each side: how far out and in they reach (raw px), and how many per side.
PROFILE_HALF_PX = 6.0
PROFILES_PER_SIDE = 60
DOT_KERNEL_PX = 15  # wider than a marker dot or a speck of dust
MIN_EDGE_SHARE = 0.7  # of a side's profiles must find its edge
SIDE_MARGIN = 0.12  # of a side's length next to each corner, where the outline rounds off


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
        Root-mean-square distance of the measured edge points to their side's line.
    contrast : float
        Median brightness (8-bit levels) inside the gel minus outside, near the border.
    reason : str
        Empty when found; otherwise what was wrong, for a person.
    """

    corners_px: np.ndarray | None = None
    outline_px: np.ndarray | None = None
    edge_rms_px: float = float("nan")
    contrast: float = float("nan")
    reason: str = ""

    def __bool__(self) -> bool:
        return not self.reason

    def as_settings(self) -> list[list[float]]:
        """The corners as ``warp_corners_px`` holds them, rounded to 0.1 px."""
        return [[round(float(x), 1), round(float(y), 1)] for x, y in self.corners_px]


def _bright_region(value: np.ndarray, *, min_area_fraction: float) -> tuple[np.ndarray | None, str]:
    """Outline (N, 2) of the brightest large region, or None and why."""
    _, mask = cv2.threshold(value, 0, 255, cv2.THRESH_BINARY | cv2.THRESH_OTSU)
    specks = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (DOT_KERNEL_PX, DOT_KERNEL_PX))
    mask = cv2.morphologyEx(mask, cv2.MORPH_OPEN, specks)
    contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    rows, cols = value.shape
    big = [c for c in contours if cv2.contourArea(c) >= min_area_fraction * rows * cols]
    if not big:
        return None, (f"no bright region of at least {min_area_fraction:.0%} of the frame: is the camera "
                      "looking at the gel with its lights on?")

    def brightness(contour: np.ndarray) -> float:
        region = np.zeros_like(mask)
        cv2.drawContours(region, [contour], -1, 255, cv2.FILLED)
        return cv2.mean(value, mask=region)[0]

    gel = max(big, key=brightness)
    x, y, w, h = cv2.boundingRect(gel)
    if x <= 1 or y <= 1 or x + w >= cols - 1 or y + h >= rows - 1:
        return None, "the bright gel runs off the frame's edge: its corners are not all in view"
    return gel[:, 0, :], ""


def _order(points: np.ndarray) -> np.ndarray:
    """Four points as top-left, top-right, bottom-left, bottom-right (x right, y down)."""
    s, d = points.sum(axis=1), points[:, 0] - points[:, 1]
    return points[[np.argmin(s), np.argmax(d), np.argmin(d), np.argmax(s)]]


def _side_points(value: np.ndarray, start: np.ndarray, end: np.ndarray, inward: np.ndarray, *,
                 min_rise: float) -> np.ndarray:
    """Sub-pixel edge points (M, 2) along the side start -> end: the steepest step of each
    profile across it (``inward`` unit normal, into the gel), interpolated by a parabola.
    A profile that does not rise by ``min_rise`` levels from its outer to its inner end, or
    whose steepest step is at an end, has no edge within reach and gives no point."""
    along = np.linspace(SIDE_MARGIN, 1.0 - SIDE_MARGIN, PROFILES_PER_SIDE)
    offsets = np.arange(-PROFILE_HALF_PX, PROFILE_HALF_PX + 0.25, 0.25)
    base = start[None] + along[:, None] * (end - start)[None]
    samples = base[:, None, :] + offsets[None, :, None] * inward[None, None, :]
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
    return (base + position[:, None] * inward[None])[edge]


def _intersect(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Where lines (vx, vy, x0, y0) ``a`` and ``b`` meet."""
    (ax, ay, ax0, ay0), (bx, by, bx0, by0) = a, b
    t = np.linalg.solve(np.array([[ax, -bx], [ay, -by]]), np.array([bx0 - ax0, by0 - ay0]))
    return np.array([ax0 + t[0] * ax, ay0 + t[0] * ay])


def _half_pixel_shift(outline: np.ndarray, warped_size_px: tuple[int, int]) -> np.ndarray:
    """Raw points of warped (0, 0) ... (W, H), given the outline spanning warped -0.5 ... W - 0.5."""
    w, h = warped_size_px
    border = np.array([[-0.5, -0.5], [w - 0.5, -0.5], [-0.5, h - 0.5], [w - 0.5, h - 0.5]], np.float32)
    to_raw = cv2.getPerspectiveTransform(border, outline.astype(np.float32))
    target = np.array([[[0.0, 0.0], [w, 0.0], [0.0, h], [w, h]]])
    return cv2.perspectiveTransform(target, to_raw)[0]


def find_gel_corners(
    raw_bgr: np.ndarray, *, warped_size_px: tuple[int, int], min_area_fraction: float = 0.05,
    min_contrast: float = 20.0, max_edge_rms_px: float = 1.0,
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
        Largest RMS scatter (raw px) of the edge points about their sides' lines.

    Returns
    -------
    CornerFit
        Falsy with the reason when no gel quadrilateral is found, it is faint, or its
        sides are not straight.
    """
    if not (isinstance(raw_bgr, np.ndarray) and raw_bgr.dtype == np.uint8 and raw_bgr.ndim == 3
            and raw_bgr.shape[2] == 3):
        got = f"{raw_bgr.dtype} {raw_bgr.shape}" if isinstance(raw_bgr, np.ndarray) else type(raw_bgr).__name__
        raise TeleopError(f"raw_bgr: expected a uint8 (H, W, 3) BGR frame, got {got}")
    # Closing fills marker dots and dust (dark spots smaller than the kernel) and keeps straight edges.
    dots = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (DOT_KERNEL_PX, DOT_KERNEL_PX))
    value = cv2.GaussianBlur(cv2.morphologyEx(raw_bgr.max(axis=2), cv2.MORPH_CLOSE, dots), (0, 0), 1.0)
    outline, reason = _bright_region(value, min_area_fraction=min_area_fraction)
    if outline is None:
        return CornerFit(reason=reason)
    hull = cv2.convexHull(outline)
    approx = cv2.approxPolyDP(hull, 0.02 * cv2.arcLength(hull, True), True)[:, 0, :]
    if len(approx) != 4:
        return CornerFit(reason=f"the bright gel's outline has {len(approx)} corners, not 4: is all of it in view, "
                                "unobstructed?")
    rough = _order(approx.astype(np.float64))
    value_f = value.astype(np.float32)
    centre = rough.mean(axis=0)
    sides = []  # top, right, bottom, left: (start corner, end corner, inward unit normal)
    for i, j in ((0, 1), (1, 3), (3, 2), (2, 0)):
        direction = (rough[j] - rough[i]) / np.linalg.norm(rough[j] - rough[i])
        inward = np.array([-direction[1], direction[0]])
        sides.append((rough[i], rough[j], inward if np.dot(centre - rough[i], inward) > 0 else -inward))
    # Brightness 4 px inside minus 4 px outside the middle of each side.
    picks = np.array([0.5 * (a + b) + k * 4.0 * n for a, b, n in sides for k in (1, -1)], dtype=np.float32)
    levels = cv2.remap(value_f, picks[:, 0:1], picks[:, 1:2], cv2.INTER_LINEAR)[:, 0]
    contrast = float(np.median(levels[0::2] - levels[1::2]))
    if contrast < min_contrast:
        return CornerFit(contrast=contrast, reason=f"the gel is only {contrast:.0f} levels brighter than the housing "
                                                   f"(at least {min_contrast:.0f} needed): lights on, exposure right?")
    lines, scatter = [], []
    for start, end, inward in sides:
        points = _side_points(value_f, start, end, inward, min_rise=min_contrast / 2)
        if len(points) < MIN_EDGE_SHARE * PROFILES_PER_SIDE:
            return CornerFit(contrast=contrast, reason=(
                f"the gel's sides are not straight: along {1 - len(points) / PROFILES_PER_SIDE:.0%} of one, its "
                f"edge strays over {PROFILE_HALF_PX:g} px from a line; something in view, or a distorting lens?"))
        line = cv2.fitLine(points.astype(np.float32), cv2.DIST_HUBER, 0, 0.01, 0.01)[:, 0].astype(np.float64)
        scatter.append((points - line[2:]) @ np.array([-line[1], line[0]]))
        lines.append(line)
    top, right, bottom, left = lines
    outline_px = np.array([_intersect(top, left), _intersect(top, right),
                           _intersect(bottom, left), _intersect(bottom, right)])
    edge_rms = float(np.sqrt(np.mean(np.concatenate(scatter) ** 2)))
    common = {"outline_px": outline_px, "edge_rms_px": edge_rms, "contrast": contrast}
    if edge_rms > max_edge_rms_px:
        return CornerFit(**common, reason=f"the gel's sides are not straight: edge points scatter {edge_rms:.2f} px "
                                          f"about their lines (at most {max_edge_rms_px} px); something in view?")
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
