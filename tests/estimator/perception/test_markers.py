"""Marker dots: detection on real press images with printed-on dots, and inpainting."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from estimator.errors import CalibrationError, PerceptionError
from estimator.perception import (
    detect_markers,
    fit_calibration,
    fit_sphere,
    inpaint_markers,
    reconstruct_depth,
)

SPACING_PX, DOT_RADIUS_PX = 24, 3


def dot_mask(shape, offset):
    """Dots on a regular grid (as printed on a marker gel), shifted by ``offset`` px."""
    mask = np.zeros(shape, np.uint8)
    for y in range(12 + offset[1], shape[0] - 6, SPACING_PX):
        for x in range(12 + offset[0], shape[1] - 6, SPACING_PX):
            cv2.circle(mask, (x, y), DOT_RADIUS_PX, 1, -1)
    return mask.astype(bool)


def with_dots(image, mask, darkness=0.35):
    out = image.copy()
    out[mask] = (out[mask] * darkness).astype(np.uint8)
    return out


@pytest.fixture(scope="module")
def marked(gelsight_presses):
    """A held-out real press and its reference, each with dots; the frame's dots have moved."""
    shape = gelsight_presses.reference.shape[:2]
    ref_dots, frame_dots = dot_mask(shape, (0, 0)), dot_mask(shape, (3, 2))
    press = gelsight_presses.images[1]
    return {
        "press": press, "reference": gelsight_presses.reference,
        "marked_press": with_dots(press, frame_dots), "marked_reference": with_dots(gelsight_presses.reference, ref_dots),
        "dots": ref_dots | frame_dots,
    }


def test_dots_of_frame_and_reference_are_found(marked):
    mask = detect_markers(marked["marked_press"], marked["marked_reference"])
    dots = marked["dots"]
    assert mask.dtype == bool and mask.shape == dots.shape
    assert (mask & dots).sum() >= 0.95 * dots.sum()
    near_dots = cv2.dilate(dots.view(np.uint8), np.ones((7, 7), np.uint8)).view(bool)
    assert (mask & ~near_dots).sum() < 0.002 * mask.size


def test_a_press_without_dots_is_not_taken_for_markers(marked):
    mask = detect_markers(marked["press"], marked["reference"])
    assert mask.mean() < 0.002


def test_inpainting_restores_the_reconstruction(marked, gelsight_calibration):
    clean = reconstruct_depth(marked["press"], marked["reference"], gelsight_calibration)
    mask = detect_markers(marked["marked_press"], marked["marked_reference"])
    filled = reconstruct_depth(marked["marked_press"], marked["marked_reference"], gelsight_calibration,
                               marker_mask=mask)
    raw = reconstruct_depth(marked["marked_press"], marked["marked_reference"], gelsight_calibration)
    error_filled = np.sqrt(np.mean((filled - clean) ** 2))
    error_raw = np.sqrt(np.mean((raw - clean) ** 2))
    assert error_filled < 0.5 * error_raw
    pitch = gelsight_calibration.pixel_pitch_m
    assert fit_sphere(filled, pixel_pitch_m=pitch).radius_m == pytest.approx(
        fit_sphere(clean, pixel_pitch_m=pitch).radius_m, rel=0.03)


@pytest.mark.parametrize("image", [
    np.full((40, 50, 3), 120, np.uint8), np.full((40, 50), 120, np.uint8), np.full((40, 50), 0.5, np.float32),
])
def test_inpaint_keeps_shape_dtype_and_unmasked_pixels(image):
    image = image.copy()
    image[10:13, 20:23] = 0
    mask = np.zeros((40, 50), bool)
    mask[9:14, 19:24] = True
    out = inpaint_markers(image, mask)
    assert out.shape == image.shape and out.dtype == image.dtype
    np.testing.assert_array_equal(out[~mask], image[~mask])
    assert out[11, 21].min() > 0.4 * image.max()


@pytest.mark.parametrize(("frame", "mask", "match"), [
    (np.zeros((10, 10, 3), np.uint8), np.zeros((10, 11), bool), "mask"),
    (np.zeros((10, 10, 3), np.uint8), np.zeros((10, 10), np.uint8), "mask"),
    (np.zeros((10, 10, 3), np.float32), np.zeros((10, 10), bool), "frame"),
    (np.zeros((10, 10, 4), np.uint8), np.zeros((10, 10), bool), "frame"),
])
def test_inpaint_refuses_bad_inputs(frame, mask, match):
    with pytest.raises(PerceptionError, match=match):
        inpaint_markers(frame, mask)


