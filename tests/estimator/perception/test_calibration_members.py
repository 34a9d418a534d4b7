"""A calibration file whose number members have the wrong shape or type is refused naming the member
and what it should hold, not with numpy's conversion message."""

from __future__ import annotations

import numpy as np
import pytest

from estimator.errors import CalibrationError
from estimator.perception import Calibration, load_calibration


def _saved_with(tmp_path, member, value):
    lut = np.zeros((2, 3, 4, 4, 4, 2), np.float32)
    path = Calibration(lut=lut, image_shape=(20, 30), pixel_pitch_m=3e-5, ball_radius_m=2e-3,
                       provenance={}).save(tmp_path / "cal.npz")
    with np.load(path) as data:
        members = {k: data[k] for k in data.files}
    members[member] = value
    np.savez(tmp_path / "bad.npz", **members)
    return tmp_path / "bad.npz"


@pytest.mark.parametrize(("member", "value", "got"), [
    ("pixel_pitch_m", np.full((2, 2), 3e-5), "a 2-D array of float64"),
    ("pixel_pitch_m", np.array("abc"), "a scalar of <U3 (abc)"),
    ("ball_radius_m", np.array([2e-3]), "a 1-D array of float64"),
    ("relative_range", np.array(True), "a scalar of bool (True)"),
    ("smoothing_px", np.zeros(3), "a 1-D array of float64"),
])
def test_a_number_member_of_the_wrong_shape_or_type_is_named_with_what_it_should_be(tmp_path, member, value, got):
    path = _saved_with(tmp_path, member, value)
    with pytest.raises(CalibrationError) as caught:
        load_calibration(path)
    message = str(caught.value)
    assert message.startswith(f"{path}: {member}: expected a ") and "scalar float" in message, message
    assert got in message, message


@pytest.mark.parametrize(("value", "got"), [(np.array(20), "a scalar of int64"), (np.array(["20", "30"]), "a 1-D array of <U2")])
def test_an_image_shape_that_is_no_pair_of_whole_numbers_is_named(tmp_path, value, got):
    path = _saved_with(tmp_path, "image_shape", value)
    with pytest.raises(CalibrationError, match=rf"image_shape: expected whole numbers \(rows, cols\), got {got}"):
        load_calibration(path)


def test_a_well_formed_member_still_reads(tmp_path):
    path = _saved_with(tmp_path, "pixel_pitch_m", np.array(4e-5))
    assert load_calibration(path).pixel_pitch_m == 4e-5
