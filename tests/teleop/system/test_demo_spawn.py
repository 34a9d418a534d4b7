"""``teleop demo``'s children run the packages the parent imported, whatever modules the working folder holds;
a run folder they cannot write in is said as such."""

from __future__ import annotations

import errno
import os
import subprocess
import sys
from pathlib import Path

import pytest

from teleop.errors import TeleopError
from teleop.system import live_system
from teleop.system.live_system import LiveSystem, _Child


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


def test_a_run_folder_on_a_read_only_file_system_is_refused_naming_out(tmp_path, monkeypatch):
    # The child's log could not be opened: an OSError traceback, not an error naming --out.
    def read_only(path, *args, **kwargs):
        raise OSError(errno.EROFS, "Read-only file system", str(path))

    monkeypatch.setattr(Path, "open", read_only)
    system = LiveSystem(Path("settings.toml"), "quick", tmp_path, Path("calibration.npz"))
    with pytest.raises(TeleopError, match=rf"--out {tmp_path}: cannot write node.log \(Read-only file system\)"):
        system._spawn("node", ["teleop", "--help"], dict(os.environ))
    assert system.children == {}


def test_a_child_that_exits_with_an_empty_log_points_at_its_folder(tmp_path):
    # On a full disk the child's error message is lost with its log: "the end of recorder.log:" and nothing.
    log_path = tmp_path / "recorder.log"
    log_path.write_bytes(b"")
    process = subprocess.Popen([sys.executable, "-c", "raise SystemExit(1)"])
    assert process.wait(timeout=60) == 1
    system = LiveSystem(Path("settings.toml"), "quick", tmp_path, Path("calibration.npz"))
    system.children["recorder"] = _Child("recorder", process, log_path)
    with pytest.raises(TeleopError) as raised:
        system.check()
    assert str(raised.value).startswith(
        f"recorder exited with status 1; its log {log_path} is empty: is {tmp_path} full or unwritable? (free: ")
