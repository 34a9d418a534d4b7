"""Fitting a calibration at its edges: option ranges, what is labelled, what each refinement pass uses and records."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from estimator.errors import CalibrationError
from estimator.perception import calibration_fit, fit_calibration
from estimator.perception.press_circles import PressRings, press_rings

PITCH = 0.0295e-3
BALL = 2.0e-3
BALL_PX = BALL / PITCH


@pytest.fixture(scope="module")
def few(gelsight_presses):
    """Two real GelSight presses: reference, list of images, (2, 2) centres and (2,) radii as float64 arrays."""
    p = gelsight_presses
    return p.reference, list(p.images[:2]), np.array(p.centers_px[:2], float), np.array(p.radii_px[:2], float)


def fit(few, **options):
    """A quick fit (no refinement, 16 bins) of the two presses, with ``options`` changed."""
    reference, presses, centers, radii = few
    args = {"presses": presses, "centers_px": centers.copy(), "radii_px": radii.copy(), "ball_radius_m": BALL,
            "pixel_pitch_m": PITCH, "refine_passes": 0, "bins": 16, **options}
    return fit_calibration(reference, args.pop("presses"), args.pop("centers_px"), args.pop("radii_px"), **args)


def disks(few, scale: float = 1.0) -> list[np.ndarray]:
    reference, _, centers, radii = few
    rows, cols = np.indices(reference.shape[:2])
    return [(cols - x) ** 2 + (rows - y) ** 2 < (scale * r) ** 2 for (x, y), r in zip(centers, radii, strict=True)]


# --------------------------------------------------------------------------- options out of range


@pytest.mark.parametrize(("options", "match"), [
    ({"inside_fraction": 0.0}, "inside_fraction: expected a positive number"),
    ({"inside_fraction": 1.5, "outside_fraction": 3.0}, "inside_fraction"),
    ({"tile_prior_count": 0.0}, "tile_prior_count: expected a positive number"),
    ({"relative_range": 0.0}, "relative_range: expected a positive number"),
    ({"relative_range": float("inf")}, "relative_range"),
    ({"flat_fraction": 0.0}, "flat_fraction: expected a value in"),
    ({"flat_fraction": 1.0}, "flat_fraction: expected a value in"),
    ({"outside_fraction": 0.95}, "outside_fraction = 0.95: expected more than inside_fraction"),
    ({"tiles": (1, 641)}, "tiles: expected"),  # the frames are 640 columns
    ({"tiles": None}, "tiles: expected"),
    ({"tiles": (2.5, 3)}, "tiles: expected"),
    ({"tiles": (1, 2, 3)}, "tiles: expected"),
    ({"refine_passes": True}, "refine_passes: expected a non-negative integer, got True"),  # True is no count
    ({"flat_weight": True}, "flat_weight: expected a positive number or None, got True"),
    ({"tile_prior_count": True}, "tile_prior_count: expected a positive number, got True"),
    ({"smoothing_px": float("nan")}, "smoothing_px"),
    ({"smoothing_px": float("inf")}, "smoothing_px"),
    ({"presses": "images"}, "presses: expected a sequence"),
    ({"presses": b"images"}, "presses: expected a sequence"),
])
def test_an_option_out_of_range_is_refused_with_its_name(few, options, match):
    with pytest.raises(CalibrationError, match=match):
        fit(few, **options)


@pytest.mark.parametrize(("change", "match"), [
    (lambda c, r: (np.zeros((2, 3)), r), r"centers_px: expected shape \(2, 2\)"),
    (lambda c, r: (c, r[:, None]), r"radii_px: expected shape \(2,\)"),
    (lambda c, r: (c, np.append(r, 60.0)), r"radii_px: expected shape \(2,\)"),
    (lambda c, r: (c, np.array([60.0, np.nan])), "NaN or infinite"),
    (lambda c, r: (c, np.array([60.0, np.inf])), "NaN or infinite"),
    (lambda c, r: (c, np.array([60.0, BALL_PX])), "not smaller than the ball's"),
])
def test_a_circle_of_the_wrong_shape_or_size_is_refused_with_its_name(few, change, match):
    centers, radii = change(few[2], few[3])
    with pytest.raises(CalibrationError, match=match):
        fit(few, centers_px=centers, radii_px=radii)


@pytest.mark.parametrize(("masks", "match"), [
    (lambda shape: [np.zeros(shape, np.uint8)] * 2, "marker_masks"),
    (lambda shape: [np.zeros((shape[0], shape[1] - 1), bool)] * 2, "marker_masks"),
    (lambda shape: [np.zeros(shape, bool)] * 3, "marker_masks"),
])
def test_marker_masks_of_the_wrong_kind_are_refused(few, masks, match):
    with pytest.raises(CalibrationError, match=match):
        fit(few, marker_masks=masks(few[0].shape[:2]))


def test_a_stacked_array_of_presses_fits_as_the_list_does(few):
    np.testing.assert_array_equal(fit(few, presses=np.stack(few[1])).lut, fit(few).lut)


# --------------------------------------------------------------------------- what the table holds


def test_ball_slopes_point_away_from_the_press_centre(few):
    reference, presses, centers, _ = few
    gx, gy = fit(few).gradients(presses[0], reference)
    rows, cols = np.indices(reference.shape[:2])
    (cx, cy), inside = centers[0], disks(few, 0.8)[0]
    assert gx[inside & (cols < cx - 10)].mean() > 0.2 > -0.2 > gx[inside & (cols > cx + 10)].mean()
    assert gy[inside & (rows < cy - 10)].mean() > 0.2 > -0.2 > gy[inside & (rows > cy + 10)].mean()


def synthetic_press(n_flat_left: int):
    """A 48 x 48 press of a 10 px ball, contact radius 8 px at (20, 20): the disk's left half one colour change,
    its right half another, ``n_flat_left`` flat-gel pixels (beyond 18 px) the left half's change, the rest none."""
    reference = np.full((48, 48, 3), 100, np.uint8)
    press = reference.copy()
    rows, cols = np.indices((48, 48))
    r2 = (cols - 20.0) ** 2 + (rows - 20.0) ** 2
    press[(r2 < 64) & (cols <= 20)] = 120
    press[(r2 < 64) & (cols > 20)] = 80
    flat_left = np.zeros((48, 48), bool)
    flat_left.ravel()[np.flatnonzero((r2 > 18**2).ravel())[:n_flat_left]] = True
    press[flat_left] = 120
    return reference, press, cols, r2, flat_left


