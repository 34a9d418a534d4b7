"""The rig calibrations refuse every simulated device, not only the backends named ``sim``: a simulated
device's constants are set, not measured."""

from __future__ import annotations

import argparse
import dataclasses

import pytest
from support import second_sim

from teleop.errors import SettingsError, TeleopError
from teleop.rig import camera_calibration, gripper_calibration
from teleop.rig.load_cell_calibration import connect_counts_cell
from teleop.settings import default_settings_path, load_settings


@pytest.fixture
def slow_cell(monkeypatch):
    """The shipped settings with a second simulated load cell."""
    second_sim.register(monkeypatch, "load cell")
    return second_sim.with_load_cell(load_settings(default_settings_path()))


@pytest.mark.parametrize("backend", ["sim", second_sim.NAME])
def test_counts_calibration_refuses_a_simulated_cell_naming_its_backend(slow_cell, backend):
    settings = second_sim.with_load_cell(slow_cell, backend)
    with pytest.raises(SettingsError, match=f"load_cell.backend = '{backend}' is simulated"):
        connect_counts_cell(settings.load_cell)


def test_gripper_calibration_refuses_a_second_simulated_cell(slow_cell):
    with pytest.raises(SettingsError, match=f"load_cell.backend = '{second_sim.NAME}' is simulated"):
        gripper_calibration._check(argparse.Namespace(object_width_mm=30.0), slow_cell)


def test_camera_latency_calibration_refuses_a_second_simulated_cell(slow_cell, monkeypatch):
    real_cameras = dataclasses.replace(slow_cell, sensors=tuple(
        dataclasses.replace(s, camera_backend="opencv", camera_source="0") for s in slow_cell.sensors))
    monkeypatch.setattr(camera_calibration, "load_settings", lambda path: real_cameras)
    args = argparse.Namespace(settings="rig.toml", finger=None, latency=True)
    with pytest.raises(TeleopError, match=f"is simulated \\(backend '{second_sim.NAME}'\\)"):
        camera_calibration.run(args)
