"""Warp and crop against the real Wedge frames and their published corner calibrations."""

from __future__ import annotations

import csv

import cv2
import numpy as np
import pytest

from estimator.errors import PerceptionError
from estimator.perception import warp_and_crop, warp_maps, warp_matrix, warp_points
from teleop.errors import SettingsError
from teleop.settings import SensorSettings


def corners(path):
    with path.open() as fh:
        rows = {row["Name"]: (float(row["x"]), float(row["y"])) for row in csv.DictReader(fh)}
    return tuple(rows[name] for name in ("topleft", "topright", "bottomleft", "bottomright"))


@pytest.fixture(scope="module")
def wedge(shared_dir):
    seed = shared_dir / "seed"
    raw = cv2.imread(str(seed / "wedge_init_frame_raw_640x480.png"), cv2.IMREAD_COLOR)
    warped = cv2.imread(str(seed / "wedge_init_frame_warped_400x300.png"), cv2.IMREAD_COLOR)
    return seed, raw, warped


@pytest.mark.parametrize(("corners_file", "matches"), [
    ("wedge_corners_no_markers.csv", True),
    ("wedge_corners_markers.csv", False),
])
def test_real_wedge_frame_warps_onto_the_published_warped_frame(wedge, corners_file, matches):
    seed, raw, warped = wedge
    sensor = SensorSettings(warp_corners_px=corners(seed / corners_file))
    ours = warp_and_crop(raw, sensor)
    crop = sensor.crop_px
    expected = warped[crop:-crop, crop:-crop]
    assert ours.shape == (*sensor.image_shape, 3) == expected.shape
    assert ours.dtype == np.uint8
    psnr = cv2.PSNR(ours, expected)
    # The no-marker corners reproduce the published frame to interpolation rounding
    # (measured 67 dB uncropped); the other corner set is a different sensor's warp.
    if matches:
        assert psnr > 50.0
        assert np.abs(ours.astype(int) - expected).max() <= 2
    else:
        assert psnr < 35.0


def test_matrix_is_cached_per_sensor_and_read_only():
    sensor = SensorSettings()
    first = warp_matrix(sensor)
    assert warp_matrix(SensorSettings()) is first
    assert not first.flags.writeable
    moved = SensorSettings(warp_corners_px=((40.0, 80.0), (439.0, 121.0), (52.0, 425.0), (446.0, 368.0)))
    assert not np.allclose(warp_matrix(moved), first)


def test_cached_remap_matches_a_per_frame_perspective_warp(wedge):
    _, raw, _ = wedge
    sensor = SensorSettings()
    rows, cols = sensor.image_shape
    direct = cv2.warpPerspective(raw, warp_matrix(sensor), (cols, rows), flags=cv2.INTER_LINEAR)
    ours = warp_and_crop(raw, sensor)
    # Both interpolate bilinearly; the remap's positions are rounded to 1/32 px (warpPerspective
    # in OpenCV 5 interpolates at full precision), which moves a few pixels by a grey level or two.
    difference = np.abs(ours.astype(int) - direct)
    assert difference.max() <= 3
    assert np.count_nonzero(difference) < 0.1 * difference.size
    assert difference.mean() < 0.1


def test_remap_tables_are_cached_per_sensor_and_read_only():
    sensor = SensorSettings()
    xy, fraction = warp_maps(sensor)
    assert warp_maps(SensorSettings())[0] is xy
    assert xy.shape == (*sensor.image_shape, 2) and xy.dtype == np.int16
    assert fraction.shape == sensor.image_shape and fraction.dtype == np.uint16
    assert not xy.flags.writeable and not fraction.flags.writeable
    # The output pixel (0, 0) samples the raw point the inverse warp sends it to.
    inverse = cv2.perspectiveTransform(np.zeros((1, 1, 2)), np.linalg.inv(warp_matrix(sensor)))[0, 0]
    np.testing.assert_array_equal(xy[0, 0], np.floor(inverse))


def test_corners_map_to_the_cropped_rectangle_corners():
    sensor = SensorSettings()
    mapped = warp_points(np.array(sensor.warp_corners_px), sensor)
    w, h, c = sensor.warped_width_px, sensor.warped_height_px, sensor.crop_px
    np.testing.assert_allclose(mapped, [[-c, -c], [w - c, -c], [-c, h - c], [w - c, h - c]], atol=1e-6)


def test_a_raw_dot_lands_where_warp_points_says():
    sensor = SensorSettings()
    raw = np.zeros((sensor.raw_height_px, sensor.raw_width_px, 3), np.uint8)
    cv2.circle(raw, (250, 260), 6, (255, 255, 255), -1)
    warped = warp_and_crop(raw, sensor)
    rows, cols = np.nonzero(warped[..., 0] > 128)
    np.testing.assert_allclose([cols.mean(), rows.mean()], warp_points([[250, 260]], sensor)[0], atol=0.5)


@pytest.mark.parametrize("raw", [
    np.zeros((480, 640, 3), np.float32),
    np.zeros((300, 400, 3), np.uint8),
    np.zeros((480, 640), np.uint8),
    [[0, 0, 0]],
])
def test_bad_raw_frames_are_refused_by_name(raw):
    with pytest.raises(PerceptionError, match="raw_bgr"):
        warp_and_crop(raw, SensorSettings())


def test_a_binned_frame_of_the_wrong_size_is_named_as_captured():
    sensor = SensorSettings()
    big = np.zeros((sensor.raw_height_px, sensor.raw_width_px, 3), np.uint8)  # decoded at half size from 2x
    with pytest.raises(PerceptionError, match=f"a frame of about {2 * sensor.raw_width_px}x{2 * sensor.raw_height_px} px "
                                              f"for the sensor's {sensor.raw_width_px}x{sensor.raw_height_px}"):
        warp_and_crop(big, sensor, binning=2)


def test_degenerate_corners_are_refused():
    corners = ((0.0, 0.0), (10.0, 0.0), (20.0, 0.0), (30.0, 0.0))
    with pytest.raises(SettingsError, match="warp_corners_px"):  # the settings refuse them first
        SensorSettings(warp_corners_px=corners)
    line = SensorSettings()
    object.__setattr__(line, "warp_corners_px", corners)  # past the settings: warp_matrix's own check
    with pytest.raises(PerceptionError, match="warp_corners_px"):
        warp_matrix(line)
