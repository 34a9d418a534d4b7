"""Per-frame contact features of tactile depth maps, vectorised over a stack of frames.

Frames: a depth map is indexed ``[row, col]`` on the warped, cropped image
grid; ``x`` runs along columns and ``y`` along rows, both in metres from the
centre of the top-left pixel. Depth is the gel's indentation in metres,
positive into the gel.

Two regions are measured in each frame:

* the *contact region* of the paper: depth at or above the contact threshold
  (0.1 mm by default, ``SensorSettings.contact_threshold_m``). Its area uses the
  true pixel area ``pitch**2`` (the published code used the pixel diagonal and
  got areas about half too small).
* the *contact cap*: depth at or above half the peak depth. For a Hertzian
  contact the gel's displacement at the contact edge is exactly half its
  centre value, so the cap's radius is the Hertz contact radius ``a``, whereas
  the 0.1 mm threshold region grows far beyond ``a`` once the peak is deep.
  The apparent radius of curvature is fitted on the cap.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from scipy import ndimage

from estimator.errors import PerceptionError

__all__ = ["ContactFeatures", "contact_features"]

MIN_FIT_PIXELS = 6


@dataclass(frozen=True)
class ContactFeatures:
    """Contact features of ``n`` depth maps; every array has ``n`` rows.

    Attributes
    ----------
    peak_depth_m : ndarray, shape (n,)
        Peak of the lightly smoothed depth map (m, >= 0).
    area_m2 : ndarray, shape (n,)
        Area at or above the contact threshold (m^2).
    radius_m : ndarray, shape (n,)
        ``sqrt(area_m2 / pi)`` (m).
    cap_radius_m : ndarray, shape (n,)
        Equivalent radius of the region at or above half the peak depth (m); 0
        where the peak is below the contact threshold.
    curvature_radius_m : ndarray, shape (n,)
        Apparent radius of curvature of the cap from a least-squares isotropic
        paraboloid (m): ``inf`` where the cap is flat or concave, NaN where
        the cap has fewer than 6 pixels. For two elastic bodies it is the
        object's radius times ``(k_sensor + k_object) / k_sensor``.
    centroid_m : ndarray, shape (n, 2)
        (x, y) centroid of the contact region (m); NaN where there is none.
    touches_edge : ndarray of bool, shape (n,)
        The contact region reaches the image border (the contact may extend
        beyond the pad; its area is then a lower bound).
    cap_touches_edge : ndarray of bool, shape (n,)
        The same for the cap (its radius is then a lower bound).
    """

    peak_depth_m: np.ndarray
    area_m2: np.ndarray
    radius_m: np.ndarray
    cap_radius_m: np.ndarray
    curvature_radius_m: np.ndarray
    centroid_m: np.ndarray
    touches_edge: np.ndarray
    cap_touches_edge: np.ndarray

    def __len__(self) -> int:
        return int(self.peak_depth_m.shape[0])

    def take(self, indices: np.ndarray) -> ContactFeatures:
        """Features of the frames at ``indices`` (integer positions or a boolean mask)."""
        return ContactFeatures(
            peak_depth_m=self.peak_depth_m[indices],
            area_m2=self.area_m2[indices],
            radius_m=self.radius_m[indices],
            cap_radius_m=self.cap_radius_m[indices],
            curvature_radius_m=self.curvature_radius_m[indices],
            centroid_m=self.centroid_m[indices],
            touches_edge=self.touches_edge[indices],
            cap_touches_edge=self.cap_touches_edge[indices],
        )


@lru_cache(maxsize=4)
def _paraboloid_basis(shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray, float]:
    """Basis 1, u, v, u^2 + v^2 over the flattened grid (u, v in units of ``scale`` pixels),
    and its per-pixel outer products (P, 16) for the normal equations."""
    rows, cols = shape
    scale = max(rows, cols) / 2.0  # keeps the normal equations well conditioned
    v, u = np.indices(shape, dtype=np.float64)
    u = (u.ravel() - (cols - 1) / 2.0) / scale
    v = (v.ravel() - (rows - 1) / 2.0) / scale
    basis = np.stack([np.ones_like(u), u, v, u * u + v * v], axis=1)
    outer = (basis[:, :, None] * basis[:, None, :]).reshape(-1, 16)
    basis.flags.writeable = False
    outer.flags.writeable = False
    return basis, outer, scale


def contact_features(
    depth_m: np.ndarray,
    *,
    pixel_pitch_m: float,
    contact_threshold_m: float,
    smooth_px: float = 1.0,
) -> ContactFeatures:
    """Measure peak depth, contact area and radius, cap curvature and centroid per frame.

    Parameters
    ----------
    depth_m : ndarray, shape (n, H, W), float
        Gel indentation (m, positive into the gel) of ``n`` frames.
    pixel_pitch_m : float
        Gel surface per pixel (m); pixel area is ``pixel_pitch_m ** 2``.
    contact_threshold_m : float
        Depth at and above which a pixel is in contact (m).
    smooth_px : float, optional
        Standard deviation (pixels) of the Gaussian applied before measuring,
        so that single-pixel noise moves neither the peak nor the contact
        edge. 0 disables it.

    Returns
    -------
    ContactFeatures

    Raises
    ------
    PerceptionError
        ``depth_m`` is not a finite float (n, H, W) array, or an option is not
        finite and positive.
    """
    depth = np.asarray(depth_m)
    if depth.ndim != 3 or not np.issubdtype(depth.dtype, np.floating):
        raise PerceptionError(
            f"depth_m: expected a float (n, H, W) stack of depth maps, got {depth.dtype} {depth.shape}"
        )
    if not np.all(np.isfinite(depth)):
        raise PerceptionError("depth_m: contains NaN or infinite values")
    for name, value in (("pixel_pitch_m", pixel_pitch_m), ("contact_threshold_m", contact_threshold_m)):
        if not (np.isfinite(value) and value > 0):
            raise PerceptionError(f"{name}: expected a finite value > 0, got {value}")
    if not (np.isfinite(smooth_px) and smooth_px >= 0):
        raise PerceptionError(f"smooth_px: expected a finite value >= 0, got {smooth_px}")

    n, rows, cols = depth.shape
    if smooth_px > 0 and depth.size:
        depth = ndimage.gaussian_filter(depth, sigma=(0, smooth_px, smooth_px), mode="nearest")
    flat = depth.reshape(n, rows * cols)
    pixel_area = pixel_pitch_m**2

    peak = np.maximum(flat.max(axis=1, initial=0.0), 0.0).astype(np.float64)
    contact = flat >= contact_threshold_m
    count = contact.sum(axis=1)
    area = count * pixel_area
    radius = np.sqrt(area / np.pi)

    border = np.zeros((rows, cols), dtype=bool)
    border[[0, -1], :] = True
    border[:, [0, -1]] = True
    border = border.ravel()
    touches_edge = (contact & border).any(axis=1)

    y_m, x_m = (np.indices((rows, cols), dtype=np.float64) * pixel_pitch_m).reshape(2, -1)
    weights = contact.astype(np.float64)
    with np.errstate(invalid="ignore", divide="ignore"):
        centroid = np.stack([weights @ x_m, weights @ y_m], axis=1) / count[:, None]

    # The cap: at or above half the peak, only where the peak is itself a contact.
    half = np.where(peak >= contact_threshold_m, peak / 2.0, np.inf)
    cap = flat >= half[:, None]
    cap_count = cap.sum(axis=1)
    cap_touches_edge = (cap & border).any(axis=1)
    cap_radius = np.sqrt(cap_count * pixel_area / np.pi)

    basis, outer, scale = _paraboloid_basis((rows, cols))
    cap_w = cap.astype(np.float64)
    normal = (cap_w @ outer).reshape(n, 4, 4)
    rhs = (cap_w * flat) @ basis
    coef = (np.linalg.pinv(normal) @ rhs[:, :, None])[:, :, 0]
    curvature = coef[:, 3]  # depth (m) per scale^2 pixels^2: depth = d0 - r^2 / (2 R)
    with np.errstate(divide="ignore"):
        curvature_radius = np.where(
            curvature < 0, -((scale * pixel_pitch_m) ** 2) / (2.0 * curvature), np.inf
        )
    curvature_radius = np.where(cap_count >= MIN_FIT_PIXELS, curvature_radius, np.nan)

    return ContactFeatures(
        peak_depth_m=peak,
        area_m2=area.astype(np.float64),
        radius_m=radius,
        cap_radius_m=cap_radius,
        curvature_radius_m=curvature_radius,
        centroid_m=centroid,
        touches_edge=touches_edge,
        cap_touches_edge=cap_touches_edge,
    )
