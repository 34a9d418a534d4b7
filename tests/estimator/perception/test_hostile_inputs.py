"""Hostile options and degenerate images for the marker mask and the sphere fit: refused by name."""

from __future__ import annotations

import numpy as np
import pytest

from estimator.errors import PerceptionError
from estimator.perception import fit_sphere
from estimator.perception.markers import detect_markers, inpaint_markers

PITCH = 1e-4


def edge_cap(shape=(40, 40)):
    """A shallow cap centred on the image's top-right corner."""
    rows, cols = np.indices(shape, dtype=np.float64)
    return np.clip(2e-4 - ((cols - (shape[1] - 1)) ** 2 + rows**2) * 1e-6, 0, None)


def dotted(shape=(40, 50)):
    image = np.full(shape + (3,), 150, np.uint8)
    image[10:14, 10:14] = 40  # a dot
    image[25:28, 30:33] = 50  # another
    return image


@pytest.mark.parametrize("center", [(1e30, 0.0), (1e12, 0.0), (0.0, -1e12), (40.0, 5.0), (5.0, -1.0),
                                    (-3.0, 5.0)])
def test_fit_sphere_refuses_a_centre_off_the_image(center):
    with pytest.raises(PerceptionError, match="center_px"):
        fit_sphere(edge_cap(), pixel_pitch_m=PITCH, center_px=center)


@pytest.mark.parametrize("center", [(39.9, 0.0), (-0.9, 20.0), (20.0, 39.5), (0.0, 0.0)])
def test_fit_sphere_still_takes_a_centre_on_or_at_the_edge_of_the_image(center):
    fit = fit_sphere(edge_cap(), pixel_pitch_m=PITCH, center_px=center)
    assert isinstance(fit.ok, bool)


@pytest.mark.parametrize("smooth_px", [1e9, 1e300, 41.0])
def test_fit_sphere_refuses_a_smoothing_wider_than_the_image(smooth_px):
    depth = np.zeros((40, 30))
    depth[20, 15] = 1e-4
    with pytest.raises(PerceptionError, match="smooth_px"):
        fit_sphere(depth, pixel_pitch_m=PITCH, smooth_px=smooth_px)


def test_fit_sphere_takes_a_smoothing_as_wide_as_the_image():
    fit_sphere(edge_cap(), pixel_pitch_m=PITCH, smooth_px=40.0)


@pytest.mark.parametrize("shape", [(0, 0), (0, 5), (5, 0)])
def test_empty_images_are_refused(shape):
    empty = np.zeros(shape + (3,), np.uint8)
    with pytest.raises(PerceptionError, match="frame"):
        inpaint_markers(empty, np.zeros(shape, bool))
    with pytest.raises(PerceptionError, match="frame"):
        inpaint_markers(np.zeros(shape, np.float32), np.zeros(shape, bool))
    with pytest.raises(PerceptionError, match="frame"):
        detect_markers(empty, empty)
    with pytest.raises(PerceptionError, match="reference"):
        detect_markers(np.zeros((4, 4, 3), np.uint8), empty)


def test_numpy_integer_sizes_give_the_same_mask():
    image, reference = dotted(), np.full((40, 50, 3), 150, np.uint8)
    plain = detect_markers(image, reference, max_diameter_px=7, dilate_px=2)
    assert plain.any()
    numpy_sized = detect_markers(image, reference, max_diameter_px=np.int64(7), dilate_px=np.int32(2))
    np.testing.assert_array_equal(numpy_sized, plain)


@pytest.mark.parametrize(("options", "named"), [
    ({"max_diameter_px": 2**40}, "max_diameter_px"),
    ({"max_diameter_px": 10**6}, "max_diameter_px"),
    ({"max_diameter_px": 51}, "max_diameter_px"),
    ({"max_diameter_px": True}, "max_diameter_px"),
    ({"max_diameter_px": 7.0}, "max_diameter_px"),
    ({"max_diameter_px": 0}, "max_diameter_px"),
    ({"dilate_px": 2**31}, "dilate_px"),
    ({"dilate_px": np.int64(10**9)}, "dilate_px"),
    ({"dilate_px": -1}, "dilate_px"),
    ({"dilate_px": False}, "dilate_px"),
    ({"min_darkness": "0.5"}, "min_darkness"),
    ({"min_darkness": None}, "min_darkness"),
    ({"min_darkness": float("nan")}, "min_darkness"),
    ({"min_darkness": True}, "min_darkness"),
])
def test_detect_markers_refuses_unusable_options_by_name(options, named):
    image = dotted()
    with pytest.raises(PerceptionError, match=named):
        detect_markers(image, image, **options)


def test_detect_markers_takes_sizes_up_to_the_image_and_the_default_on_small_images():
    image = dotted()
    detect_markers(image, image, max_diameter_px=50, dilate_px=50)
    small = np.full((5, 6, 3), 150, np.uint8)
    assert not detect_markers(small, small).any()
    detect_markers(small, small, max_diameter_px=11, dilate_px=11)
    with pytest.raises(PerceptionError, match="max_diameter_px"):
        detect_markers(small, small, max_diameter_px=12)
