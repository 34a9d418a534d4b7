"""Poisson integration, depth reconstruction guarantees and the sphere fit."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from estimator.errors import PerceptionError
from estimator.perception import Calibration, fit_sphere, poisson_depth, reconstruct_depth

PITCH = 1e-3 / 11


def bump(shape=(60, 80), *, center=(41.3, 27.8), sigma=7.0, height_m=0.4e-3):
    rows, cols = np.indices(shape, dtype=np.float64)
    return height_m * np.exp(-((cols - center[0]) ** 2 + (rows - center[1]) ** 2) / (2 * sigma**2))


def cap(shape, *, center, ball_m, contact_m, pitch=PITCH):
    """A rigid ball pressed into the gel, with the gel relaxing outside the contact.

    Inside: the sphere. Outside: the half-space (Hertz) surface, whose slope is
    continuous at the contact edge and largest there.
    """
    rows, cols = np.indices(shape, dtype=np.float64)
    r = np.hypot(cols - center[0], rows - center[1]) * pitch
    delta = contact_m**2 / ball_m
    ro = np.maximum(r, contact_m)
    outside = delta / (np.pi * contact_m**2) * (
        (2 * contact_m**2 - ro**2) * np.arcsin(contact_m / ro) + ro * contact_m * np.sqrt(1 - contact_m**2 / ro**2)
    )
    # The exact sphere inside, lifted to meet the Hertz rim (delta / 2) at r = a.
    sphere = np.sqrt(np.maximum(ball_m**2 - r**2, 0)) - np.sqrt(ball_m**2 - contact_m**2)
    return np.where(r <= contact_m, sphere + delta / 2, outside)


def rigid_cap(shape, *, center, ball_m, contact_m, pitch=PITCH):
    """A ball pressed into a gel that stays flat outside the contact: steepest at the rim, where the depth is 0."""
    rows, cols = np.indices(shape, dtype=np.float64)
    r = np.hypot(cols - center[0], rows - center[1]) * pitch
    inside = np.sqrt(np.maximum(ball_m**2 - r**2, 0)) - np.sqrt(ball_m**2 - contact_m**2)
    return np.where(r <= contact_m, inside, 0.0)


def lowest_odd_mode(shape, height_m=0.3e-3):
    """The lowest DST-II mode: exactly zero half a pixel outside every side, steep at the border."""
    rows, cols = np.indices(shape, dtype=np.float64)
    return height_m * np.sin(np.pi * (rows + 0.5) / shape[0]) * np.sin(np.pi * (cols + 0.5) / shape[1])


def odd_central_gradients(surface):
    """Central differences (dimensionless) of a surface extended oddly about the half-pixel border."""
    ext = np.pad(surface, 1)
    ext[0], ext[-1] = -ext[1], -ext[-2]
    ext[:, 0], ext[:, -1] = -ext[:, 1], -ext[:, -2]
    gx = (ext[1:-1, 2:] - ext[1:-1, :-2]) / (2 * PITCH)
    gy = (ext[2:, 1:-1] - ext[:-2, 1:-1]) / (2 * PITCH)
    return gx, gy


def test_exact_gradients_integrate_back_to_the_surface():
    surface = bump()
    gy, gx = np.gradient(surface / PITCH)  # central differences, dimensionless
    depth = poisson_depth(gx, gy, pixel_pitch_m=PITCH)
    assert depth.dtype == np.float64
    np.testing.assert_allclose(depth, surface, atol=1e-3 * surface.max())


def test_a_surface_sloping_at_the_border_integrates_back_exactly():
    # The divergence must keep the one-sided differences of the edge rows and columns.
    surface = lowest_odd_mode((40, 56))
    gx, gy = odd_central_gradients(surface)
    assert abs(gx[:, 0]).max() > 0.1 * abs(gx).max()  # the border slope is not negligible
    depth = poisson_depth(gx, gy, pixel_pitch_m=PITCH)
    np.testing.assert_allclose(depth, surface, atol=1e-6 * surface.max())


def test_float32_in_float32_out_and_zero_gradients_give_zero_depth():
    zeros = np.zeros((25, 35), np.float32)
    depth = poisson_depth(zeros, zeros, pixel_pitch_m=PITCH)
    assert depth.dtype == np.float32
    assert not depth.any()


def test_depth_is_positive_into_the_gel():
    # Depth growing to the right: dz/dx > 0 everywhere inside a ramp that returns at the border.
    surface = bump(sigma=10.0)
    gy, gx = np.gradient(surface / PITCH)
    depth = poisson_depth(gx.astype(np.float32), gy.astype(np.float32), pixel_pitch_m=PITCH)
    assert depth.max() > 0.9 * surface.max()
    assert np.unravel_index(np.argmax(depth), depth.shape) == np.unravel_index(np.argmax(surface), surface.shape)


@pytest.mark.parametrize(("gx", "gy", "pitch", "match"), [
    (np.zeros((5, 5)), np.zeros((5, 6)), PITCH, "must match"),
    (np.zeros((5, 5), np.float32), np.zeros((5, 5)), PITCH, "must match"),
    (np.zeros((5, 5), np.int32), np.zeros((5, 5), np.int32), PITCH, "gx"),
    (np.zeros(5), np.zeros(5), PITCH, "gx"),
    (np.full((5, 5), np.nan), np.zeros((5, 5)), PITCH, "NaN"),
    (np.zeros((5, 5)), np.zeros((5, 5)), 0.0, "pixel_pitch_m"),
    (np.zeros((5, 5)), np.zeros((5, 5)), float("inf"), "pixel_pitch_m"),
    (np.zeros((5, 5)), np.zeros((5, 5)), -PITCH, "pixel_pitch_m"),  # would flip the depth's sign
    (np.zeros((5, 5)), np.zeros((5, 5)), -1.0, "pixel_pitch_m"),
    (np.zeros((2, 8)), np.zeros((2, 8)), PITCH, "3 x 3"),
    (np.zeros((8, 2)), np.zeros((8, 2)), PITCH, "3 x 3"),
])
def test_bad_gradients_are_refused(gx, gy, pitch, match):
    with pytest.raises(PerceptionError, match=match):
        poisson_depth(gx, gy, pixel_pitch_m=pitch)


def test_unpressed_real_frame_reconstructs_flat(gelsight_presses, gelsight_calibration):
    rng = np.random.default_rng(7)
    ref = gelsight_presses.reference
    noisy = np.clip(ref + rng.normal(0.0, 2.0, ref.shape), 0, 255).astype(np.uint8)
    for frame in (ref, noisy):
        depth = reconstruct_depth(frame, ref, gelsight_calibration)
        assert depth.dtype == np.float32 and depth.shape == ref.shape[:2]
        # Camera noise of 2 levels stays far below the 20 um depth resolution of the settings.
        assert np.abs(depth).max() < 20e-6


def test_reconstruct_refuses_frames_of_another_shape(gelsight_presses, gelsight_calibration):
    small = gelsight_presses.reference[:100, :100]
    with pytest.raises(PerceptionError, match="frame"):
        reconstruct_depth(small, small, gelsight_calibration)
    with pytest.raises(PerceptionError, match="reference"):
        reconstruct_depth(gelsight_presses.reference, gelsight_presses.reference.astype(np.float32),
                          gelsight_calibration)


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(seed=st.integers(0, 2**32 - 1), style=st.sampled_from(["uniform", "extreme", "near_reference"]))
def test_random_frames_never_give_nan(gelsight_presses, gelsight_calibration, seed, style):
    rng = np.random.default_rng(seed)
    ref = gelsight_presses.reference
    if style == "uniform":
        frame = rng.integers(0, 256, ref.shape, dtype=np.uint8)
        reference = rng.integers(0, 256, ref.shape, dtype=np.uint8)
    elif style == "extreme":  # saturated and black pixels, black reference pixels
        frame = rng.choice(np.array([0, 255], np.uint8), ref.shape)
        reference = rng.choice(np.array([0, 1, 255], np.uint8), ref.shape)
    else:
        frame = np.clip(ref + rng.integers(-40, 41, ref.shape), 0, 255).astype(np.uint8)
        reference = ref
    depth = reconstruct_depth(frame, reference, gelsight_calibration)
    assert np.isfinite(depth).all()


@settings(max_examples=30, deadline=None)
@given(lut_seed=st.integers(0, 2**32 - 1), frame_seed=st.integers(0, 2**32 - 1),
       scale=st.floats(1e-3, 1e3))
def test_any_finite_table_gives_finite_depth(lut_seed, frame_seed, scale):
    lut = (np.random.default_rng(lut_seed).standard_normal((2, 2, 6, 6, 6, 2)) * scale).astype(np.float32)
    calibration = Calibration(lut, (24, 32), PITCH, 2e-3)
    rng = np.random.default_rng(frame_seed)
    frame, reference = rng.integers(0, 256, (2, 24, 32, 3), dtype=np.uint8)
    assert np.isfinite(reconstruct_depth(frame, reference, calibration)).all()


# --------------------------------------------------------------------------- sphere fit


@pytest.mark.parametrize(("ball_mm", "contact_mm", "center"), [
    (2.0, 1.2, (170.4, 120.7)),
    (2.0, 1.7, (90.0, 140.2)),
    (5.0, 2.0, (200.6, 110.1)),
])
def test_sphere_fit_recovers_radius_centre_and_contact(ball_mm, contact_mm, center):
    depth = cap((250, 350), center=center, ball_m=ball_mm * 1e-3, contact_m=contact_mm * 1e-3)
    fit = fit_sphere(depth.astype(np.float32), pixel_pitch_m=PITCH)
    assert fit, fit.reason
    assert fit.radius_m == pytest.approx(ball_mm * 1e-3, rel=0.02)
    assert np.hypot(*(np.array(fit.center_px) - center)) < 0.5
    assert fit.contact_radius_m == pytest.approx(contact_mm * 1e-3, abs=2 * PITCH)
    assert fit.apex_depth_m == pytest.approx(depth.max(), rel=0.02)
    assert fit.rms_residual_m < 2e-6


def test_contact_circle_of_a_cap_without_rim_reaches_its_edge():
    # The search for the contact circle runs down to a tenth of the peak, not to half of it.
    contact_m = 1.5e-3
    depth = rigid_cap((120, 140), center=(70.3, 60.6), ball_m=3e-3, contact_m=contact_m)
    fit = fit_sphere(depth.astype(np.float32), pixel_pitch_m=PITCH)
    assert fit, fit.reason
    assert fit.radius_m == pytest.approx(3e-3, rel=0.02)
    assert fit.contact_radius_m == pytest.approx(contact_m, abs=3 * PITCH)


def test_sphere_fitted_with_its_centre_off_the_image_is_a_falsy_result():
    depth = rigid_cap((120, 140), center=(-3.0, 60.0), ball_m=3e-3, contact_m=1.5e-3)
    fit = fit_sphere(depth.astype(np.float32), pixel_pitch_m=PITCH)
    assert not fit
    assert "outside the image" in fit.reason
    assert fit.center_px is None


def test_contact_circle_cut_by_the_corner_to_a_few_pixels_is_too_small():
    # About 10 pixels lie inside the circle: too few for a 4-parameter fit.
    depth = cap((40, 50), center=(0.3, 0.3), ball_m=1e-3, contact_m=4 * PITCH)
    fit = fit_sphere(depth.astype(np.float32), pixel_pitch_m=PITCH, smooth_px=0.0)
    assert not fit
    assert "contact circle too small" in fit.reason


def test_sphere_fit_reports_no_contact_as_a_falsy_result():
    fit = fit_sphere(np.zeros((50, 60), np.float32), pixel_pitch_m=PITCH)
    assert not fit
    assert "no indentation" in fit.reason
    assert fit.radius_m is None
    nan = np.zeros((50, 60))
    nan[3, 4] = np.nan
    assert "NaN" in fit_sphere(nan, pixel_pitch_m=PITCH).reason


def test_sphere_fit_refuses_a_non_depth_input():
    with pytest.raises(PerceptionError, match="depth"):
        fit_sphere(np.zeros((5, 5), np.uint8), pixel_pitch_m=PITCH)


def test_gradients_whose_depth_overflows_are_refused():
    huge = np.random.default_rng(0).normal(size=(50, 50)) * 1e306  # finite, but their sums are not
    with pytest.raises(PerceptionError, match="overflows"):
        poisson_depth(huge, np.zeros((50, 50)), pixel_pitch_m=PITCH)
    with pytest.raises(PerceptionError, match="float32"):
        poisson_depth((huge * 1e-270).astype(np.float32), np.zeros((50, 50), np.float32), pixel_pitch_m=PITCH)


@pytest.mark.parametrize(("depth", "options", "named"), [
    (np.zeros((0, 5)), {}, "depth"),
    (np.full((1, 1), 1e-3), {}, "depth"),
    (np.zeros((2, 40)), {}, "depth"),
    (bump(), {"pixel_pitch_m": None}, "pixel_pitch_m"),
    (bump(), {"pixel_pitch_m": "1e-4"}, "pixel_pitch_m"),
    (bump(), {"smooth_px": float("nan")}, "smooth_px"),
    (bump(), {"smooth_px": -1.0}, "smooth_px"),
    (bump(), {"smooth_px": None}, "smooth_px"),
    (bump(), {"min_depth_m": float("nan")}, "min_depth_m"),
])
def test_sphere_fit_refuses_maps_too_small_and_bad_options_by_name(depth, options, named):
    with pytest.raises(PerceptionError, match=named):
        fit_sphere(depth, **{"pixel_pitch_m": PITCH, **options})


def test_sphere_fit_of_numbers_beyond_the_float_range_is_a_falsy_result():
    fit = fit_sphere(bump() * 1e300, pixel_pitch_m=PITCH)
    assert not fit and "too large" in fit.reason
    fit = fit_sphere(bump() * 1e300, pixel_pitch_m=1e306)  # the sphere in metres overflows
    assert not fit and "float range" in fit.reason
    assert fit_sphere(bump(), pixel_pitch_m=np.float32(PITCH))  # a numpy scalar pitch is a number