def synthetic_fit(reference, press, **options):
    return fit_calibration(reference, [press], [[20.0, 20.0]], [8.0], ball_radius_m=10 * PITCH, pixel_pitch_m=PITCH,
                           tiles=(1, 1), bins=16, refine_passes=0, **options)


@pytest.mark.parametrize("flat_weight", [15.0, 1.0, None])
@pytest.mark.parametrize("n_flat_left", [0, 60])
def test_a_bin_holds_the_mean_ball_slope_with_flat_labels_weighted_as_documented(flat_weight, n_flat_left):
    reference, press, cols, r2, _ = synthetic_press(n_flat_left)
    gx, gy = synthetic_fit(reference, press, flat_weight=flat_weight).gradients(press, reference)
    on_ball = r2 < (0.95 * 8) ** 2
    left = on_ball & (cols <= 20)
    slopes = -(cols - 20.0)[left] / np.sqrt(10.0**2 - r2[left])  # dz/dx of the ball's cap
    n_flat = (r2 > (2.0 * 8) ** 2).sum()  # beyond outside_fraction * a (the flat ring is nearer)
    per_flat = 1.0 if flat_weight is None else flat_weight * on_ball.sum() / n_flat
    assert gx[20, 15] == pytest.approx(slopes.sum() / (left.sum() + per_flat * n_flat_left), rel=1e-5)
    assert abs(gy[20, 15]) < 1e-6  # the left half is symmetric about the centre row


def test_marker_pixels_on_the_flat_gel_are_not_labelled_flat():
    reference, press, cols, r2, flat_left = synthetic_press(60)
    gx, _ = synthetic_fit(reference, press, marker_masks=[flat_left]).gradients(press, reference)
    left = (r2 < (0.95 * 8) ** 2) & (cols <= 20)
    assert gx[20, 15] == pytest.approx((-(cols - 20.0)[left] / np.sqrt(100.0 - r2[left])).mean(), rel=1e-5)


