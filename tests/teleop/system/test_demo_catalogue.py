"""The session log of a scene's run carries the scene's catalogue, not the shipped one."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from teleop.catalogue import default_catalogue_path
from teleop.live import ENDPOINTS
from teleop.scene import load_scene
from teleop.session import LogReader
from teleop.settings import default_settings_path
from teleop.system.live_system import LiveSystem

TELEOP = Path(sys.executable).parent / "teleop"
BALL = 'name = "stress_ball"\nshape = "sphere"\nmaterial = "foam"\nmodulus_pa = 4.0e4'


def _own_catalogue_scene(folder: Path) -> Path:
    """A scene whose catalogue gives the stress ball another modulus than the shipped one."""
    shipped = default_catalogue_path().read_text(encoding="utf-8")
    assert BALL in shipped
    (folder / "cat.toml").write_text(shipped.replace(BALL, BALL.replace("4.0e4", "9.0e5")), encoding="utf-8")
    scene = folder / "own.toml"
    scene.write_text(f'catalogue = "cat.toml"\nobjects = ["stress_ball"]\nsettings = "{default_settings_path()}"\n',
                     encoding="utf-8")
    return scene


def test_a_scene_keeps_its_catalogue_path(tmp_path):
    assert load_scene(str(_own_catalogue_scene(tmp_path))).catalogue_path == tmp_path / "cat.toml"
    assert load_scene("quick").catalogue_path == default_catalogue_path()


def test_the_demo_recorder_attaches_the_scene_catalogue(tmp_path):
    """The recorder `teleop demo` (and bench-latency) starts, run briefly on its own: the log
    carries the scene's catalogue, from which export and report label the grasps."""
    scene = _own_catalogue_scene(tmp_path)
    system = LiveSystem(default_settings_path(), str(scene), tmp_path / "run", tmp_path / "cal.npz")
    system.endpoints = {name: f"tcp://127.0.0.1:{7000 + i}" for i, name in enumerate(ENDPOINTS)}
    system.run_dir.mkdir()
    line = system._command_lines()["recorder"]
    assert line[:2] == ["teleop", "record"]
    result = subprocess.run([str(TELEOP), *line[1:], "--duration-s", "0.1"], capture_output=True, text=True,
                            timeout=60)
    assert result.returncode == 0, result.stderr
    attachments = LogReader(system.session_log).info().attachments
    assert attachments["catalogue.toml"] == (tmp_path / "cat.toml").read_bytes()
