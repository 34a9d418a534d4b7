"""A flat (``mini``) sensor with an odd image side at a binning of 2: a frame decoded smaller would
round that side (its pixels no longer the grid's 2 x 2 blocks), so putting it on the depth grid is
refused with the binning rule, whatever its encoding; binning 1 takes it as it is."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from estimator.errors import PerceptionError
from estimator.perception.grid import decode_frame, frame_on_grid, to_grid
from teleop.settings import SensorSettings


def _mini(width_px, height_px):
    return SensorSettings(model="mini", raw_width_px=width_px, raw_height_px=height_px, warped_width_px=width_px,
                          warped_height_px=height_px, crop_px=0, pixel_pitch_m=1.475e-4)


def _encoded(image):
    return {"png": cv2.imencode(".png", image)[1], "jpeg": cv2.imencode(".jpg", image)[1], "raw": image}


SIZES = [(321, 241), (239, 319), (320, 241)]


@pytest.mark.parametrize(("width_px", "height_px"), SIZES)
@pytest.mark.parametrize("encoding", ["png", "jpeg", "raw"])
def test_an_odd_side_is_refused_at_binning_2_naming_the_binning(width_px, height_px, encoding):
    sensor = _mini(width_px, height_px)
    image = np.random.default_rng(0).integers(0, 256, (height_px, width_px, 3), dtype=np.uint8)
    data = _encoded(image)[encoding]
    sides = f"{height_px} x {width_px} px"
    for decode in (decode_frame, frame_on_grid):
        with pytest.raises(PerceptionError, match=f"frame 4: binning 2: does not divide both sides of the {sides}"):
            decode(data, encoding, sensor, binning=2, where="frame 4")
    assert frame_on_grid(data, encoding, sensor, binning=1).shape == (height_px, width_px, 3)


@pytest.mark.parametrize(("width_px", "height_px"), SIZES)
def test_to_grid_refuses_a_rounded_frame_of_an_odd_side(width_px, height_px):
    # What a PNG decoded at half size gives: the odd side rounded down, of the size binning 2 expects.
    rounded = np.zeros((height_px // 2, width_px // 2, 3), np.uint8)
    with pytest.raises(PerceptionError, match=rf"binning 2: does not divide the {height_px} x {width_px} px image grid"):
        to_grid(rounded, _mini(width_px, height_px), binning=2)
