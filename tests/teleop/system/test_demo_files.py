"""``teleop demo``'s files: a run folder it cannot make is refused in one line, and a recorder
whose disk filled stops the recording, not the session."""

from __future__ import annotations

import argparse
from dataclasses import dataclass
from pathlib import Path

import pytest

import teleop.cli
from teleop.errors import TeleopError
from teleop.session import record_cli
from teleop.session.recorder import RECORDING_STOPPED_STATUS, RecorderStats
from teleop.system.live_system import LiveSystem, _Child


@pytest.mark.parametrize("command", ["demo", "bench-latency"])
@pytest.mark.parametrize("under", ["afile/out", "afile"])
def test_an_out_folder_under_a_plain_file_is_refused_naming_the_file(tmp_path, capsys, command, under):
    (tmp_path / "afile").write_text("not a folder")
    out = tmp_path / under
    assert teleop.cli.main([command, "--scene", "quick", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert f"--out {out}: {tmp_path / 'afile'} is not a directory" in err, err
    assert "Traceback" not in err


@dataclass
class _Exited:
    """A child process that exited with ``code``."""

    code: int | None
    pid: int = 0

    def poll(self) -> int | None:
        return self.code


def _system(tmp_path: Path, recorder_code: int | None) -> LiveSystem:
    system = LiveSystem(Path("settings.toml"), "quick", tmp_path, Path("calibration.npz"))
    log = tmp_path / "recorder.log"
    log.write_text("writing session.mcap failed: No space left on device; recording stopped, ...\n"
                   "recording stopped: writing session.mcap failed: No space left on device; the log is readable "
                   "up to there: `teleop recover session.mcap --out FIXED.mcap`\n")
    system.children = {"recorder": _Child("recorder", _Exited(recorder_code), log),
                       "node": _Child("node", _Exited(None), tmp_path / "node.log")}
    return system


def test_a_recorder_that_stopped_recording_leaves_the_session_running_and_says_why(tmp_path, capsys):
    system = _system(tmp_path, RECORDING_STOPPED_STATUS)
    system.check()
    system.check()  # said once
    assert system.recording_stopped.startswith("writing session.mcap failed: No space left on device;")
    err = capsys.readouterr().err
    assert err.count("recording stopped: writing session.mcap failed: No space left on device") == 1, err
    assert "the session log holds what came before" in err


def test_a_recorder_that_failed_otherwise_still_stops_the_session(tmp_path):
    with pytest.raises(TeleopError, match="recorder exited with status 2"):
        _system(tmp_path, 2).check()


def test_teleop_record_exits_with_the_stopped_status_its_last_line_saying_why(tmp_path, monkeypatch, capsys):
    stats = RecorderStats(error="writing session.mcap failed: No space left on device")
    monkeypatch.setattr(record_cli, "_record_until_stopped", lambda *_: stats)
    parser = argparse.ArgumentParser()
    record_cli.add_arguments(parser)
    args = parser.parse_args(["--out", str(tmp_path / "session.mcap"), "--endpoint", "tcp://127.0.0.1:1"])
    assert record_cli.run(args) == RECORDING_STOPPED_STATUS != 2
    last = capsys.readouterr().err.strip().splitlines()[-1]
    assert last.startswith("recording stopped: writing session.mcap failed: No space left on device;"), last


def test_an_output_file_under_a_plain_file_names_the_file_not_file_exists(tmp_path):
    from teleop.clikit import output_file

    (tmp_path / "afile").write_text("not a folder")
    with pytest.raises(TeleopError, match=f"--out {tmp_path}/afile/x.mcap: {tmp_path}/afile is not a directory"):
        output_file("--out", str(tmp_path / "afile" / "x.mcap"))
