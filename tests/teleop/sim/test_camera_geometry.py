"""Camera geometry and the Wedge's illumination (teleop.sim.camera_geometry, teleop.sim.wedge_optics)."""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np
import pytest

from teleop.errors import SimulationError
from teleop.sim.camera_geometry import pad_view, raw_footprint, warp_to_grid
from teleop.sim.wedge_optics import channel_gain, reflectance_map


@pytest.fixture(scope="module")
def sensor(settings):
    return settings.sensor("left")


def test_a_raw_frame_of_another_size_is_refused(sensor):
    # A frame of another camera would be warped into a meaningless grid.
    with pytest.raises(SimulationError, match="raw frame has shape"):
        warp_to_grid(np.zeros((sensor.raw_height_px // 2, sensor.raw_width_px, 3), np.uint8), sensor)


def test_shared_cached_arrays_cannot_be_written(sensor):
    # Every camera of a sensor shares these: one writing into them would change them all.
    _, map_x, map_y = raw_footprint(sensor)
    for array in (pad_view(sensor).raw_to_warped, map_x, map_y, channel_gain(sensor), reflectance_map()):
        with pytest.raises(ValueError):
            array.flat[0] = 0


def test_the_footprint_box_holds_every_raw_pixel_that_sees_the_pad(sensor):
    # A raw pixel of the pad outside the box would never show a press.
    (rows, cols), _, _ = raw_footprint(sensor)
    view = pad_view(sensor)
    xs, ys = np.meshgrid(np.arange(sensor.raw_width_px, dtype=np.float64),
                         np.arange(sensor.raw_height_px, dtype=np.float64))
    warped = cv2.perspectiveTransform(np.dstack([xs, ys]), view.raw_to_warped)
    sees = ((warped[..., 0] >= 0) & (warped[..., 0] <= view.width_px - 1)
            & (warped[..., 1] >= 0) & (warped[..., 1] <= view.height_px - 1))
    seen_rows, seen_cols = np.flatnonzero(sees.any(axis=1)), np.flatnonzero(sees.any(axis=0))
    assert rows.start <= seen_rows[0] and seen_rows[-1] < rows.stop
    assert cols.start <= seen_cols[0] and seen_cols[-1] < cols.stop


def test_each_physical_sensor_has_its_own_illumination(sensor):
    # The uneven illumination follows the sensor's model, finger and serial: the Wedges of a rig
    # differ, and one sensor's is the same in every run.
    same = channel_gain(dataclasses.replace(sensor))
    other_serial = channel_gain(dataclasses.replace(sensor, serial=sensor.serial + "-b"))
    other_finger = channel_gain(dataclasses.replace(sensor, finger="right" if sensor.finger != "right" else "left"))
    np.testing.assert_array_equal(same, channel_gain(sensor))
    assert not np.allclose(other_serial, same) and not np.allclose(other_finger, same)
