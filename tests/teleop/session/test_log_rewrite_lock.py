"""One rewrite of a session log at a time: while ``teleop label`` rewrites a log, a second
``teleop label`` and a ``teleop recover --out`` onto it are refused, naming the log and the
process rewriting it, and the first one's labels are all kept."""

from __future__ import annotations

import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest

from teleop.cli import main
from teleop.errors import SessionLogError
from teleop.session import LogReader, recover
from teleop.session.label import label_session

# The first `teleop label`, in its own process: it stops as it starts copying (its rewrite begun)
# until the test lets it go.
SLOW_LABEL = """
import sys, time
from pathlib import Path
from teleop.session import label

log, csv_path, ready, go = sys.argv[1:]
copy = label._copy_with_labels

def slow_copy(*args, **kwargs):
    Path(ready).touch()
    deadline = time.monotonic() + 120
    while not Path(go).exists() and time.monotonic() < deadline:
        time.sleep(0.01)
    return copy(*args, **kwargs)

label._copy_with_labels = slow_copy
label.label_session(log, csv_path)
"""


def _labels(path: Path) -> dict[str, str]:
    return {m.message.fields.grasp_id: m.message.fields.object_name
            for m in LogReader(path).messages(("label",))}


@pytest.fixture
def first_label(recorded, tmp_path):
    """A copy of the recorded session, and a `teleop label` process rewriting it (labelling g0)."""
    log, ready, go = tmp_path / "session.mcap", tmp_path / "ready", tmp_path / "go"
    shutil.copyfile(recorded.path, log)
    (tmp_path / "first.csv").write_text("grasp_id,object\ng0,stress_ball\n", encoding="utf-8")
    process = subprocess.Popen([sys.executable, "-c", SLOW_LABEL, str(log), str(tmp_path / "first.csv"),
                                str(ready), str(go)], stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 120
        while not ready.exists():
            assert process.poll() is None, process.stderr.read()
            assert time.monotonic() < deadline, "the first label run never began its rewrite"
            time.sleep(0.01)
        yield log, process
    finally:
        go.touch()
        try:
            process.wait(timeout=120)
        finally:
            process.kill()


@pytest.mark.slow
def test_a_second_label_run_is_refused_and_the_first_ones_labels_kept(first_label, tmp_path):
    log, process = first_label
    (tmp_path / "second.csv").write_text("grasp_id,object\ng1,stress_ball\n", encoding="utf-8")
    with pytest.raises(SessionLogError, match=f"held by another process \\(PID {process.pid}\\)") as info:
        label_session(log, tmp_path / "second.csv")
    assert str(log) in str(info.value)
    (tmp_path / "go").touch()
    assert process.wait(timeout=120) == 0, process.stderr.read()
    assert _labels(log) == {"g0": "stress_ball"}  # the first run's label, in a whole log
    assert sorted(p.name for p in tmp_path.iterdir() if p.name.startswith("session")) == ["session.mcap"]


@pytest.mark.slow
def test_recover_onto_a_log_being_labelled_is_refused(first_label, recorded, tmp_path, capsys):
    log, process = first_label
    with pytest.raises(SessionLogError, match=f"held by another process \\(PID {process.pid}\\)"):
        recover(recorded.path, log)
    assert main(["recover", str(recorded.path), "--out", str(log), "--overwrite"]) == 2
    assert f"{log} is held by another process (PID {process.pid})" in capsys.readouterr().err
    (tmp_path / "go").touch()
    assert process.wait(timeout=120) == 0, process.stderr.read()
    assert _labels(log) == {"g0": "stress_ball"}


def test_a_rewrite_a_killed_run_left_behind_is_taken_over(recorded, tmp_path):
    log = tmp_path / "session.mcap"
    shutil.copyfile(recorded.path, log)
    log.with_name("session.mcap.partial").write_bytes(b"half a labelled log")  # its run was killed
    (tmp_path / "labels.csv").write_text("grasp_id,object\ng0,stress_ball\n", encoding="utf-8")
    label_session(log, tmp_path / "labels.csv")
    assert _labels(log) == {"g0": "stress_ball"}
    assert sorted(p.name for p in tmp_path.iterdir()) == ["labels.csv", "session.mcap"]
