"""Fixtures of the rig calibrations' tests."""

from __future__ import annotations

import shutil

import pytest

from teleop.settings import default_settings_path
from teleop.settings_edit import update_settings_file


@pytest.fixture
def absent_cell_rig(tmp_path):
    """A settings file whose load cell is a serial one on a port that is not there."""
    path = tmp_path / "rig.toml"
    shutil.copy(default_settings_path(), path)
    update_settings_file(path, {"load_cell.backend": "serial", "load_cell.port": "/dev/ttyUSB9"})
    return path
