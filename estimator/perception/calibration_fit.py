"""Fitting a colour-to-gradient calibration from presses of a ball of known radius.

The table it fits is described in :mod:`estimator.perception.calibration` ("Model").

Labels
------
Training labels come from a ball of known radius ``R`` pressed into the gel.
Inside the contact circle (centre ``c``, radius ``a``) the gel follows the
ball, a cap ``z = sqrt(R^2 - r^2) - const``, so ``dz/dx = -(x - cx) /
sqrt(R^2 - r^2)`` and likewise for y (pixels per pixel, with R in pixels).
Pixels within ``inside_fraction * a`` of the centre are labelled so; the rim
is left out because the skin does not follow the ball exactly at the contact
edge. Pixels beyond ``outside_fraction * a`` and beyond the press's visible
colour change are labelled flat; the ring in between (where the gel is pulled
down around the ball) is not used.

Flat-gel weight
---------------
A bin's mean is the conditional mean of the gradient given the colour *under
the calibration set's mix of slopes*. In ball presses that mix is almost all
flat gel (the shipped simulated sets label 45 to 210 flat pixels for every
on-ball one), so a bin near "no colour change", hit both by sensor noise on
flat gel and by a small slope, is pulled towards zero: small slopes read far
too small, while real contacts are broad and shallow.
The table should not carry that prior, so the flat labels are reweighted:
together they count ``flat_weight`` times the on-ball labels (each flat pixel
``flat_weight * n_on_ball / n_flat``), whatever the pad and press sizes. A
bin seen only by flat gel still reads zero and a bin seen only on the ball
reads the ball; only bins hit by both shift. The price is noise: an untouched
pixel whose noise moves it out of the centre bin reads a small slope rather
than ~0, and such slopes integrate over the pad. The default 15 lies between
the two (figures: ``docs/decisions/0009-flat-gel-weight.md``; the study is in
``tests/estimator/perception/test_sphere_depth.py`` and ``test_depth.py``).
Held-out ball radii do not depend on the weight. ``flat_weight=None`` counts
every flat pixel once, the set's own mix.

Each bin holds its mean slope, not the slope of an inverted forward map
(colour as a function of slope): a real press frame's flat gel differs from
the reference by more than noise, which the bins' means absorb and a forward
map does not (``docs/decisions/0010-bin-means-not-forward-map.md``).

Smoothing
---------
A slope below ~0.05 changes an 8-bit pixel's colour by a grey level or two, the size of the
camera and JPEG noise, so bin by bin the table cannot tell a broad, shallow contact from flat
gel. With ``smoothing_px`` > 0 the frames and the reference are smoothed by a Gaussian of that
many pixels, in floating point, before their colour change is binned, here and at every lookup
of the table: shallow slopes then read far better, at about 1.6 times the depth's cost. The
default stays 0 (:data:`DEFAULT_SMOOTHING_PX`): the shipped calibrations and the models trained
on their depth have none, and a model reads depth as it was trained
(``docs/decisions/0011-no-colour-smoothing.md`` has the figures and the retraining tried).

Recorded press circles
----------------------
Press circles from a dataPack (``touch_center``, ``touch_radius``) are hand
annotations, and their conventions differ between sets: the GelSight set in
``taxim`` draws the contact a few pixels wider than it is, while the GelSight
Mini set scatters the centres by up to ~20 px around where the ball visibly
pressed and draws the radius at the edge of the whole visible dimple (34-57 px)
rather than of the contact (14-20 px, where the colour change peaks; the soft
Mini gel sinks in far around the ball). Labelling that dimple with the ball's
slopes teaches the table a depth-dependent mapping (shallow presses came out
as smaller spheres, deep ones as larger). By default (``refine_passes=1``) the
annotations therefore only seed the calibration: a first table is fitted with
them, every training press is reconstructed with it and its centre re-measured
with :func:`~estimator.perception.depth.fit_sphere` (sphere-fit centre, which
does not depend on the annotated radius), and its rings with
:func:`press_rings` around that centre, straight from the images: the contact
radius is the ring of largest mean colour change (the surface slope, and so
the colour change, peaks at the contact edge), and the flat gel starts where
the change has fallen to ``flat_fraction`` of that peak. The table is then
fitted again with the re-measured circles. A re-measured circle whose centre
moved further than the given radius ``a`` is discarded and the given one
kept. ``refine_passes=0`` uses the annotations as given. Flat labels always
start beyond both ``outside_fraction * a`` and the measured flat ring, so the
sunk-in gel around a press is never labelled flat. The circles actually used
are kept in the calibration's provenance. Circles detected in the images
(:func:`~estimator.perception.press_circles.detect_press_circle`, for presses
without annotations) are seeds of the
same kind.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from datetime import UTC, datetime
from typing import Any

import numpy as np
import scipy.ndimage

from estimator.errors import CalibrationError
from estimator.perception.calibration import Calibration, _check_image, _tile_offsets, lut_index
from estimator.perception.depth import fit_sphere, reconstruct_depth
from estimator.perception.press_circles import (
    CLIPPED_SHARE,
    PressRings,
    clipped_presses,
    clipped_share,
    press_rings,
)
from teleop.progress import progress_bar

__all__ = ["DEFAULT_FLAT_WEIGHT", "DEFAULT_SMOOTHING_PX", "fit_calibration"]

DEFAULT_FLAT_WEIGHT = 15.0
"""Default total weight of the flat-gel labels relative to the on-ball ones (module notes)."""
DEFAULT_SMOOTHING_PX = 0.0
"""Default Gaussian sigma (pixels of the calibration's frames) of the colour changes: none, as the
shipped models were trained on unsmoothed depth (module notes: "Smoothing")."""


def _press_labels(
    grid: tuple[np.ndarray, np.ndarray], center: np.ndarray, radius_px: float, flat_px: float,
    ball_px: float, inside_fraction: float, outside_fraction: float, markers: np.ndarray | None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Labelled pixels of one press, marker pixels left out.

    Returns the on-ball mask, its ``dz/dx`` and ``dz/dy`` (flat over that
    mask), and the flat-gel mask (beyond both ``outside_fraction * radius_px``
    and ``flat_px``); ``grid`` is ``np.indices`` (rows, cols).
    """
    dx, dy = grid[1] - center[0], grid[0] - center[1]
    r2 = dx * dx + dy * dy
    on_ball = r2 < (inside_fraction * radius_px) ** 2
    flat = r2 > max(outside_fraction * radius_px, flat_px) ** 2
    if markers is not None:
        on_ball &= ~markers
        flat &= ~markers
    cap = np.sqrt(np.maximum(ball_px**2 - r2[on_ball], 1e-12))
    return on_ball, -dx[on_ball] / cap, -dy[on_ball] / cap, flat


def _fit_table(
    reference: np.ndarray, presses: Sequence[np.ndarray], centers: np.ndarray, radii: np.ndarray,
    flat_radii: np.ndarray, markers: Sequence[np.ndarray | None], *, ball_px: float, bins: int, tiles: tuple[int, int], relative_range: float,
    inside_fraction: float, outside_fraction: float, tile_prior_count: float, flat_weight: float | None,
    smoothing_px: float,
) -> np.ndarray:
    """Accumulate labelled pixels into bins and build the filled, tiled table.

    Each on-ball pixel counts 1; the flat-gel pixels together count ``flat_weight`` times the
    on-ball pixels (each ``flat_weight * n_on_ball / n_flat``), or 1 each when it is None.
    """
    shape = reference.shape[:2]
    n_tiles, n_colours = tiles[0] * tiles[1], bins**3
    offsets = _tile_offsets(shape, tiles, bins)
    grid = np.indices(shape, dtype=np.float64)
    flat_count = np.zeros(n_tiles * n_colours)
    ball_index, ball_gx, ball_gy = [], [], []
    for press, center, radius, flat_px, mask in zip(presses, centers, radii, flat_radii, markers,
                                                   strict=True):
        on_ball, gx, gy, flat = _press_labels(grid, center, radius, flat_px, ball_px, inside_fraction,
                                              outside_fraction, mask)
        index = lut_index(press, reference, bins=bins, relative_range=relative_range, offsets=offsets,
                          smoothing_px=smoothing_px)
        flat_count += np.bincount(index[flat], minlength=flat_count.size)
        ball_index.append(index[on_ball])
        ball_gx.append(gx)
        ball_gy.append(gy)
    labelled_on_ball = sum(len(i) for i in ball_index)
    if labelled_on_ball == 0:
        raise CalibrationError("centers_px/radii_px: no press circle covers any pixel of the images")
    labelled_flat = flat_count.sum()
    if flat_weight is not None and labelled_flat > 0:
        flat_count *= flat_weight * labelled_on_ball / labelled_flat
    # Flat-gel pixels add to the counts only: their gradient is zero.
    ball_index = np.concatenate(ball_index)
    count = flat_count + np.bincount(ball_index, minlength=flat_count.size)
    sum_x = np.bincount(ball_index, np.concatenate(ball_gx), minlength=count.size)
    sum_y = np.bincount(ball_index, np.concatenate(ball_gy), minlength=count.size)
    sum_x, sum_y, count = (a.reshape(n_tiles, n_colours) for a in (sum_x, sum_y, count))
    seen = count.sum(axis=0)
    populated = seen > 0
    global_x = np.where(populated, sum_x.sum(axis=0) / np.where(populated, seen, 1.0), 0.0)
    global_y = np.where(populated, sum_y.sum(axis=0) / np.where(populated, seen, 1.0), 0.0)
    nearest = scipy.ndimage.distance_transform_edt(
        ~populated.reshape(bins, bins, bins), return_distances=False, return_indices=True
    )
    nearest_flat = np.ravel_multi_index(tuple(nearest), (bins, bins, bins)).ravel()
    global_x, global_y = global_x[nearest_flat], global_y[nearest_flat]
    lut_x = (sum_x + tile_prior_count * global_x) / (count + tile_prior_count)
    lut_y = (sum_y + tile_prior_count * global_y) / (count + tile_prior_count)
    lut = np.stack([lut_x, lut_y], axis=-1).astype(np.float32)
    return lut.reshape(tiles[0], tiles[1], bins, bins, bins, 2)


def _validate_presses(
    reference: Any, presses: Any, centers_px: Any, radii_px: Any, ball_px: float,
) -> tuple[list[np.ndarray], np.ndarray, np.ndarray]:
    _check_image("reference", reference, None, CalibrationError)
    shape = reference.shape[:2]
    as_stack = isinstance(presses, np.ndarray) and presses.ndim == 4
    as_list = isinstance(presses, Sequence) and not isinstance(presses, str | bytes)
    if as_stack or as_list:
        press_list = list(presses)
    else:
        raise CalibrationError(
            f"presses: expected a sequence of uint8 BGR images or an (N, H, W, 3) array, got "
            f"{getattr(presses, 'shape', type(presses).__name__)}"
        )
    if not press_list:
        raise CalibrationError("presses: empty; at least one ball press is needed")
    for i, press in enumerate(press_list):
        _check_image(f"presses[{i}]", press, shape, CalibrationError)
    n = len(press_list)
    if (share := clipped_share(reference)) > CLIPPED_SHARE:
        raise CalibrationError(f"reference: a channel clipped at 0 or 255 in {share:.0%} of its pixels (expected at "
                               f"most {CLIPPED_SHARE:.0%}): overexposed or dark")
    if clipped := clipped_presses(press_list, range(n)):
        raise CalibrationError(f"presses: {clipped}")
    centers = np.asarray(centers_px, dtype=np.float64)
    radii = np.asarray(radii_px, dtype=np.float64)
    if centers.shape != (n, 2):
        raise CalibrationError(f"centers_px: expected shape ({n}, 2) (x, y per press), got {centers.shape}")
    if radii.shape != (n,):
        raise CalibrationError(f"radii_px: expected shape ({n},), got {radii.shape}")
    if not (np.isfinite(centers).all() and np.isfinite(radii).all()):
        raise CalibrationError("centers_px/radii_px: contain NaN or infinite values")
    if (radii <= 0).any():
        raise CalibrationError(f"radii_px: expected positive contact radii, got {radii[radii <= 0][:5]}")
    if (radii >= ball_px).any():
        raise CalibrationError(
            f"radii_px: a contact radius of {radii.max():.1f} px is not smaller than the ball's "
            f"{ball_px:.1f} px; check ball_radius_m and pixel_pitch_m"
        )
    return press_list, centers, radii


def _real(value: object) -> bool:
    """Whether ``value`` is an int or float and not a bool (True is no count or size)."""
    return isinstance(value, int | float) and not isinstance(value, bool)


def fit_calibration(
    reference: np.ndarray,
    presses: Sequence[np.ndarray] | np.ndarray,
    centers_px: Sequence[Sequence[float]] | np.ndarray,
    radii_px: Sequence[float] | np.ndarray,
    *,
    ball_radius_m: float,
    pixel_pitch_m: float,
    bins: int = 48,
    tiles: tuple[int, int] = (3, 3),
    relative_range: float = 1.0,
    inside_fraction: float = 0.95,
    outside_fraction: float = 2.0,
    flat_fraction: float = 0.1,
    tile_prior_count: float = 5.0,
    flat_weight: float | None = DEFAULT_FLAT_WEIGHT,
    smoothing_px: float = DEFAULT_SMOOTHING_PX,
    refine_passes: int = 1,
    marker_masks: Sequence[np.ndarray] | None = None,
    provenance: Mapping[str, Any] | None = None,
    progress: bool = False,
) -> Calibration:
    """Fit the colour-to-gradient table from presses of a ball of known radius.

    Parameters
    ----------
    reference : ndarray
        uint8 BGR no-contact frame (H, W, 3).
    presses : sequence of ndarray or ndarray
        uint8 BGR frames of the pressed ball, each (H, W, 3), same pixel frame.
    centers_px : array_like
        (N, 2) contact centres ``(x, y)``, pixels.
    radii_px : array_like
        (N,) contact radii, pixels; each must be below the ball radius.
    ball_radius_m : float
        Ball radius, metres.
    pixel_pitch_m : float
        Gel surface per pixel, metres.
    bins : int
        Bins per colour channel.
    tiles : (int, int)
        Position tiles (rows, cols), each with its own table.
    relative_range : float
        Relative colour change covered by the bins.
    inside_fraction, outside_fraction : float
        Label pixels within ``inside_fraction * a`` with the sphere's gradient
        and beyond ``outside_fraction * a`` as flat; ``inside_fraction`` is at most 1.
    flat_fraction : float
        In (0, 1): pixels are labelled flat only beyond the ring where the
        press's mean colour change has fallen to this share of its peak
        (:func:`press_rings`).
    tile_prior_count : float
        Weight (in pixels) pulling each tile's bin towards the all-image bin.
    flat_weight : float or None
        Total weight of the flat-gel labels relative to the on-ball labels (module notes:
        "Flat-gel weight"): each flat pixel counts ``flat_weight * n_on_ball / n_flat``. None
        counts every flat pixel 1 (the calibration set's own mix, mostly flat).
    smoothing_px : float
        Gaussian sigma (pixels) of the frames and reference before their colour change is binned,
        here and at every lookup (module notes: "Smoothing"); 0 (the default) bins the 8-bit pixels
        as they are.
    refine_passes : int
        Times to re-measure the press circles (centre from the reconstruction
        with the current table, radius from :func:`press_rings`) and fit the
        table again (module notes); 0 uses the given circles as they are.
    marker_masks : sequence of ndarray, optional
        Per press, bool (H, W) marker-dot pixels (from
        :func:`~estimator.perception.markers.detect_markers`): left out of the
        table, and inpainted when the circles are re-measured.
    provenance : Mapping, optional
        Extra JSON-able facts recorded with the result.
    progress : bool
        Show a tqdm bar on stderr.

    Returns
    -------
    Calibration

    Raises
    ------
    CalibrationError
        An input has the wrong type, shape or dtype, the press list is empty,
        a radius is not positive or not below the ball's, the reference or a
        press is clipped at 0 or 255 over most of its pixels (listed by index),
        or an option is out of range; the message names the input.
    """
    for name, value in (("ball_radius_m", ball_radius_m), ("pixel_pitch_m", pixel_pitch_m),
                        ("relative_range", relative_range), ("inside_fraction", inside_fraction),
                        ("tile_prior_count", tile_prior_count)):
        if not (_real(value) and math.isfinite(value) and value > 0):
            raise CalibrationError(f"{name}: expected a positive number, got {value!r}")
    if not (_real(refine_passes) and isinstance(refine_passes, int) and refine_passes >= 0):
        raise CalibrationError(f"refine_passes: expected a non-negative integer, got {refine_passes!r}")
    if not (_real(bins) and isinstance(bins, int) and 2 <= bins <= 128):
        raise CalibrationError(f"bins: expected an integer in [2, 128], got {bins!r}")
    if not (_real(flat_fraction) and 0.0 < flat_fraction < 1.0):
        raise CalibrationError(f"flat_fraction: expected a value in (0, 1), got {flat_fraction!r}")
    if flat_weight is not None and not (_real(flat_weight) and math.isfinite(flat_weight) and flat_weight > 0):
        raise CalibrationError(f"flat_weight: expected a positive number or None, got {flat_weight!r}")
    if inside_fraction > 1.0:
        raise CalibrationError(f"inside_fraction: expected at most 1 (the contact circle's edge; beyond it the gel does "
                               f"not follow the ball), got {inside_fraction!r}")
    if not outside_fraction > inside_fraction:
        raise CalibrationError(
            f"outside_fraction = {outside_fraction!r}: expected more than inside_fraction = {inside_fraction!r}"
        )
    ball_px = ball_radius_m / pixel_pitch_m
    press_list, centers, radii = _validate_presses(reference, presses, centers_px, radii_px, ball_px)
    if not (isinstance(tiles, Sequence) and len(tiles) == 2
            and all(isinstance(t, int | np.integer) and not isinstance(t, bool) for t in tiles)):
        raise CalibrationError(f"tiles: expected (rows, cols), two integers, got {tiles!r}")
    tiles = tuple(int(t) for t in tiles)
    shape = reference.shape[:2]
    if min(tiles) < 1 or tiles[0] > shape[0] or tiles[1] > shape[1]:
        raise CalibrationError(f"tiles: expected (rows, cols) between 1 and the image size, got {tiles}")
    if not (isinstance(smoothing_px, int | float) and math.isfinite(smoothing_px) and smoothing_px >= 0):
        raise CalibrationError(f"smoothing_px: expected a number of pixels >= 0, got {smoothing_px!r}")
    options = dict(ball_px=ball_px, bins=bins, tiles=tiles, relative_range=float(relative_range),
                   inside_fraction=inside_fraction, outside_fraction=outside_fraction,
                   tile_prior_count=tile_prior_count, flat_weight=flat_weight, smoothing_px=float(smoothing_px))
    if marker_masks is None:
        masks = [None] * len(press_list)
    else:
        masks = list(marker_masks)
        if len(masks) != len(press_list) or any(
            not isinstance(m, np.ndarray) or m.dtype != bool or m.shape != shape for m in masks
        ):
            raise CalibrationError(
                f"marker_masks: expected {len(press_list)} bool arrays of shape {shape}, one per press"
            )

    def measured_rings(i: int, center: np.ndarray) -> PressRings | None:
        try:
            return press_rings(press_list[i], reference, center, max_radius_px=0.98 * ball_px,
                               flat_fraction=flat_fraction, marker_mask=masks[i])
        except CalibrationError:  # no visible change around that centre: keep what was given
            return None

    seeds = [measured_rings(i, center) for i, center in enumerate(centers)]
    flat_radii = np.array([0.0 if rings is None else rings.flat_px for rings in seeds])
    lut = _fit_table(reference, press_list, centers, radii, flat_radii, masks, **options)
    used_centers, used_radii = centers.copy(), radii.copy()
    refined = np.zeros(len(press_list), dtype=bool)
    bar = progress_bar(total=refine_passes * len(press_list), desc="refining press circles", unit="press",
               enabled=progress)
    for _ in range(refine_passes):
        current = Calibration(lut, shape, pixel_pitch_m, ball_radius_m, relative_range, float(smoothing_px))
        for i, press in enumerate(press_list):
            bar.update()
            x, y = used_centers[i]
            if not (-1.0 < x < shape[1] and -1.0 < y < shape[0]):
                continue  # a press centred off the image (fit_sphere refuses it): keep the circle given
            depth = reconstruct_depth(press, reference, current, marker_mask=masks[i])
            fit = fit_sphere(depth, pixel_pitch_m=pixel_pitch_m, center_px=tuple(used_centers[i]))
            if not fit or math.dist(fit.center_px, centers[i]) > radii[i]:
                continue
            rings = measured_rings(i, np.array(fit.center_px))
            if rings is not None:
                used_centers[i], used_radii[i], flat_radii[i] = fit.center_px, rings.contact_px, rings.flat_px
                refined[i] = True
        lut = _fit_table(reference, press_list, used_centers, used_radii, flat_radii, masks, **options)
    bar.close()
    record = {
        "created_utc": datetime.now(UTC).isoformat(timespec="seconds"),
        "n_presses_used": len(press_list),
        "press_centers_px": used_centers.round(2).tolist(),
        "press_radii_px": used_radii.round(2).tolist(),
        "press_flat_radii_px": flat_radii.round(2).tolist(),
        "circles_refined": refined.tolist(),
        "markers_masked": marker_masks is not None,
        "inside_fraction": inside_fraction,
        "outside_fraction": outside_fraction,
        "flat_fraction": flat_fraction,
        "tile_prior_count": tile_prior_count,
        "flat_weight": flat_weight,
        **dict(provenance or {}),
    }
    return Calibration(lut, shape, pixel_pitch_m, ball_radius_m, float(relative_range), float(smoothing_px), record)
