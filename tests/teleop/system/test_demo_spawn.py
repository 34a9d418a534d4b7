"""``teleop demo``'s children run the packages the parent imported, whatever modules the working folder holds."""

from __future__ import annotations

import os
from pathlib import Path

from teleop.system import live_system
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


def test_a_child_runs_the_packages_the_parent_imported(tmp_path, monkeypatch):
    # A second checkout run with the first one's venv (an editable install points at the first): the
    # children must run this checkout's code, as the parent does, not the install's.
    checkout = tmp_path / "checkout"
    (checkout / "teleop").mkdir(parents=True)
    (checkout / "teleop" / "__init__.py").write_text("")
    (checkout / "teleop" / "cli.py").write_text("def main():\n    print('this checkout ran')\n    return 0\n")
    monkeypatch.setattr(live_system, "package_root", lambda: checkout)
    system = LiveSystem(Path("settings.toml"), "quick", tmp_path, Path("calibration.npz"))
    system._spawn("node", ["teleop", "--help"], dict(os.environ))
    child = system.children["node"]
    assert child.process.wait(timeout=60) == 0, child.log_path.read_text()
    assert "this checkout ran" in child.log_path.read_text()
