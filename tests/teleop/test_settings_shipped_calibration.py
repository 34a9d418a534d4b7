"""A copy of the shipped settings elsewhere: its relative calibration paths miss, and the warning
points at the shipped calibrations of those names rather than at a capture."""

from __future__ import annotations

import argparse
import shutil

from teleop.settings import config_dir, default_settings_path, load_settings, missing_calibrations
from teleop.system.settings_cli import run as settings_run


def _copy(tmp_path):
    path = tmp_path / "settings.toml"
    shutil.copy(default_settings_path(), path)
    return path


def test_a_copied_settings_files_missing_calibrations_are_pointed_at_the_shipped_ones(tmp_path, capsys):
    # `teleop settings` told the user to recapture with `estimator calibrate`, for a simulated sensor.
    path = _copy(tmp_path)
    warnings = missing_calibrations(load_settings(path), path)
    assert warnings == [
        f"[sensors.{finger}] calibration {tmp_path / 'calibration' / f'sim-wedge-{finger}.npz'}: no such file (a "
        f"relative path resolves against {tmp_path}); the shipped one is "
        f"{config_dir() / 'calibration' / f'sim-wedge-{finger}.npz'}: point [sensors.{finger}] calibration at it, "
        "or make your own with `estimator calibrate`"
        for finger in ("left", "right")]
    settings_run(argparse.Namespace(path=str(path), settings=None))
    assert "the shipped one is" in capsys.readouterr().err


def test_a_missing_calibration_no_shipped_one_is_named_as_is_made_with_estimator_calibrate(tmp_path):
    path = _copy(tmp_path)
    path.write_text(path.read_text(encoding="utf-8").replace("sim-wedge-left.npz", "mine.npz"), encoding="utf-8")
    warning = missing_calibrations(load_settings(path), path)[0]
    assert warning.endswith("mine.npz: no such file (a relative path resolves against "
                            f"{tmp_path}); make it with `estimator calibrate`")
