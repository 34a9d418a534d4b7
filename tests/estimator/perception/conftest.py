"""Real GelSight ball presses shipped in the ``taxim`` wheel, and calibrations fitted on them."""

from __future__ import annotations

from pathlib import Path

import pytest

from estimator.perception import fit_calibration, load_presses, split_presses

# Ball radius of both taxim press sets; pixel pitch from each set's params.json ("pixmm").
BALL_RADIUS_M = 2.0e-3
TAXIM_PITCH_M = 0.0295e-3


@pytest.fixture(scope="session")
def taxim_pack(taxim_calib_dir, missing_data):
    """Path of a taxim dataPack: ``taxim_pack("gelsight")`` or ``taxim_pack("gelsight_mini")``."""
    root = taxim_calib_dir

    def path(sensor: str) -> Path:
        pack = root / sensor / "dataPack.npz"
        if not pack.is_file():
            missing_data(f"{pack} not found")
        return pack

    return path


@pytest.fixture(scope="session")
def gelsight_presses(taxim_pack):
    return load_presses(taxim_pack("gelsight"))


@pytest.fixture(scope="session")
def mini_presses(taxim_pack):
    return load_presses(taxim_pack("gelsight_mini"))


def _calibrate_half(presses):
    train = split_presses(len(presses), 0.5)
    return fit_calibration(
        presses.reference, presses.images[train], presses.centers_px[train], presses.radii_px[train],
        ball_radius_m=BALL_RADIUS_M, pixel_pitch_m=TAXIM_PITCH_M,
        provenance={"train_indices": train.tolist()},
    )


@pytest.fixture(scope="session")
def gelsight_calibration(gelsight_presses):
    """Calibrated on every other GelSight press (24 of 48)."""
    return _calibrate_half(gelsight_presses)


@pytest.fixture(scope="session")
def mini_calibration(mini_presses):
    """Calibrated on every other GelSight Mini press (12 of 24)."""
    return _calibrate_half(mini_presses)
