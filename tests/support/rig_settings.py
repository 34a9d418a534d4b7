"""A rig's settings file as a tester makes one: a copy of the shipped settings with some values changed."""

from __future__ import annotations

import shutil
from pathlib import Path

from teleop.settings import default_settings_path
from teleop.settings_edit import update_settings_file


def rig_settings(tmp_path: Path, changes: dict) -> Path:
    """``tmp_path / "rig.toml"``: the shipped settings with ``changes`` (dotted key -> value) written in."""
    path = tmp_path / "rig.toml"
    shutil.copy(default_settings_path(), path)
    update_settings_file(path, changes)
    return path
