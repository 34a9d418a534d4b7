"""One writer per session log: a second recorder, ``teleop label`` and ``teleop recover --out`` are
refused on a log a recorder is writing; a footer followed by another writer's bytes is told; what a
stop leaves queued is counted."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from teleop.bus import Publisher
from teleop.cli import main
from teleop.errors import SessionLogError
from teleop.session import LogReader, SessionRecorder, recover
from teleop.session import recorder as recorder_module
from teleop.session.label import label_session

TELEOP = Path(sys.executable).parent / "teleop"
QUIET = "tcp://127.0.0.1:1"  # nothing publishes there: the recorder only writes its log's start and end


@pytest.fixture
def first(tmp_path):
    """A recorder writing ``tmp_path / "held.mcap"``, open for the test, closed after it."""
    recorder = SessionRecorder(tmp_path / "held.mcap", QUIET).open()
    yield recorder
    recorder.close()


def _complete(path: Path) -> bool:
    reader = LogReader(path)
    list(reader.records())
    return reader.complete and reader.good_bytes == path.stat().st_size


@pytest.mark.slow
@pytest.mark.parametrize("overwrite", [True, False])
def test_a_second_recorder_on_a_log_being_recorded_is_refused_naming_the_holder(first, overwrite):
    with pytest.raises(SessionLogError, match=f"held by another process \\(PID {os.getpid()}\\)") as info:
        SessionRecorder(first.out, QUIET, **({} if overwrite else {"overwrite": False})).open()  # True: the default
    assert str(first.out) in str(info.value)
    first.close()
    assert _complete(first.out)  # the first recorder's log is whole: nothing truncated or written over it


@pytest.mark.slow
def test_the_record_command_with_overwrite_is_refused_on_a_log_being_recorded(first):
    result = subprocess.run(
        [str(TELEOP), "record", "--out", str(first.out), "--overwrite", "--duration-s", "0.1",
         "--endpoint", QUIET],
        capture_output=True, text=True, timeout=120,
    )
    assert result.returncode == 2 and "Traceback" not in result.stderr
    assert f"{first.out} is held by another process (PID {os.getpid()})" in result.stderr
    first.close()
    assert _complete(first.out)


def test_a_recorder_without_overwrite_never_replaces_a_file(tmp_path):
    path = tmp_path / "exists.mcap"
    path.write_bytes(b"precious")
    with pytest.raises(SessionLogError, match="exists: choose another name or pass --overwrite"):
        SessionRecorder(path, QUIET, overwrite=False).open()
    assert path.read_bytes() == b"precious"
    with SessionRecorder(path, QUIET, overwrite=True):  # once no recorder holds it, it may be replaced
        pass
    assert _complete(path)


@pytest.mark.slow
def test_label_and_recover_refuse_a_log_being_recorded(first, recorded, tmp_path):
    csv_path = tmp_path / "labels.csv"
    csv_path.write_text("grasp_id,object\ng0,stress_ball\n", encoding="utf-8")
    with pytest.raises(SessionLogError, match="held by another process"):
        label_session(first.out, csv_path)
    with pytest.raises(SessionLogError, match="held by another process"):
        recover(recorded.path, first.out)
    assert main(["recover", str(recorded.path), "--out", str(first.out), "--overwrite"]) == 2
    first.close()
    assert _complete(first.out) and LogReader(first.out).info().session  # still the recorder's own log


@pytest.mark.slow
def test_recover_never_renames_over_a_log_a_recorder_took_while_it_read(recorded, tmp_path, monkeypatch, capsys):
    """Checked as it starts, and held across the rename: a recorder that started in between keeps its log."""
    from teleop.session import recover_cli

    out, taken = tmp_path / "out.mcap", []
    out.write_bytes(b"an older recovery")

    def slow_recover(*args, **kwargs):  # a long recovery, during which a recorder takes --out
        report = recover(*args, **kwargs)
        taken.append(SessionRecorder(out, QUIET, overwrite=True).open())
        return report

    monkeypatch.setattr(recover_cli, "recover", slow_recover)
    try:
        assert main(["recover", str(recorded.path), "--out", str(out), "--overwrite"]) == 2
        assert "held by another process" in capsys.readouterr().err
    finally:
        for recorder in taken:
            recorder.close()
    assert _complete(out) and LogReader(out).info().session  # the recorder's own log, whole
    assert sorted(f.name for f in tmp_path.iterdir()) == ["out.mcap"]  # and no staged recovery left behind


def test_a_file_system_without_locks_records_unguarded_and_says_so(tmp_path, monkeypatch, caplog):
    import errno

    from teleop.session import recordfile

    def no_flock(fd, operation):
        raise OSError(errno.ENOLCK, "No locks available")

    monkeypatch.setattr(recordfile, "_unlockable", set())
    monkeypatch.setattr(recordfile.fcntl, "flock", no_flock)
    with SessionRecorder(tmp_path / "nfs.mcap", QUIET):
        pass
    assert _complete(tmp_path / "nfs.mcap") and "cannot be locked on this file system" in caplog.text


def test_recover_tells_the_bytes_after_a_footer(recorded, tmp_path, capsys):
    doubled = tmp_path / "doubled.mcap"
    shutil.copyfile(recorded.path, doubled)
    size = doubled.stat().st_size
    with doubled.open("ab") as file:  # as a first recorder writing on past the second one's footer
        file.seek(size + 4096)
        file.write(recorded.path.read_bytes()[8:])
    trailing = doubled.stat().st_size - size
    assert main(["recover", str(doubled), "--out", str(tmp_path / "fixed.mcap"), "--json"]) == 0
    captured = capsys.readouterr()
    assert json.loads(captured.out.splitlines()[-1])["trailing_bytes"] == trailing
    assert f"complete up to its footer at byte {size}, but {trailing} bytes of trailing data" in captured.err
    assert main(["recover", str(recorded.path), "--out", str(tmp_path / "whole.mcap"), "--json"]) == 0
    assert json.loads(capsys.readouterr().out.splitlines()[-1])["trailing_bytes"] == 0


def test_messages_still_queued_when_a_stop_gives_up_are_counted(tmp_path, monkeypatch, helpers):
    path = tmp_path / "stopped.mcap"
    with Publisher("tcp://127.0.0.1:*", lossless=True, source="robot") as pub:
        recorder = SessionRecorder(path, [pub.endpoint]).open()
        pub.wait_for_subscriber("", timeout_s=30.0)
        for k in range(20):
            pub.send("force", t_capture_s=float(k), t_s=[float(k)], value_n=[1.0])
        subscriber = recorder._subscriber
        helpers.wait_for(lambda: (subscriber.recv(timeout_s=0.05), len(subscriber.captured))[1] >= 20,
                         what="20 messages received")
        # A stop whose time to store what is queued is already over (as after a long Ctrl-Z).
        monkeypatch.setattr(recorder_module, "PENDING_S", -1.0)
        monkeypatch.setattr(recorder, "_drain", lambda: 0)
        stats = recorder.close()
    assert stats.messages == 0 and stats.not_stored == subscriber.stats.received >= 20
    assert stats.as_dict()["not_stored"] == stats.not_stored
    assert json.loads(LogReader(path).info().metadata["session_end"]["not_stored"]) == stats.not_stored


def test_checks_take_a_shared_lock_as_nfs_grants_read_only_files(recorded, tmp_path, monkeypatch):
    """NFS emulates flock with byte-range locks: an exclusive one needs a file open for writing."""
    import errno
    import fcntl

    from teleop.session import recordfile

    flock = fcntl.flock

    def nfs_flock(fd, operation):
        if operation & fcntl.LOCK_EX and fcntl.fcntl(fd, fcntl.F_GETFL) & os.O_ACCMODE == os.O_RDONLY:
            raise OSError(errno.EBADF, "Bad file descriptor")
        return flock(fd, operation)

    monkeypatch.setattr(recordfile.fcntl, "flock", nfs_flock)
    log = tmp_path / "session.mcap"
    shutil.copyfile(recorded.path, log)
    assert recordfile.held_by(log) is None
    (tmp_path / "labels.csv").write_text("grasp_id,object\ng0,stress_ball\n", encoding="utf-8")
    label_session(log, tmp_path / "labels.csv")  # holds the log's lock while it rewrites it
    with SessionRecorder(tmp_path / "new.mcap", QUIET) as recorder:  # a recorder's lock is exclusive
        assert recordfile.held_by(recorder.out) == os.getpid()
