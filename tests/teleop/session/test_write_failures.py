"""Full and read-only disks under ``teleop record`` and ``teleop recover``: what is left, and what is said."""

from __future__ import annotations

import errno
from pathlib import Path

import pytest

import teleop.cli
from teleop.errors import SessionLogError
from teleop.session import LogReader, SessionRecorder, record_cli, recover
from teleop.session.recorder import RECORDING_STOPPED, RECORDING_STOPPED_STATUS, RecorderStats
from teleop.session.recordfile import LogSink

NOWHERE = "tcp://127.0.0.1:1"  # connected lazily: nothing needs to listen there


def test_a_log_whose_start_cannot_be_written_is_removed_so_the_next_recording_may_take_its_name(
        tmp_path, session_settings, monkeypatch):
    path = tmp_path / "session.mcap"

    def disk_full(self, data):
        raise OSError(errno.ENOSPC, "No space left on device")

    with monkeypatch.context() as patch:
        patch.setattr(LogSink, "write", disk_full)
        with pytest.raises(SessionLogError, match=f"cannot write the start of session log {path}: No space left"):
            SessionRecorder(path, NOWHERE, settings=session_settings, overwrite=False).open()
    # An empty file left there refused the next `teleop record --out` and read as no MCAP log.
    assert not path.exists()
    with SessionRecorder(path, NOWHERE, settings=session_settings, overwrite=False):
        pass
    reader = LogReader(path)
    assert list(reader.messages()) == [] and reader.complete


def test_the_record_summary_after_a_write_error_says_what_was_stored_and_what_was_lost(
        tmp_path, capsys, monkeypatch):
    out = tmp_path / "session.mcap"
    error = f"writing {out} failed: No space left on device"
    stats = RecorderStats(messages=1579, saved_messages=1548, file_bytes=12_500_000, error=error)
    monkeypatch.setattr(record_cli, "_record_until_stopped", lambda recorder, duration_s: stats)
    code = teleop.cli.main(["record", "--out", str(out), "--endpoint", NOWHERE, "--duration-s", "1"])
    err = capsys.readouterr().err
    assert code == RECORDING_STOPPED_STATUS
    # Not "recorded 1579": `teleop recover` salvages 1548, and the 31 were said nowhere.
    assert (f"recorded 1548 messages (12.5 MB) from {NOWHERE} into {out}, and lost 31 with the chunk that "
            "could not be written; refused 0, missed 0") in err
    assert err.rstrip().splitlines()[-1].startswith(f"{RECORDING_STOPPED}{error}")


def test_recovering_onto_a_read_only_file_system_is_one_error_naming_out(tmp_path, recorded, capsys, monkeypatch):
    folder = tmp_path / "ro"
    folder.mkdir()
    out = folder / "fixed.mcap"
    opened = Path.open

    def read_only_open(self, mode="r", *args, **kwargs):
        if self.parent == folder and "w" in mode:
            raise OSError(errno.EROFS, "Read-only file system", str(self))
        return opened(self, mode, *args, **kwargs)

    def read_only_unlink(self, missing_ok=False):
        # As Linux does: EROFS for a name on a read-only mount, whether it exists or not.
        raise OSError(errno.EROFS, "Read-only file system", str(self))

    monkeypatch.setattr(Path, "open", read_only_open)
    monkeypatch.setattr(Path, "unlink", read_only_unlink)
    with pytest.raises(SessionLogError, match=f"cannot write the recovered log {out}: Read-only file system"):
        recover(recorded.path, out)
    assert teleop.cli.main(["recover", str(recorded.path), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err
    assert f"teleop recover: error: cannot write the recovered log {out}: Read-only file system" in err
