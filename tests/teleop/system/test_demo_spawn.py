"""``teleop demo``'s children run the installed packages, whatever modules the working folder holds."""

from __future__ import annotations

import os
from pathlib import Path

from teleop.system.live_system import LiveSystem


def test_a_child_runs_the_package_not_a_same_named_script_in_the_working_folder(tmp_path, monkeypatch):
    # `-c` put the working folder first on sys.path: a user's teleop.py there ran instead of the package.
    folder = tmp_path / "work"
    folder.mkdir()
    (folder / "teleop.py").write_text("print('the decoy ran'); raise SystemExit(7)\n")
    monkeypatch.chdir(folder)
    system = LiveSystem(Path("settings.toml"), "quick", tmp_path, Path("calibration.npz"))
    system._spawn("node", ["teleop", "--help"], dict(os.environ))
    child = system.children["node"]
    assert child.process.wait(timeout=60) == 0, child.log_path.read_text()
    assert "the decoy ran" not in child.log_path.read_text()
