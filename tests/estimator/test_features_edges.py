"""Contact features at their boundaries: the cap of a peak at the threshold, the fewest cap pixels a
curvature is fitted on, a cap that barely falls, every image border, smoothing at the border,
negative depth and options that are bools."""

from __future__ import annotations

import numpy as np
import pytest

from estimator.errors import PerceptionError
from estimator.features import MIN_FIT_PIXELS, contact_features

PITCH = 1e-3 / 11
THRESHOLD = 1e-4


def features(depth, **options):
    return contact_features(depth, **{"pixel_pitch_m": PITCH, "contact_threshold_m": THRESHOLD,
                                      "smooth_px": 0.0, **options})


def test_a_peak_exactly_at_the_threshold_has_a_cap():
    depth = np.zeros((1, 20, 30))
    depth[0, 5:9, 10:15] = THRESHOLD
    f = features(depth)
    assert f.cap_radius_m[0] == pytest.approx(np.sqrt(20 * PITCH**2 / np.pi))
    assert np.isinf(f.curvature_radius_m[0])  # a flat cap of 20 px is fitted, and is flat


def test_a_peak_just_below_the_threshold_has_no_cap():
    depth = np.zeros((1, 20, 30))
    depth[0, 5:9, 10:15] = 0.99 * THRESHOLD
    f = features(depth)
    assert f.cap_radius_m[0] == 0 and f.area_m2[0] == 0 and np.isnan(f.curvature_radius_m[0])


@pytest.mark.parametrize(("pixels", "fitted"), [(MIN_FIT_PIXELS - 1, False), (MIN_FIT_PIXELS, True)])
def test_the_curvature_is_fitted_on_at_least_six_cap_pixels(pixels, fitted):
    assert MIN_FIT_PIXELS == 6
    depth = np.zeros((1, 20, 30))
    depth[0, 10, 10:10 + pixels] = 5 * THRESHOLD  # a one-row flat cap of ``pixels`` px
    f = features(depth)
    assert f.cap_radius_m[0] == pytest.approx(np.sqrt(pixels * PITCH**2 / np.pi))
    assert np.isinf(f.curvature_radius_m[0]) if fitted else np.isnan(f.curvature_radius_m[0])


@pytest.mark.parametrize(("fall", "curved"), [(1e-3, True), (1e-7, False)])
def test_a_cap_is_flat_when_it_falls_by_less_than_a_millionth_of_its_peak(fall, curved):
    # A paraboloid cut off at radius 8 px that falls by ``fall`` of its peak to its edge: curved, with
    # the paraboloid's own radius, unless the fall is below flat rounding (1e-6 of the peak).
    rows, cols = np.indices((41, 41))
    r2 = ((rows - 20) ** 2 + (cols - 20) ** 2) * PITCH**2
    peak, edge = 1e-3, 8 * PITCH
    radius = edge**2 / (2 * fall * peak)
    depth = np.where(r2 <= edge**2, peak - r2 / (2 * radius), 0.0)[None]
    f = features(depth)
    if curved:
        assert f.curvature_radius_m[0] == pytest.approx(radius, rel=1e-3)
    else:
        assert np.isinf(f.curvature_radius_m[0])


@pytest.mark.parametrize("rows", [slice(0, 4), slice(16, 20)], ids=["top", "bottom"])
def test_contact_reaching_only_the_top_or_bottom_border_touches_the_edge(rows):
    depth = np.zeros((1, 20, 30))
    depth[0, rows, 10:14] = 5 * THRESHOLD
    f = features(depth)
    assert f.touches_edge[0] and f.cap_touches_edge[0]


def test_only_the_cap_decides_whether_the_cap_touches_the_edge():
    depth = np.zeros((1, 20, 30))
    depth[0, 0:10, 5:25] = 2 * THRESHOLD  # a contact reaching the top border
    depth[0, 6:9, 12:16] = 10 * THRESHOLD  # its cap, inside
    f = features(depth)
    assert f.touches_edge[0] and not f.cap_touches_edge[0]


def test_smoothing_replicates_the_border_so_a_uniform_press_stays_uniform():
    # scipy's mode "nearest": a press covering the whole pad keeps its depth at the border after
    # smoothing, so the whole pad stays in contact (zero padding would pull the border below it).
    depth = np.full((1, 20, 30), 1.5 * THRESHOLD, dtype=np.float32)
    f = features(depth, smooth_px=2.0)
    assert f.peak_depth_m[0] == pytest.approx(1.5 * THRESHOLD, rel=1e-6)
    assert f.area_m2[0] == pytest.approx(20 * 30 * PITCH**2)


def test_negative_depth_is_no_peak():
    # The gel bulging out (negative depth) is not an indentation: the peak is the largest positive depth.
    depth = np.zeros((2, 20, 30))
    depth[0] = -1e-3
    depth[1, 2:5, 2:5] = -1e-3
    depth[1, 10:13, 10:13] = 2e-4
    f = features(depth)
    assert f.peak_depth_m[0] == 0 and f.area_m2[0] == 0
    assert f.peak_depth_m[1] == pytest.approx(2e-4)
    assert f.cap_radius_m[1] == pytest.approx(np.sqrt(9 * PITCH**2 / np.pi))


@pytest.mark.parametrize("named", ["pixel_pitch_m", "contact_threshold_m", "smooth_px"])
def test_an_option_given_as_a_bool_is_refused_by_name(named):
    with pytest.raises(PerceptionError, match=named):
        features(np.zeros((1, 4, 4)), **{named: True})


def test_take_and_concatenate_keep_every_field_of_the_frames_chosen():
    depth = np.zeros((3, 20, 30))
    depth[0, 0:4, 0:4] = 5 * THRESHOLD  # at the corner: touches the edge
    depth[1, 8:12, 10:16] = 5 * THRESHOLD
    depth[2, 5:8, 20:29] = 2 * THRESHOLD
    f = features(depth)
    chosen = np.array([2, 0])
    parts = {"indices": f.take(chosen), "concatenated": type(f).concatenate([f.take(chosen[:1]), f.take(chosen[1:])])}
    for how, part in parts.items():
        for name in type(f).__dataclass_fields__:
            np.testing.assert_array_equal(getattr(part, name), getattr(f, name)[chosen], err_msg=f"{how} {name}")
    masked = f.take(np.array([True, False, True]))
    for name in type(f).__dataclass_fields__:
        np.testing.assert_array_equal(getattr(masked, name), getattr(f, name)[[0, 2]], err_msg=name)