def test_detect_refuses_mismatched_images():
    with pytest.raises(PerceptionError, match="reference"):
        detect_markers(np.zeros((10, 10, 3), np.uint8), np.zeros((10, 12, 3), np.uint8))
    with pytest.raises(PerceptionError, match="min_darkness"):
        detect_markers(np.zeros((10, 10, 3), np.uint8), np.zeros((10, 10, 3), np.uint8), min_darkness=1.5)


def test_only_dot_shaped_dark_blobs_are_markers():
    image = np.full((60, 80, 3), 150, np.uint8)
    cv2.circle(image, (20, 20), 3, (40, 40, 40), -1)  # a dot
    cv2.line(image, (40, 10), (40, 50), (40, 40, 40), 2)  # a scratch, longer than a dot
    cv2.ellipse(image, (60, 40), (12, 12), 0, -60, 60, (40, 40, 40), 2)  # a thin crescent (press rim)
    mask = detect_markers(image, np.full_like(image, 150), dilate_px=0)
    assert mask[20, 20] and mask[17:24, 17:24].sum() >= 25
    assert not mask[:, 35:].any()


def test_calibration_leaves_marker_pixels_out(gelsight_presses):
    shape = gelsight_presses.reference.shape[:2]
    args = (gelsight_presses.reference, gelsight_presses.images[:2], gelsight_presses.centers_px[:2],
            gelsight_presses.radii_px[:2])
    with pytest.raises(CalibrationError, match="marker_masks"):
        fit_calibration(*args, ball_radius_m=2e-3, pixel_pitch_m=0.0295e-3, refine_passes=0,
                        marker_masks=[np.zeros(shape, bool)])
    everything = [np.ones(shape, bool)] * 2
    with pytest.raises(CalibrationError, match="no press circle covers"):
        fit_calibration(*args, ball_radius_m=2e-3, pixel_pitch_m=0.0295e-3, refine_passes=0,
                        marker_masks=everything)


def test_reconstruct_refuses_a_bad_marker_mask(gelsight_presses, gelsight_calibration):
    ref = gelsight_presses.reference
    for mask in ([[True]], np.zeros(ref.shape[:2], np.uint8), np.zeros((10, 10), bool)):
        with pytest.raises(PerceptionError, match="mask"):
            reconstruct_depth(ref, ref, gelsight_calibration, marker_mask=mask)
    # An empty mask changes nothing.
    empty = np.zeros(ref.shape[:2], bool)
    np.testing.assert_array_equal(reconstruct_depth(gelsight_presses.images[3], ref, gelsight_calibration,
                                                    marker_mask=empty),
                                  reconstruct_depth(gelsight_presses.images[3], ref, gelsight_calibration))


def test_a_thin_scratch_that_fits_the_dot_size_is_not_a_marker():
    # A one-pixel diagonal fits an 11 px box but fills far less than half of it.
    image = np.full((60, 80, 3), 180, np.uint8)
    for i in range(9):
        image[20 + i, 30 + i] = 60
    assert not detect_markers(image, np.full_like(image, 180), dilate_px=0).any()


@pytest.mark.parametrize("max_diameter_px", [10, 11])
@pytest.mark.parametrize("corner", ["top_left", "top_right", "bottom_left", "bottom_right"])
def test_a_dot_in_a_corner_of_the_image_is_masked_whole(max_diameter_px, corner):
    # The closing disc is centred on each pixel, so it fills the half of a dot left by any image border.
    half_px = (max_diameter_px + 1) // 2
    image = np.full((30, 40, 3), 180, np.uint8)
    rows = slice(0, half_px) if corner.startswith("top") else slice(30 - half_px, 30)
    cols = slice(0, half_px) if corner.endswith("left") else slice(40 - half_px, 40)
    image[rows, cols] = 60
    dot = np.zeros((30, 40), bool)
    dot[rows, cols] = True
    mask = detect_markers(image, np.full_like(image, 180), max_diameter_px=max_diameter_px, dilate_px=0)
    np.testing.assert_array_equal(mask, dot)
