"""Presses clipped at 0 or 255 over most of the image (overexposed or dark) are refused by index, by
``estimator calibrate`` and by :func:`fit_calibration`; real presses clip nothing."""

from __future__ import annotations

import numpy as np
import pytest

from estimator.cli import main
from estimator.errors import CalibrationError
from estimator.perception import fit_calibration

MINI_ARGS = ["--ball-radius-mm", "2", "--mm-per-px", "0.0295"]


def test_real_presses_clip_nothing(gelsight_presses, mini_presses):
    from estimator.perception.press_circles import CLIPPED_SHARE, clipped_share

    for presses in (gelsight_presses, mini_presses):
        assert max(clipped_share(image) for image in (presses.reference, *presses.images)) < 0.01 < CLIPPED_SHARE


def test_calibrate_refuses_saturated_or_black_presses_by_index(tmp_path, gelsight_presses, capsys):
    pack, out = tmp_path / "pack.npz", tmp_path / "c.npz"
    images = gelsight_presses.images[:6].copy()
    images[2] = 255  # overexposed: every channel saturated
    images[4, 40:] = 0  # dark over most of the image
    np.savez(pack, f0=gelsight_presses.reference, imgs=images,
             touch_center=gelsight_presses.centers_px[:6], touch_radius=gelsight_presses.radii_px[:6])
    assert main(["calibrate", "--presses", str(pack), *MINI_ARGS, "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert f"{pack}: 2 of the 3 presses to calibrate on are clipped at 0 or 255" in err
    assert "2 (100%), 4 (92%)" in err and not out.exists()


def test_fit_calibration_refuses_a_clipped_press_or_reference(gelsight_presses):
    p = gelsight_presses
    images = p.images[:3].copy()
    images[1, ..., 2] = 255  # the red channel saturated everywhere
    kwargs = dict(ball_radius_m=2e-3, pixel_pitch_m=2.95e-5)
    with pytest.raises(CalibrationError, match=r"presses: 1 of the 3 .* clipped .*: 1 \(100%\)"):
        fit_calibration(p.reference, images, p.centers_px[:3], p.radii_px[:3], **kwargs)
    with pytest.raises(CalibrationError, match=r"reference: a channel clipped at 0 or 255 in 100%"):
        fit_calibration(np.zeros_like(p.reference), p.images[:3], p.centers_px[:3], p.radii_px[:3], **kwargs)
