"""A non-Wedge sensor's frame of another size than its settings say: refused where it is put on the
depth grid or decoded, naming the sensor's raw size and the size the frame was captured at, not
the binned sizes the depth solver would see."""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np
import pytest

from estimator.cli import main
from estimator.errors import CalibrationError, PerceptionError
from estimator.measure import reference_frame
from estimator.measurements import check_calibration_fits
from estimator.perception.calibration import Calibration
from estimator.perception.grid import to_grid
from teleop.catalogue import load_catalogue
from teleop.record import FrameStream, write_record
from teleop.settings import CONFIG_DIR, SensorSettings, load_settings
from teleop.sim.grasp import simulate_grasp

MINI = SensorSettings(model="mini", raw_width_px=128, raw_height_px=96, warped_width_px=128, warped_height_px=96,
                      crop_px=0, pixel_pitch_m=1.475e-4)


def test_to_grid_refuses_a_mini_frame_of_another_size_naming_the_captured_size():
    with pytest.raises(PerceptionError, match=r"\(48, 64, 3\) \(sensor 'left', binning 2\), got uint8 \(240, 320, 3\), "
                                              r"binned from a frame of about 640x480 px for the sensor's 128x96"):
        to_grid(np.zeros((240, 320, 3), np.uint8), MINI, binning=2)
    image = np.zeros((48, 64, 3), np.uint8)
    assert to_grid(image, MINI, binning=2) is image


def flat_calibration(shape):
    """A calibration of ``shape`` px at the mini's pitch reading every colour as flat."""
    return Calibration(np.zeros((1, 1, 2, 2, 2, 2), np.float32), shape, MINI.pixel_pitch_m, 2e-3, 1.0)


@pytest.fixture(scope="module")
def big_frames(tmp_path_factory):
    """A grasp whose left sensor says 128 x 96 px (a mini) while its frames are 640 x 480 px."""
    settings = load_settings()
    obj = next(o for o in load_catalogue(CONFIG_DIR / "objects.toml") if o.name == "rubber_duck")
    record, _ = simulate_grasp(obj, settings=settings, rng=np.random.default_rng(3), seed=3)
    stream = record.stream("left")
    big = [cv2.resize(stream.frame(i), (640, 480)) for i in range(len(stream))]
    frames = tuple(FrameStream.from_frames("left", stream.t_s, big, encoding="png") if s.finger == "left" else s
                   for s in record.frames)
    folder = tmp_path_factory.mktemp("big")
    calibration = flat_calibration((96, 128)).save(folder / "mini.npz")  # fits the sensor: the frames do not
    mini = dataclasses.replace(MINI, finger="left", calibration=str(calibration))
    sensors = tuple(mini if s.finger == "left" else s for s in record.sensors)
    record = dataclasses.replace(record, frames=frames, sensors=sensors)
    path = folder / "big.grasp"
    write_record(record, path)
    return record, path


def test_estimate_names_the_captured_size_of_a_mini_frame(big_frames, capsys):
    _, path = big_frames
    assert main(["estimate", str(path), "--method", "series"]) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err and "got 240 x 320" not in err
    assert "binned from a frame of about 640x480 px for the sensor's 128x96" in err
    assert "frame 31 of finger 'left'" in err  # which frame (the first the estimate decodes), as live


def test_frames_decoded_offline_are_checked_in_their_header(big_frames):
    record, _ = big_frames
    with pytest.raises(PerceptionError, match=r"finger 'left' frame 2: image declares 640x480 px, expected 128x96 px"):
        reference_frame(record, "left", np.array([2, 3]), binning=2)


def test_a_mini_calibration_mismatch_does_not_say_warped_and_cropped():
    cal = flat_calibration((48, 64))
    with pytest.raises(CalibrationError, match=r"gives \(96, 128\)$"):
        check_calibration_fits(cal, MINI)
