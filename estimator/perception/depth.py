"""Gel depth from tactile frames: gradients to depth, and sphere fits to indentations.

Frames and conventions
----------------------
Images are indexed ``[row, col]``; ``x`` is the column (right), ``y`` the row
(down), both in pixels of the frame given. Depth ``z`` is in metres, positive
into the gel (a pressed object makes it positive). Surface gradients
``gx = dz/dx`` and ``gy = dz/dy`` are dimensionless (metres per metre, which is
the same as pixels per pixel).

Baseline
--------
:func:`poisson_depth` anchors the surface at the frame border: depth is zero
half a pixel outside the image on every side (a Dirichlet condition, solved
with type-II discrete sine transforms). An undeformed gel is flat at the
border in every grasp the sensor sees (contacts are inside the pad), so this
fixes the free constant of integration where the truth is known, instead of
forcing a zero mean that would push the free gel negative around a contact.
A frame without contact has near-zero gradients and so near-zero depth.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from numbers import Real
from typing import TYPE_CHECKING

import numpy as np
import scipy.fft
import scipy.ndimage
from scipy.optimize import least_squares

from estimator.errors import PerceptionError
from estimator.perception.markers import inpaint_markers

if TYPE_CHECKING:
    from estimator.perception.calibration import Calibration

__all__ = ["SphereFit", "fit_sphere", "poisson_depth", "reconstruct_depth"]


def _finite_real(value: object) -> bool:
    """Whether ``value`` is one finite real number (a numpy scalar too, a bool not)."""
    return isinstance(value, Real) and not isinstance(value, bool) and math.isfinite(value)


@functools.lru_cache(maxsize=16)
def _inverse_eigenvalues(shape: tuple[int, int], dtype: np.dtype, scale: float) -> np.ndarray:
    """``scale`` / eigenvalues of the central-difference normal operator in the DST-II basis.

    With central differences ``D`` for both gradients, the least-squares depth
    solves ``D^T D z = D^T g``. Under the odd extension about the half-pixel
    border (the DST-II basis) ``D^T D`` is diagonal with eigenvalue
    ``-(sin^2(pi k / M) + sin^2(pi l / N))``, ``k = 1..M``, ``l = 1..N``. The
    single mode ``(M, N)`` is invisible to central differences and is set to 0.
    ``scale`` folds constant factors of the solve (the divergence's 1/2, the
    pixel pitch) into the table so they cost no pass over the image.
    """
    rows, cols = shape
    sy = np.sin(np.pi * np.arange(1, rows + 1) / rows) ** 2
    sx = np.sin(np.pi * np.arange(1, cols + 1) / cols) ** 2
    eig = -(sy[:, None] + sx[None, :])
    eig[-1, -1] = -np.inf
    inverse = (scale / eig).astype(dtype)
    inverse.setflags(write=False)
    return inverse


def _central_divergence(gx: np.ndarray, gy: np.ndarray) -> np.ndarray:
    """``D^T``-side of the normal equations: twice the central-difference divergence.

    Gradients are extended evenly beyond the border (they are even when the
    depth is odd about the half-pixel border), so the edge rows use one-sided
    differences. The factor 1/2 of the central difference is left to the
    caller (folded into :func:`_inverse_eigenvalues`).
    """
    div = np.empty_like(gx)
    div[:, 1:-1] = gx[:, 2:] - gx[:, :-2]
    div[:, 0] = gx[:, 1] - gx[:, 0]
    div[:, -1] = gx[:, -1] - gx[:, -2]
    div[1:-1] += gy[2:] - gy[:-2]
    div[0] += gy[1] - gy[0]
    div[-1] += gy[-1] - gy[-2]
    return div


def poisson_depth(gx: np.ndarray, gy: np.ndarray, *, pixel_pitch_m: float) -> np.ndarray:
    """Integrate surface gradients into depth with a fast Poisson solve.

    Least-squares integration of central-difference gradients, solved exactly
    with two type-II discrete sine transforms (``scipy.fft``, one worker) and
    cached eigenvalue denominators; depth is anchored to zero half a pixel
    outside the border (see the module notes).

    Parameters
    ----------
    gx, gy : ndarray
        Float, 2-D, same shape (at least 3 x 3): ``dz/dx`` (along columns) and
        ``dz/dy`` (along rows), dimensionless, finite.
    pixel_pitch_m : float
        Gel surface per pixel, metres.

    Returns
    -------
    ndarray
        Depth in metres, positive into the gel, same shape and dtype as ``gx``.

    Raises
    ------
    PerceptionError
        Shapes or dtypes differ, the arrays are not 2-D floats, a value is not
        finite, the pixel pitch is not a positive number, or the gradients are
        so large that the depth overflows.
    """
    for name, arr in (("gx", gx), ("gy", gy)):
        if not isinstance(arr, np.ndarray) or arr.ndim != 2 or arr.dtype.kind != "f":
            got = f"{arr.dtype} {arr.shape}" if isinstance(arr, np.ndarray) else type(arr).__name__
            raise PerceptionError(f"{name}: expected a 2-D float array, got {got}")
    if gx.shape != gy.shape or gx.dtype != gy.dtype:
        raise PerceptionError(
            f"gx and gy must match: got {gx.dtype} {gx.shape} and {gy.dtype} {gy.shape}"
        )
    if min(gx.shape) < 3:
        raise PerceptionError(f"gx: expected at least 3 x 3 pixels, got {gx.shape}")
    if not (_finite_real(pixel_pitch_m) and pixel_pitch_m > 0):
        raise PerceptionError(f"pixel_pitch_m: expected a positive number of metres, got {pixel_pitch_m!r}")
    divergence = _central_divergence(gx, gy)
    spectrum = scipy.fft.dstn(divergence, type=2, workers=1, overwrite_x=True)
    with np.errstate(over="ignore", invalid="ignore"):  # refused below, as a whole
        spectrum *= _inverse_eigenvalues(gx.shape, gx.dtype, 0.5 * float(pixel_pitch_m))
    depth = scipy.fft.idstn(spectrum, type=2, workers=1, overwrite_x=True)
    # One check of the result, on the hot path: every output of the two transforms sums every
    # divergence value, which sums every gradient value, so a NaN or infinite gradient leaves no
    # output finite; finite gradients near the float range (float32's sooner) can overflow too.
    if not np.isfinite(depth).all():
        if not (np.isfinite(gx).all() and np.isfinite(gy).all()):
            raise PerceptionError("gx/gy: gradients contain NaN or infinite values")
        raise PerceptionError(f"gx/gy: gradients too large to integrate in {gx.dtype}: the depth overflows")
    return depth


def reconstruct_depth(
    frame: np.ndarray,
    reference: np.ndarray,
    calibration: Calibration,
    *,
    marker_mask: np.ndarray | None = None,
) -> np.ndarray:
    """Depth map of the gel from one tactile frame and its no-contact reference.

    Parameters
    ----------
    frame, reference : ndarray
        uint8 BGR, shape ``calibration.image_shape + (3,)``, in the same pixel
        frame as the calibration (warp and crop them first when the sensor
        needs it, see :func:`~estimator.perception.warp.warp_and_crop`).
    calibration : Calibration
        Colour-to-gradient mapping of this sensor.
    marker_mask : ndarray of bool, optional
        Marker-dot pixels (from :func:`~estimator.perception.markers.detect_markers`);
        both images are inpainted there before the colour lookup.

    Returns
    -------
    ndarray
        float32 depth in metres, positive into the gel, shape ``image_shape``;
        always finite, near zero where the gel is untouched.

    Raises
    ------
    PerceptionError
        An image or the mask has the wrong shape or dtype.
    """
    if marker_mask is not None:
        if (not isinstance(marker_mask, np.ndarray) or marker_mask.dtype != bool
                or marker_mask.shape != calibration.image_shape):
            got = (f"{marker_mask.dtype} {marker_mask.shape}" if isinstance(marker_mask, np.ndarray)
                   else type(marker_mask).__name__)
            raise PerceptionError(f"marker_mask: expected a bool array of shape {calibration.image_shape}, got {got}")
        if marker_mask.any():
            frame = inpaint_markers(frame, marker_mask)
            reference = inpaint_markers(reference, marker_mask)
    gx, gy = calibration.gradients(frame, reference)
    return poisson_depth(gx, gy, pixel_pitch_m=calibration.pixel_pitch_m)


# --------------------------------------------------------------------------- sphere fit


@dataclass(frozen=True)
class SphereFit:
    """A sphere fitted to an indentation; falsy (``ok`` False) with a ``reason`` on failure.

    Attributes
    ----------
    ok : bool
        Whether the fit succeeded; ``bool(fit)`` is the same.
    reason : str
        Why it failed; empty on success.
    center_px : tuple of float or None
        Contact centre ``(x, y)`` in pixels of the depth map.
    radius_m : float or None
        Fitted sphere radius, metres.
    contact_radius_m : float or None
        Radius of the contact circle (where the surface slope peaks), metres.
    apex_depth_m : float or None
        Depth of the fitted cap at its centre, metres.
    rms_residual_m : float or None
        Root-mean-square depth residual of the fit over the contact circle, metres.
    n_pixels : int
        Pixels inside the contact circle used by the fit.
    """

    ok: bool
    reason: str = ""
    center_px: tuple[float, float] | None = None
    radius_m: float | None = None
    contact_radius_m: float | None = None
    apex_depth_m: float | None = None
    rms_residual_m: float | None = None
    n_pixels: int = 0

    def __bool__(self) -> bool:
        return self.ok


def _contact_circle(smooth_px: np.ndarray, slope: np.ndarray, distance: np.ndarray, peak_px: float) -> float:
    """Contact radius (px): middle of the ring of steepest mean slope inside the indentation.

    ``distance`` holds every pixel's distance (px) from the centre. The gel
    surface follows the indenter inside the contact and relaxes outside it,
    so its slope magnitude peaks at the contact edge. The search stops where
    the mean (over 1 px rings) depth falls below a tenth of the peak.
    """
    ring = distance.astype(np.intp).ravel()
    counts = np.maximum(np.bincount(ring), 1)
    depth_profile = np.bincount(ring, smooth_px.ravel()) / counts
    slope_profile = np.bincount(ring, slope.ravel()) / counts
    below = np.flatnonzero(depth_profile < 0.1 * peak_px)
    extent = int(below[0]) if below.size else len(counts)
    if extent <= 3:
        return 0.0
    return 2.5 + float(np.argmax(slope_profile[2:extent]))


def fit_sphere(
    depth: np.ndarray,
    *,
    pixel_pitch_m: float,
    center_px: tuple[float, float] | None = None,
    min_depth_m: float = 20e-6,
    smooth_px: float = 1.0,
) -> SphereFit:
    """Fit a spherical cap to the deepest indentation of a depth map.

    The contact circle is found first (the ring of steepest slope around the
    deepest point, or around ``center_px`` when given); a sphere
    ``z = sqrt(R^2 - (x - cx)^2 - (y - cy)^2) - h`` is then fitted to the depth
    inside it with ``scipy.optimize.least_squares``, and the circle and fit are
    refined once around the fitted centre.

    Parameters
    ----------
    depth : ndarray
        2-D float depth map (at least 3 x 3 pixels), metres, positive into the gel.
    pixel_pitch_m : float
        Gel surface per pixel, metres (> 0).
    center_px : (float, float), optional
        Where to look for the indentation, ``(x, y)`` pixels, on the image:
        ``-1 < x < W`` and ``-1 < y < H`` (a centre farther out has no pixel
        within 1 px, so no contact circle); default: the deepest point of the
        smoothed map.
    min_depth_m : float
        Shallower indentations are reported as no contact (m, finite).
    smooth_px : float
        Gaussian sigma (pixels, >= 0, at most ``max(H, W)``) used to find the
        peak and the contact circle; the sphere itself is fitted to the
        unsmoothed depth.

    Returns
    -------
    SphereFit
        Falsy with a reason when there is no indentation, the contact circle
        is too small, the depth is too large for the fit's arithmetic, or the
        fit does not converge to a finite sphere.

    Raises
    ------
    PerceptionError
        ``depth`` is not a 2-D float array of at least 3 x 3 pixels, or an
        option is not a finite number in its range (``center_px`` off the
        image, ``smooth_px`` wider than the image).
    """
    if not isinstance(depth, np.ndarray) or depth.ndim != 2 or depth.dtype.kind != "f":
        got = f"{depth.dtype} {depth.shape}" if isinstance(depth, np.ndarray) else type(depth).__name__
        raise PerceptionError(f"depth: expected a 2-D float array in metres, got {got}")
    if min(depth.shape) < 3:
        raise PerceptionError(f"depth: expected at least 3 x 3 pixels, got {depth.shape}")
    if not (_finite_real(pixel_pitch_m) and pixel_pitch_m > 0):
        raise PerceptionError(f"pixel_pitch_m: expected a positive number of metres, got {pixel_pitch_m!r}")
    if not _finite_real(min_depth_m):
        raise PerceptionError(f"min_depth_m: expected a finite number of metres, got {min_depth_m!r}")
    if not (_finite_real(smooth_px) and smooth_px >= 0):
        raise PerceptionError(f"smooth_px: expected a finite number of pixels >= 0, got {smooth_px!r}")
    rows, cols = depth.shape
    if smooth_px > max(rows, cols):  # wider than the image; its kernel would outgrow memory
        raise PerceptionError(f"smooth_px: expected at most the image's larger side, {max(rows, cols)} px, "
                              f"got {smooth_px!r}")
    if center_px is not None:
        center = np.asarray(center_px, dtype=np.float64)
        if center.shape != (2,) or not np.isfinite(center).all():
            raise PerceptionError(f"center_px: expected finite (x, y) pixels, got {center_px!r}")
        if not (-1.0 < center[0] < cols and -1.0 < center[1] < rows):
            raise PerceptionError(f"center_px: expected (x, y) on the {rows} x {cols} image, -1 < x < {cols} "
                                  f"and -1 < y < {rows}, got {center_px!r}")
    if not np.isfinite(depth).all():
        return SphereFit(ok=False, reason="depth contains NaN or infinite values")
    with np.errstate(over="ignore"):
        depth_px = depth.astype(np.float64) / pixel_pitch_m
        largest = float(np.max(np.abs(depth_px)))
    # The fit squares depths in pixels, up to twice the largest (the cap, the sphere's radius).
    if not math.isfinite(4.0 * largest * largest):
        return SphereFit(ok=False, reason=f"depth too large to fit: its largest value, {largest:.3g} px, "
                                               "overflows when squared")
    smooth = scipy.ndimage.gaussian_filter(depth_px, smooth_px)
    if center_px is None:
        row, col = np.unravel_index(int(np.argmax(smooth)), smooth.shape)
        center = np.array([col, row], dtype=np.float64)
    yy, xx = np.indices((rows, cols), dtype=np.float32)
    slope = np.hypot(*np.gradient(smooth))
    fit = None
    for _ in range(2):
        col = int(np.clip(round(center[0]), 0, cols - 1))
        row = int(np.clip(round(center[1]), 0, rows - 1))
        peak = float(smooth[row, col])
        if peak * pixel_pitch_m < min_depth_m:
            return SphereFit(
                ok=False,
                reason=f"no indentation: depth {peak * pixel_pitch_m:.3g} m at ({col}, {row}) is "
                f"below min_depth_m = {min_depth_m:.3g} m",
            )
        distance = np.hypot(xx - center[0], yy - center[1])
        contact_px = _contact_circle(smooth, slope, distance, peak)
        inside = distance < contact_px
        n_pixels = int(inside.sum())
        if contact_px < 3 or n_pixels < 20:
            return SphereFit(ok=False, reason=f"contact circle too small ({contact_px:.1f} px)")
        xs, ys, zs = xx[inside], yy[inside], depth_px[inside]
        cap = max(peak - float(np.min(smooth[inside])), 1e-3)
        radius0 = (contact_px**2 + cap**2) / (2.0 * cap)
        start = np.array([center[0], center[1], radius0, radius0 - peak])

        def residual(p, xs=xs, ys=ys, zs=zs):
            cx, cy, radius, offset = p
            return np.sqrt(np.maximum(radius**2 - (xs - cx) ** 2 - (ys - cy) ** 2, 0.0)) - offset - zs

        def jacobian(p, xs=xs, ys=ys):
            cx, cy, radius, _ = p
            dx, dy = xs - cx, ys - cy
            height = np.sqrt(np.maximum(radius**2 - dx**2 - dy**2, 0.0))
            inverse = np.divide(1.0, height, out=np.zeros_like(height), where=height > 1e-9)
            return np.column_stack([dx * inverse, dy * inverse, radius * inverse, -np.ones_like(xs)])

        fit = least_squares(residual, start, jac=jacobian, method="lm",
                            x_scale=np.array([1.0, 1.0, radius0, radius0]))
        if not (fit.success and np.isfinite(fit.x).all()) or abs(fit.x[2]) < 1.0:
            return SphereFit(ok=False, reason=f"sphere fit did not converge: {fit.message}")
        center = fit.x[:2]
        if not (0 <= center[0] < cols and 0 <= center[1] < rows):
            return SphereFit(ok=False, reason=f"fitted centre {tuple(center)} lies outside the image")
    cx, cy, radius, offset = (float(v) for v in fit.x)
    with np.errstate(over="ignore"):
        result = SphereFit(
            ok=True,
            center_px=(cx, cy),
            radius_m=abs(radius) * pixel_pitch_m,
            contact_radius_m=contact_px * pixel_pitch_m,
            apex_depth_m=(abs(radius) - offset) * pixel_pitch_m,
            rms_residual_m=float(np.sqrt(np.mean(fit.fun**2))) * pixel_pitch_m,
            n_pixels=n_pixels,
        )
    # Pixels times a large pitch can leave the float range.
    if not all(math.isfinite(v) for v in (result.radius_m, result.contact_radius_m, result.apex_depth_m,
                                          result.rms_residual_m)):
        return SphereFit(ok=False, reason="the fitted sphere in metres is beyond the float range")
    return result