def test_tiles_keep_their_rows_and_columns(few):
    calibration = fit(few, tiles=(2, 3))
    assert calibration.tiles == (2, 3) and calibration.lut.shape[:2] == (2, 3)


def test_colours_never_seen_read_the_nearest_seen_bin_not_zero(few):
    lut = fit(few, tile_prior_count=1e9).lut
    assert (lut == 0).mean() < 0.3


def test_without_flat_labels_the_flat_weight_leaves_a_finite_table(few):
    lut = fit(few, outside_fraction=1e6).lut
    assert np.isfinite(lut).all() and np.abs(lut).max() > 0.05


def test_relative_range_and_smoothing_reach_the_table_and_the_result(few):
    base = fit(few)
    ranged, smoothed = fit(few, relative_range=0.5), fit(few, smoothing_px=1.0)
    assert ranged.relative_range == 0.5 and not np.array_equal(ranged.lut, base.lut)
    assert smoothed.smoothing_px == 1.0 and not np.array_equal(smoothed.lut, base.lut)


# --------------------------------------------------------------------------- refinement


def test_the_callers_circles_are_not_changed_by_refinement(few):
    reference, presses, centers, radii = few
    given_centers, given_radii = centers.copy(), radii.copy()
    calibration = fit_calibration(reference, presses, given_centers, given_radii, ball_radius_m=BALL,
                                  pixel_pitch_m=PITCH, refine_passes=1, bins=16)
    assert any(calibration.provenance["circles_refined"])
    np.testing.assert_array_equal(given_centers, centers)
    np.testing.assert_array_equal(given_radii, radii)


def _spy_refinement(monkeypatch, fits):
    """Replace fit_sphere by ``fits`` (an iterator of results); record what each pass reconstructs with."""
    seen = SimpleNamespace(calibrations=[], masks=[], sphere_centres=[], ring_masks=[])
    real_reconstruct, real_rings = calibration_fit.reconstruct_depth, calibration_fit.press_rings

    def reconstruct(press, reference, calibration, *, marker_mask=None):
        seen.calibrations.append(calibration)
        seen.masks.append(marker_mask)
        return real_reconstruct(press, reference, calibration, marker_mask=marker_mask)

    def sphere(depth, *, pixel_pitch_m, center_px):
        seen.sphere_centres.append(center_px)
        return next(fits)

    def rings(*args, marker_mask=None, **kw):
        seen.ring_masks.append(marker_mask)
        return real_rings(*args, marker_mask=marker_mask, **kw)

    monkeypatch.setattr(calibration_fit, "reconstruct_depth", reconstruct)
    monkeypatch.setattr(calibration_fit, "fit_sphere", sphere)
    monkeypatch.setattr(calibration_fit, "press_rings", rings)
    return seen


def test_each_pass_reconstructs_with_the_table_of_the_pass_before_from_the_moved_centre(few, monkeypatch):
    _, _, centers, _ = few
    step = np.array([3.0, 0.0])
    fits = iter([SimpleNamespace(center_px=tuple(centers[0] + step)), None,
                 SimpleNamespace(center_px=tuple(centers[0] + 2 * step)), None])
    seen = _spy_refinement(monkeypatch, fits)
    record = fit(few, refine_passes=2, smoothing_px=0.5).provenance
    assert len(seen.calibrations) == 4
    assert not np.array_equal(seen.calibrations[0].lut, seen.calibrations[2].lut)
    assert all(c.smoothing_px == 0.5 for c in seen.calibrations)
    assert seen.sphere_centres[2] == pytest.approx(tuple(centers[0] + step))
    assert record["press_centers_px"][0] == pytest.approx(list(centers[0] + 2 * step))
    assert record["circles_refined"] == [True, False]  # a press with no sphere fit keeps the circle given


