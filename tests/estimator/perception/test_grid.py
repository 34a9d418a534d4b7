"""The depth grid: frames decoded smaller and warped onto a binned grid, its sensor and calibration."""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np
import pytest

from estimator.errors import PerceptionError
from estimator.measurements import measure_frame, resolve_calibration
from estimator.perception.calibration import Calibration
from estimator.perception.depth import reconstruct_depth
from estimator.perception.grid import depth_grid, frame_on_grid, grid_calibration, to_grid
from estimator.perception.warp import warp_and_crop, warp_maps
from teleop.record import decode_image, reduce_image
from teleop.settings import SensorSettings, load_settings
from teleop.sim.optics import OpticsRenderer
from teleop.sim.presses import sphere_press_height


def block_means(image: np.ndarray, k: int) -> np.ndarray:
    rows, cols = image.shape[:2]
    return image.astype(float).reshape(rows // k, k, cols // k, k, -1).mean(axis=(1, 3))


@pytest.fixture(scope="module")
def raw_wedge(shared_dir):
    return cv2.imread(str(shared_dir / "seed" / "wedge_init_frame_raw_640x480.png"), cv2.IMREAD_COLOR)


def test_a_depth_grid_covers_the_same_pad_with_coarser_pixels():
    sensor = load_settings().sensor("left")
    rows, cols = sensor.image_shape
    coarse = depth_grid(sensor, 2)
    assert coarse.image_shape == (rows // 2, cols // 2) and coarse.binning == 2
    assert coarse.pixel_pitch_m == pytest.approx(2 * sensor.pixel_pitch_m)
    assert coarse.pad_size_m == pytest.approx(sensor.pad_size_m)
    assert coarse.contact_threshold_m == sensor.contact_threshold_m and not coarse.markers
    full = depth_grid(sensor, 1)
    assert (full.image_shape, full.pixel_pitch_m, full.binning) == (sensor.image_shape, sensor.pixel_pitch_m, 1)
    assert depth_grid(sensor, 2) is coarse


@pytest.mark.parametrize("binning", [0, 3, 4, True, 2.0])
def test_a_binning_that_does_not_tile_the_grid_is_refused(binning):
    sensor = load_settings().sensor("left")  # 250 x 350 px: 3 and 4 leave a remainder
    with pytest.raises(PerceptionError, match="binning"):
        depth_grid(sensor, binning)


def test_a_binned_grid_of_a_sensor_with_markers_is_refused():
    with pytest.raises(PerceptionError, match="markers"):
        depth_grid(load_settings().sensor("right"), 2)


def test_a_grid_calibration_is_the_same_table_at_a_coarser_pitch():
    settings = load_settings()
    full = resolve_calibration(settings.sensor("left"), None)
    coarse = grid_calibration(full, 2)
    assert np.array_equal(coarse.lut, full.lut) and coarse.image_shape == (125, 175)
    assert coarse.pixel_pitch_m == pytest.approx(2 * full.pixel_pitch_m)
    # The same smoothing on the gel: half the pixels of a grid twice as coarse.
    smoothed = dataclasses.replace(full, smoothing_px=2.0)
    assert coarse.smoothing_px == 0.0 and grid_calibration(smoothed, 2).smoothing_px == pytest.approx(1.0)
    assert grid_calibration(full, 2) is coarse and grid_calibration(full, 1) is full
    with pytest.raises(PerceptionError, match="binning 3"):
        grid_calibration(full, 3)


def test_decoding_smaller_averages_pixel_blocks(raw_wedge):
    png = cv2.imencode(".png", raw_wedge)[1].tobytes()
    jpeg = cv2.imencode(".jpg", raw_wedge, [cv2.IMWRITE_JPEG_QUALITY, 90])[1].tobytes()
    # PNG decoded at half size is the block mean of the full decode, rounded.
    half = decode_image(png, reduce=2)
    assert half.shape == (240, 320, 3)
    assert np.abs(half - block_means(raw_wedge, 2)).max() <= 0.5
    np.testing.assert_array_equal(half, reduce_image(raw_wedge, 2))
    # A JPEG at half size comes from its scaled inverse DCT: within a few levels of the block mean.
    jpeg_half = decode_image(jpeg, reduce=2).astype(float)
    assert np.abs(jpeg_half - block_means(decode_image(jpeg), 2)).mean() < 1.5
    # Reductions OpenCV does not decode to are averaged after a full decode.
    np.testing.assert_array_equal(decode_image(png, reduce=5), reduce_image(raw_wedge, 5))
    assert decode_image(b"not an image", reduce=2) is None and decode_image(b"") is None
    with pytest.raises(ValueError, match="reduce 7"):
        reduce_image(raw_wedge, 7)


def test_a_frame_on_the_binned_grid_is_the_block_mean_of_the_warped_frame(raw_wedge):
    sensor = SensorSettings()
    png = cv2.imencode(".png", raw_wedge)[1].tobytes()
    full = warp_and_crop(raw_wedge, sensor)
    binned = frame_on_grid(png, "png", sensor, binning=2)
    assert binned.shape == (125, 175, 3) and binned.dtype == np.uint8
    assert warp_maps(sensor, 2)[0].shape == (125, 175, 2)
    # Binning before or after the warp differs by interpolation only: a fraction of a level on average.
    difference = np.abs(binned - block_means(full, 2))
    assert difference.mean() < 1.0 and np.percentile(difference, 99) < 6
    # The same through a raw image, and binning 1 is the plain warp.
    np.testing.assert_array_equal(frame_on_grid(raw_wedge, "raw", sensor, binning=2), binned)
    np.testing.assert_array_equal(frame_on_grid(png, "png", sensor, binning=1), full)
    with pytest.raises(PerceptionError, match="raw_bgr"):
        to_grid(raw_wedge, sensor, binning=2)  # a full-size frame where a half-size one belongs


def test_frame_on_grid_names_the_frame_in_its_errors():
    sensor = SensorSettings()
    with pytest.raises(PerceptionError, match="frame 7: encoding 'gif'"):
        frame_on_grid(b"GIF89a", "gif", sensor, binning=2, where="frame 7")
    with pytest.raises(PerceptionError, match="uint8 H x W x 3"):
        frame_on_grid(np.zeros((4, 4), np.uint16), "raw", sensor, binning=1)
    with pytest.raises(PerceptionError, match="does not decode"):
        frame_on_grid(b"\xff\xd8 broken", "jpeg", sensor, binning=2)
    with pytest.raises(PerceptionError, match="reduce 2"):
        frame_on_grid(np.zeros((5, 5, 3), np.uint8), "raw", sensor, binning=2)
    flat = SensorSettings(model="mini", raw_width_px=350, raw_height_px=250, warped_width_px=350,
                          warped_height_px=250, crop_px=0)
    image = np.full((250, 350, 3), 7, np.uint8)
    assert frame_on_grid(image, "raw", flat, binning=1) is image


def test_depth_on_the_binned_grid_matches_the_full_grid():
    settings = load_settings()
    sensor = settings.sensor("left")
    calibration = resolve_calibration(sensor, None)
    camera = OpticsRenderer(sensor, sim=settings.simulation, rng=np.random.default_rng(3))
    rows, cols = sensor.image_shape
    press = sphere_press_height(sensor.image_shape, center_px=(cols / 2.0, rows / 2.0), ball_radius_m=4e-3,
                                depth_m=0.8e-3, pixel_pitch_m=sensor.pixel_pitch_m)
    pressed, untouched = camera.capture(press), camera.capture(np.zeros(sensor.image_shape))
    measured = {}
    for k in (1, 2):
        frame, reference = (frame_on_grid(data, "jpeg", sensor, binning=k) for data in (pressed, untouched))
        measured[k] = measure_frame(frame, reference, grid_calibration(calibration, k), depth_grid(sensor, k))
    full, (coarse_depth, coarse) = measured[1][1], measured[2]
    assert coarse_depth.shape == (125, 175)
    assert coarse.peak_depth_m[0] == pytest.approx(full.peak_depth_m[0], rel=0.1)
    assert coarse.area_m2[0] == pytest.approx(full.area_m2[0], rel=0.1)
    assert coarse.cap_radius_m[0] == pytest.approx(full.cap_radius_m[0], rel=0.1)
    # The pitch is what scales depth from gradients: at the full grid's pitch the binned depth halves.
    unscaled = Calibration(lut=calibration.lut, image_shape=(125, 175), pixel_pitch_m=calibration.pixel_pitch_m,
                           ball_radius_m=calibration.ball_radius_m, relative_range=calibration.relative_range)
    assert reconstruct_depth(frame, reference, unscaled).max() < 0.7 * coarse_depth.max()
