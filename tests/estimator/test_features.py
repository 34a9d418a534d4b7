"""Contact features on exact half-space Hertz depth fields and hard cases."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from estimator.errors import PerceptionError
from estimator.features import contact_features

PITCH = 1e-3 / 11
THRESHOLD = 1e-4
SHAPE = (250, 350)
K_GEL = (1 - 0.48**2) / 0.275e6


def hertz_gel_depth(delta_m, radius_m, *, k_object=0.0, shape=SHAPE, center_px=None):
    """Gel indentation of an exact half-space Hertz contact (Johnson eq. 3.41-3.42).

    Total normal displacement inside the contact is delta - r^2/(2R); outside it is
    delta / (pi a^2) * [(2a^2 - r^2) asin(a/r) + r a sqrt(1 - a^2/r^2)]. The gel
    takes its compliance share k_gel / (k_gel + k_object) everywhere.
    """
    rows, cols = shape
    cy, cx = center_px if center_px is not None else ((rows - 1) / 2, (cols - 1) / 2)
    y, x = np.indices(shape)
    r = np.hypot(x - cx, y - cy) * PITCH
    a = np.sqrt(radius_m * delta_m)
    inside = delta_m - r**2 / (2 * radius_m)
    ro = np.maximum(r, a)
    outside = delta_m / (np.pi * a**2) * ((2 * a**2 - ro**2) * np.arcsin(a / ro) + ro * a * np.sqrt(1 - a**2 / ro**2))
    total = np.where(r <= a, inside, outside)
    return (K_GEL / (K_GEL + k_object) * total).astype(np.float32)


def test_rigid_sphere_features_match_hertz():
    radius, delta = 10e-3, 0.5e-3
    f = contact_features(hertz_gel_depth(delta, radius)[None], pixel_pitch_m=PITCH, contact_threshold_m=THRESHOLD)
    a = np.sqrt(radius * delta)
    assert f.peak_depth_m[0] == pytest.approx(delta, rel=0.01)
    assert f.cap_radius_m[0] == pytest.approx(a, abs=PITCH)
    assert f.curvature_radius_m[0] == pytest.approx(radius, rel=0.03)
    assert f.centroid_m[0] == pytest.approx([(SHAPE[1] - 1) / 2 * PITCH, (SHAPE[0] - 1) / 2 * PITCH], abs=PITCH / 10)
    assert not f.touches_edge[0]


def test_area_uses_the_true_pixel_area_not_the_diagonal():
    depth = np.zeros((1, *SHAPE), dtype=np.float32)
    depth[0, 100:140, 100:150] = 1e-3  # a 40 x 50 px flat punch
    f = contact_features(depth, pixel_pitch_m=PITCH, contact_threshold_m=THRESHOLD, smooth_px=0)
    assert f.area_m2[0] == pytest.approx(40 * 50 * PITCH**2)
    assert f.radius_m[0] == pytest.approx(np.sqrt(40 * 50 / np.pi) * PITCH)
    assert np.isinf(f.curvature_radius_m[0])  # flat top


def test_threshold_area_exceeds_hertz_contact_when_deep():
    # Outside the contact the gel still sinks more than 0.1 mm: the paper's area is not pi a^2.
    radius, delta = 10e-3, 1.0e-3
    f = contact_features(hertz_gel_depth(delta, radius)[None], pixel_pitch_m=PITCH, contact_threshold_m=THRESHOLD)
    assert f.area_m2[0] > 2 * np.pi * radius * delta


def test_soft_object_flattens_the_gel_cap():
    # Both bodies share the displacement: the gel cap looks like a sphere of radius R (k_g + k_o) / k_g.
    radius, delta = 5e-3, 2e-3
    k_object = K_GEL  # an object as compliant as the gel
    f = contact_features(hertz_gel_depth(delta, radius, k_object=k_object)[None],
                         pixel_pitch_m=PITCH, contact_threshold_m=THRESHOLD)
    assert f.peak_depth_m[0] == pytest.approx(delta / 2, rel=0.01)
    assert f.curvature_radius_m[0] == pytest.approx(2 * radius, rel=0.03)
    assert f.cap_radius_m[0] == pytest.approx(np.sqrt(radius * delta), abs=PITCH)


def test_stack_is_measured_frame_by_frame():
    deltas = [0.2e-3, 0.4e-3, 0.8e-3]
    stack = np.stack([hertz_gel_depth(d, 8e-3) for d in deltas])
    f = contact_features(stack, pixel_pitch_m=PITCH, contact_threshold_m=THRESHOLD)
    assert len(f) == 3
    assert np.all(np.diff(f.area_m2) > 0) and np.all(np.diff(f.peak_depth_m) > 0)
    one = contact_features(stack[1:2], pixel_pitch_m=PITCH, contact_threshold_m=THRESHOLD)
    assert one.area_m2[0] == f.area_m2[1] and one.curvature_radius_m[0] == pytest.approx(f.curvature_radius_m[1])
    assert len(f.take(np.array([0, 2]))) == 2


def test_no_contact_gives_zero_area_and_nan_geometry():
    f = contact_features(np.zeros((2, 30, 40), dtype=np.float32), pixel_pitch_m=PITCH, contact_threshold_m=THRESHOLD)
    assert np.all(f.area_m2 == 0) and np.all(f.peak_depth_m == 0) and np.all(f.cap_radius_m == 0)
    assert np.all(np.isnan(f.centroid_m)) and np.all(np.isnan(f.curvature_radius_m))


def test_object_larger_than_the_pad_touches_the_edge():
    depth = hertz_gel_depth(2e-3, 200e-3)  # a 0.4 m sphere: contact wider than the pad
    f = contact_features(depth[None], pixel_pitch_m=PITCH, contact_threshold_m=THRESHOLD)
    assert f.touches_edge[0] and f.cap_touches_edge[0]
    assert f.area_m2[0] == pytest.approx(SHAPE[0] * SHAPE[1] * PITCH**2)


def test_needle_thin_contact_is_measured():
    depth = hertz_gel_depth(0.5e-3, 0.05e-3)  # a 50 um tip
    f = contact_features(depth[None], pixel_pitch_m=PITCH, contact_threshold_m=THRESHOLD, smooth_px=0)
    assert 0 < f.area_m2[0] < 1e-6
    assert f.peak_depth_m[0] == pytest.approx(0.5e-3, rel=0.2)
    assert np.isfinite(f.radius_m[0])


def test_depth_noise_at_the_resolution_does_not_make_contact():
    rng = np.random.default_rng(1)
    noise = rng.normal(0, 2e-5, (3, *SHAPE)).astype(np.float32)
    f = contact_features(noise, pixel_pitch_m=PITCH, contact_threshold_m=THRESHOLD)
    assert np.all(f.area_m2 == 0) and np.all(f.peak_depth_m < THRESHOLD / 2)
    noisy = hertz_gel_depth(0.5e-3, 10e-3)[None] + noise[:1]
    g = contact_features(noisy, pixel_pitch_m=PITCH, contact_threshold_m=THRESHOLD)
    assert g.peak_depth_m[0] == pytest.approx(0.5e-3, abs=2e-5)
    assert g.cap_radius_m[0] == pytest.approx(np.sqrt(5e-6), abs=2 * PITCH)


@pytest.mark.parametrize(
    ("depth", "match"),
    [
        (np.zeros((10, 10), dtype=np.float32), "stack"),
        (np.zeros((1, 10, 10), dtype=np.uint8), "float"),
        (np.full((1, 4, 4), np.nan, dtype=np.float32), "NaN"),
        (np.zeros((1, 0, 10), dtype=np.float32), "H, W >= 1"),
        (np.zeros((2, 10, 0)), "H, W >= 1"),
    ],
)
def test_bad_depth_is_refused_naming_it(depth, match):
    with pytest.raises(PerceptionError, match="depth_m"):
        contact_features(depth, pixel_pitch_m=PITCH, contact_threshold_m=THRESHOLD)


def test_bad_options_are_refused():
    with pytest.raises(PerceptionError, match="pixel_pitch_m"):
        contact_features(np.zeros((1, 4, 4)), pixel_pitch_m=0.0, contact_threshold_m=THRESHOLD)


@pytest.mark.parametrize(("options", "named"), [
    ({"pixel_pitch_m": None}, "pixel_pitch_m"),
    ({"pixel_pitch_m": "1e-4"}, "pixel_pitch_m"),
    ({"pixel_pitch_m": 1e200}, "pixel_pitch_m"),  # its square, the pixel area, overflows
    ({"contact_threshold_m": None}, "contact_threshold_m"),
    ({"smooth_px": None}, "smooth_px"),
    ({"smooth_px": 1e9}, "smooth_px"),  # its kernel would overflow OpenCV's int sizes
    ({"smooth_px": 51.0}, "smooth_px"),  # wider than the 40 x 50 image
])
def test_options_that_are_not_usable_numbers_are_refused_by_name(options, named):
    depth = hertz_gel_depth(0.5e-3, 10e-3, shape=(40, 50))[None]
    with pytest.raises(PerceptionError, match=named):
        contact_features(depth, **{"pixel_pitch_m": PITCH, "contact_threshold_m": THRESHOLD, **options})


@settings(max_examples=40, deadline=None)
@given(hnp.arrays(np.float32, st.tuples(st.integers(1, 3), st.integers(2, 12), st.integers(2, 12)),
                  elements=st.floats(-0.0078125, 0.0078125, width=32)))
def test_features_are_finite_or_flagged_nan(depth):
    f = contact_features(depth, pixel_pitch_m=PITCH, contact_threshold_m=THRESHOLD)
    assert np.all(np.isfinite(f.peak_depth_m) & (f.peak_depth_m >= 0))
    assert np.all(np.isfinite(f.area_m2) & (f.area_m2 >= 0))
    assert np.all(np.isfinite(f.cap_radius_m))
    assert not np.any(f.curvature_radius_m <= 0)


def test_smoothing_and_cap_fit_match_their_direct_definitions():
    # The Gaussian is scipy's (mode "nearest", radius 4 sigma) and the curvature is the least-squares
    # paraboloid through the cap pixels alone, here fitted directly with lstsq.
    from scipy import ndimage

    rng = np.random.default_rng(3)
    depth = hertz_gel_depth(0.4e-3, 7e-3, center_px=(90.3, 141.7)) + rng.normal(0, 1e-5, SHAPE).astype(np.float32)
    f = contact_features(depth[None], pixel_pitch_m=PITCH, contact_threshold_m=THRESHOLD)
    smooth = ndimage.gaussian_filter(depth, 1.0, mode="nearest")
    assert f.peak_depth_m[0] == pytest.approx(smooth.max(), rel=1e-6)
    rows, cols = np.nonzero(smooth >= smooth.max() / 2)
    assert f.cap_radius_m[0] == pytest.approx(np.sqrt(rows.size / np.pi) * PITCH)
    x, y = cols * PITCH, rows * PITCH
    design = np.stack([np.ones_like(x), x, y, x**2 + y**2], axis=1)
    c3 = np.linalg.lstsq(design, smooth[rows, cols].astype(np.float64), rcond=None)[0][3]
    assert f.curvature_radius_m[0] == pytest.approx(-1 / (2 * c3), rel=1e-6)


def test_smoothing_as_wide_as_the_image_is_taken():
    depth = hertz_gel_depth(0.5e-3, 10e-3, shape=(40, 50))[None]
    f = contact_features(depth, pixel_pitch_m=PITCH, contact_threshold_m=THRESHOLD, smooth_px=50.0)
    assert np.isfinite(f.peak_depth_m).all()


def test_depth_exactly_at_the_threshold_is_contact():
    depth = np.zeros((1, 20, 30))
    depth[0, 5:9, 10:15] = THRESHOLD
    f = contact_features(depth, pixel_pitch_m=PITCH, contact_threshold_m=THRESHOLD, smooth_px=0.0)
    assert f.area_m2[0] == pytest.approx(20 * PITCH**2)
    np.testing.assert_allclose(f.centroid_m[0], [12 * PITCH, 6.5 * PITCH])


@pytest.mark.parametrize("cols", [slice(0, 4), slice(26, 30)])
def test_contact_reaching_only_the_left_or_right_border_touches_the_edge(cols):
    depth = np.zeros((1, 20, 30))
    depth[0, 8:12, cols] = 5 * THRESHOLD
    f = contact_features(depth, pixel_pitch_m=PITCH, contact_threshold_m=THRESHOLD, smooth_px=0.0)
    assert f.touches_edge[0] and f.cap_touches_edge[0]
    inner = np.zeros_like(depth)
    inner[0, 8:12, 10:14] = 5 * THRESHOLD
    g = contact_features(inner, pixel_pitch_m=PITCH, contact_threshold_m=THRESHOLD, smooth_px=0.0)
    assert not g.touches_edge[0] and not g.cap_touches_edge[0]


def test_cap_includes_pixels_at_exactly_half_the_peak():
    depth = np.zeros((1, 21, 21))
    depth[0, 7:14, 7:14] = 2e-4  # 49 px at exactly half the peak
    depth[0, 9:12, 9:12] = 4e-4  # 9 px at the peak
    f = contact_features(depth, pixel_pitch_m=PITCH, contact_threshold_m=THRESHOLD, smooth_px=0.0)
    assert f.peak_depth_m[0] == pytest.approx(4e-4)
    assert f.cap_radius_m[0] == pytest.approx(np.sqrt(49 * PITCH**2 / np.pi))