def test_a_centre_drifting_over_passes_further_than_the_given_radius_is_discarded(few, monkeypatch):
    _, _, centers, radii = few
    step = np.array([0.6 * radii[0], 0.0])  # each pass within the radius of the last centre, two passes beyond
    fits = iter([SimpleNamespace(center_px=tuple(centers[0] + step)), None,
                 SimpleNamespace(center_px=tuple(centers[0] + 2 * step)), None])
    _spy_refinement(monkeypatch, fits)
    record = fit(few, refine_passes=2).provenance
    assert record["press_centers_px"][0] == pytest.approx(list(centers[0] + step), abs=0.01)


def test_the_drift_is_measured_against_the_given_radius_not_the_remeasured_one(few, monkeypatch):
    _, _, centers, radii = few
    far = tuple(centers[0] + [0.9 * radii[0], 0.0])  # within the given radius, beyond the re-measured one
    _spy_refinement(monkeypatch, iter([SimpleNamespace(center_px=tuple(centers[0])), None,
                                       SimpleNamespace(center_px=far), None]))
    around = []

    def rings(image, reference, center, **kw):  # the seeds' flat rings at 80 px, the re-measured ones at 90 px
        around.append(tuple(center))
        return PressRings(contact_px=20.5, flat_px=80.0 if len(around) <= 2 else 90.0)

    monkeypatch.setattr(calibration_fit, "press_rings", rings)
    record = fit(few, refine_passes=2).provenance
    assert record["press_centers_px"][0] == pytest.approx(list(far), abs=0.01)
    assert around[-1] == pytest.approx(far)  # the rings are measured around the fitted centre
    assert record["press_radii_px"] == [20.5, pytest.approx(radii[1])]
    assert record["press_flat_radii_px"] == [90.0, 80.0]


def test_refinement_reconstructs_and_measures_rings_with_each_press_marker_mask(few, monkeypatch):
    _, _, centers, _ = few
    masks = [np.zeros(few[0].shape[:2], bool) for _ in range(2)]
    masks[0][:5, :5] = True
    seen = _spy_refinement(monkeypatch, iter([SimpleNamespace(center_px=tuple(centers[0])), None]))
    record = fit(few, refine_passes=1, marker_masks=masks).provenance
    assert [m is masks[i] for i, m in enumerate(seen.masks)] == [True, True]
    assert all(any(m is mask for mask in masks) for m in seen.ring_masks) and len(seen.ring_masks) == 3
    assert record["markers_masked"] is True and fit(few).provenance["markers_masked"] is False


def test_a_press_whose_rings_vanish_at_the_fitted_centre_keeps_its_circle(few, monkeypatch):
    _, _, centers, radii = few
    near = SimpleNamespace(center_px=tuple(centers[0] + 2.0))
    monkeypatch.setattr(calibration_fit, "fit_sphere", lambda depth, **kw: near)
    real = calibration_fit.press_rings
    calls = []

    def rings(*args, **kw):  # the seeds are measured; every ring around a fitted centre is "no press visible"
        calls.append(args)
        if len(calls) > 2:
            raise CalibrationError("image: no press visible")
        return real(*args, **kw)

    monkeypatch.setattr(calibration_fit, "press_rings", rings)
    record = fit(few, refine_passes=1).provenance
    assert record["circles_refined"] == [False, False]
    np.testing.assert_allclose(record["press_centers_px"], centers, atol=0.01)


def test_a_press_centred_right_of_the_image_height_is_still_refined(few, monkeypatch):
    reference, _, centers, _ = few
    assert reference.shape[:2] == (480, 640)
    moved = centers.copy()
    moved[1, 0] = 520.0  # inside the 640 columns, beyond the 480 rows
    seen = _spy_refinement(monkeypatch, iter([None, None]))
    fit(few, centers_px=moved, refine_passes=1)
    assert len(seen.sphere_centres) == 2


def test_the_seed_flat_rings_are_recorded_without_refinement(few):
    reference, presses, centers, _ = few
    record = fit(few).provenance
    expected = [press_rings(press, reference, center, max_radius_px=0.98 * BALL_PX, flat_fraction=0.1).flat_px
                for press, center in zip(presses, centers, strict=True)]
    assert record["press_flat_radii_px"] == pytest.approx(expected, abs=0.01)
    assert record["circles_refined"] == [False, False]
