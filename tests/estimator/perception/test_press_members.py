"""A press file's circles are refused when they are not physical, naming the file and the member
(``touch_radius``, not the internal ``radii_px``), before any stage can misreport them."""

from __future__ import annotations

import numpy as np
import pytest

from estimator.cli import main
from estimator.errors import CalibrationError
from estimator.perception import load_presses

N = 4


def _pack(path, **override):
    members = dict(
        f0=np.full((12, 16, 3), 90, np.uint8),
        imgs=np.full((N, 12, 16, 3), 100, np.uint8),
        touch_center=np.tile([8.0, 6.0], (N, 1)),
        touch_radius=np.full(N, 3.0),
    )
    members.update(override)
    np.savez(path, **members)
    return path


def test_sound_circles_are_read(tmp_path):
    presses = load_presses(_pack(tmp_path / "p.npz"))
    assert presses.circles == "recorded" and presses.radii_px.tolist() == [3.0] * N


@pytest.mark.parametrize("value", [np.nan, np.inf, -np.inf])
def test_a_non_finite_touch_center_is_refused_by_file_member_and_press(tmp_path, value):
    centers = np.tile([8.0, 6.0], (N, 1))
    centers[2, 1] = value
    path = _pack(tmp_path / "p.npz", touch_center=centers)
    with pytest.raises(CalibrationError, match=r"p\.npz: touch_center: press 2 .*expected finite"):
        load_presses(path)


@pytest.mark.parametrize("value", [0.0, -3.0, np.nan, np.inf])
def test_a_touch_radius_not_positive_and_finite_is_refused_by_file_member_and_press(tmp_path, value):
    radii = np.full(N, 3.0)
    radii[1] = value
    path = _pack(tmp_path / "p.npz", touch_radius=radii)
    with pytest.raises(CalibrationError, match=r"p\.npz: touch_radius: press 1 .*expected positive"):
        load_presses(path)


def test_non_numeric_circles_are_refused_by_member(tmp_path):
    path = _pack(tmp_path / "p.npz", touch_radius=np.array(["a"] * N))
    with pytest.raises(CalibrationError, match=r"p\.npz: touch_radius: expected numbers"):
        load_presses(path)


def test_calibrate_names_the_file_and_touch_radius_for_negated_radii(tmp_path, gelsight_presses, capsys):
    p, path, out = gelsight_presses, tmp_path / "neg.npz", tmp_path / "c.npz"
    np.savez(path, f0=p.reference, imgs=p.images[:6], touch_center=p.centers_px[:6], touch_radius=-p.radii_px[:6])
    args = ["--ball-radius-mm", "2", "--mm-per-px", "0.0295", "--out", str(out)]
    assert main(["calibrate", "--presses", str(path), *args]) == 2
    err = capsys.readouterr().err
    assert f"{path}: touch_radius: press 0" in err and "radii_px" not in err
    assert not out.exists()
