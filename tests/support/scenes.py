"""Scenes for tests of the live system."""

from __future__ import annotations

import textwrap
from pathlib import Path


def one_grasp_scene(tmp_path: Path, obj: str = "steel_ball_bearing") -> Path:
    """A scene of one short grasp (a steel ball loads within a few frames), or of ``obj``."""
    path = tmp_path / "scene.toml"
    path.write_text(textwrap.dedent(f"""
        description = "one grasp"
        objects = ["{obj}"]
        seed = 5
    """))
    return path
