"""Crash recovery: a recorder killed outright, logs cut anywhere or damaged, and the record CLI."""

from __future__ import annotations

import io
import json
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import pytest
from mcap.reader import make_reader

from teleop.bus import Publisher
from teleop.bus.wire import encode
from teleop.errors import SessionLogError
from teleop.session import LogReader, recover
from teleop.session.logfile import END_METADATA, MESSAGE_ENCODING, SETTINGS_ATTACHMENT
from teleop.session.recover import RECOVERY_METADATA

TELEOP = Path(sys.executable).parent / "teleop"


def _wire_bytes(message) -> list[bytes]:
    return [bytes(memoryview(frame).cast("B")) for frame in encode(message)]


def _stored_count(path: Path) -> int:
    return sum(1 for _ in LogReader(path).messages()) if path.exists() else 0


def _assert_prefix_of(stored_frames, sent) -> None:
    """The stored messages' frames are those of the first messages sent, byte for byte."""
    assert len(stored_frames) <= len(sent)
    for frames, message in zip(stored_frames, sent, strict=False):
        assert [bytes(f) for f in frames] == _wire_bytes(message)


def _start_recorder(path: Path, endpoint: str, *extra: str) -> subprocess.Popen:
    return subprocess.Popen(
        [
            str(TELEOP),
            "record",
            "--out",
            str(path),
            "--endpoint",
            endpoint,
            "--flush-interval-s",
            "0.05",
            "--chunk-kib",
            "16",
            *extra,
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


def test_a_recorder_killed_with_sigkill_loses_at_most_its_open_chunk(tmp_path, helpers):
    path, fixed = tmp_path / "killed.mcap", tmp_path / "fixed.mcap"
    with Publisher("tcp://127.0.0.1:*", lossless=True, source="robot") as pub:
        proc = _start_recorder(path, pub.endpoint)
        try:
            pub.wait_for_subscriber("", timeout_s=30.0)
            first = helpers.publish_session(pub)
            helpers.wait_for(
                lambda: _stored_count(path) == len(first), what="the first batch on disk"
            )
            late = [
                pub.send("force", t_capture_s=float(i), t_s=[float(i)], value_n=[1.0])
                for i in range(50)
            ]
            proc.send_signal(signal.SIGKILL)
            assert proc.wait(timeout=10) == -signal.SIGKILL
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
    killed = LogReader(path)
    readable = [m.message for m in killed.messages()]
    assert not killed.complete and killed.damage  # no footer: read up to the last complete chunk
    assert len(readable) >= len(first)

    report = recover(path, fixed)
    assert not report.complete and not report.closed_cleanly and report.damage == killed.damage
    assert report.messages == len(readable) and report.undecodable == 0
    assert SETTINGS_ATTACHMENT in report.attachments
    with fixed.open("rb") as f:  # a complete file now: the seeking reader and its summary work
        reader = make_reader(f)
        summary = reader.get_summary()
        metadata = {m.name: m.metadata for m in reader.iter_metadata()}
        attachments = {a.name for a in reader.iter_attachments()}
    stored = [m.frames for m in LogReader(fixed).messages()]
    bus = [c.id for c in summary.channels.values() if c.message_encoding == MESSAGE_ENCODING]
    counts = summary.statistics.channel_message_counts
    assert sum(counts.get(c, 0) for c in bus) == len(readable) >= len(first)
    _assert_prefix_of(stored, first + late)
    assert SETTINGS_ATTACHMENT in attachments and "catalogue.toml" in attachments
    assert json.loads(metadata[RECOVERY_METADATA]["messages"]) == len(readable)
    assert END_METADATA not in metadata


def test_sigterm_stops_the_record_command_cleanly(tmp_path, helpers):
    path = tmp_path / "clean.mcap"
    with Publisher("tcp://127.0.0.1:*", lossless=True, source="robot") as pub:
        proc = _start_recorder(path, pub.endpoint, "--json", "--scene", "quick")
        try:
            pub.wait_for_subscriber("", timeout_s=30.0)
            sent = helpers.publish_session(pub)
            helpers.wait_for(lambda: _stored_count(path) == len(sent), what="the session on disk")
            proc.send_signal(signal.SIGTERM)
            out, err = proc.communicate(timeout=10)
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
    assert proc.returncode == 0, err
    summary = json.loads(out.strip().splitlines()[-1])
    assert (
        summary["messages"] == len(sent)
        and summary["error"] is None
        and summary["out"] == str(path)
    )
    reader = LogReader(path)
    assert len(list(reader.messages())) == len(sent) and reader.complete
    info = reader.info()
    assert END_METADATA in info.metadata and info.session["scene"] == "quick"


def test_the_record_command_refuses_to_overwrite_a_log(tmp_path):
    path = tmp_path / "exists.mcap"
    path.write_bytes(b"precious")
    result = subprocess.run(
        [str(TELEOP), "record", "--out", str(path), "--duration-s", "0.1"],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert result.returncode == 2 and "exists" in result.stderr and "Traceback" not in result.stderr
    assert path.read_bytes() == b"precious"


@pytest.fixture(scope="module")
def log_bytes(recorded) -> bytes:
    return recorded.path.read_bytes()


@pytest.mark.parametrize("fraction", [0.0, 0.001, 0.05, 0.2, 0.37, 0.5, 0.63, 0.8, 0.95, 0.999])
def test_a_log_cut_anywhere_reads_and_recovers_a_prefix(tmp_path, recorded, log_bytes, fraction):
    cut = max(9, int(len(log_bytes) * fraction))  # the magic and the opcode of the header survive
    damaged = tmp_path / "cut.mcap"
    damaged.write_bytes(log_bytes[:cut])
    reader = LogReader(damaged)
    readable = [m.frames for m in reader.messages()]
    assert not reader.complete and reader.damage and reader.good_bytes <= cut
    _assert_prefix_of(readable, recorded.sent)
    if reader.good_bytes == 0:  # not even the header is complete: nothing to recover
        with pytest.raises(SessionLogError, match="no readable MCAP header"):
            recover(damaged, tmp_path / "fixed.mcap")
        return
    report = recover(damaged, tmp_path / "fixed.mcap")
    assert report.messages == len(readable) and report.salvaged_bytes == reader.good_bytes
    recovered = LogReader(tmp_path / "fixed.mcap")
    assert [m.frames for m in recovered.messages()] == readable and recovered.complete


@pytest.mark.parametrize("cut", [200, "attachment"])
def test_a_log_cut_inside_an_attachment_is_said_to_end_inside_it(tmp_path, log_bytes, cut):
    if cut == "attachment":  # halfway through the largest one
        with io.BytesIO(log_bytes) as f:
            index = max(make_reader(f).get_summary().attachment_indexes, key=lambda a: a.length)
        cut = index.offset + index.length // 2
    damaged = tmp_path / "cut.mcap"
    damaged.write_bytes(log_bytes[:cut])
    reader = LogReader(damaged)
    info = reader.info()
    assert info.damage.startswith(f"the file ends inside the record after byte {reader.good_bytes} of {cut}")
    assert "attachment record" in info.damage and "damaged" not in info.damage


def test_a_damaged_chunk_is_skipped_and_reading_goes_on_after_it(tmp_path, recorded, log_bytes):
    with recorded.path.open("rb") as f:
        chunks = make_reader(f).get_summary().chunk_indexes
    target = chunks[len(chunks) // 2]
    data = bytearray(log_bytes)
    data[target.chunk_start_offset + target.chunk_length - 20] ^= (
        0xFF  # inside the chunk's compressed data
    )
    damaged = tmp_path / "flipped.mcap"
    damaged.write_bytes(bytes(data))
    reader = LogReader(damaged)
    readable = list(reader.messages())
    assert "damaged record" in reader.damage and not reader.complete and not reader.stopped
    assert f"after byte {target.chunk_start_offset} " in reader.damage
    assert [c.start_byte for c in reader.lost] == [target.chunk_start_offset]
    assert reader.good_bytes == len(log_bytes)  # the summary is intact: read on to the footer
    assert 0 < len(readable) < len(recorded.sent)
    assert [m.frames for m in readable][-1] == [m.frames for m in LogReader(recorded.path).messages()][-1]
    report = recover(damaged, tmp_path / "fixed.mcap")
    assert report.messages - report.undecodable == len(readable) and not report.complete
    recovered = LogReader(tmp_path / "fixed.mcap")
    assert [m.frames for m in recovered.messages()] == [m.frames for m in readable] and recovered.complete


def test_recovering_a_complete_log_copies_it_whole(tmp_path, recorded):
    report = recover(recorded.path, tmp_path / "copy.mcap")
    assert report.complete and report.closed_cleanly and report.damage is None
    assert report.messages == len(recorded.sent) and report.undecodable == 0
    assert report.salvaged_bytes == report.source_bytes == recorded.path.stat().st_size
    original = [m.frames for m in LogReader(recorded.path).messages()]
    assert [m.frames for m in LogReader(tmp_path / "copy.mcap").messages()] == original


def test_recover_refuses_to_overwrite_its_source_and_non_logs(tmp_path, recorded):
    with pytest.raises(SessionLogError, match="is the log being recovered"):
        recover(recorded.path, recorded.path)
    junk = tmp_path / "junk.mcap"
    junk.write_bytes(b"\x00" * 100)
    with pytest.raises(SessionLogError, match="not an MCAP"):
        recover(junk, tmp_path / "out.mcap")
    assert not (tmp_path / "out.mcap").exists() and not (tmp_path / "out.mcap.partial").exists()


def test_the_recover_command_fails_when_it_salvaged_nothing_and_report_says_why(tmp_path, recorded, log_bytes,
                                                                                 capsys):
    from teleop.cli import main
    from teleop.system.report import build_report

    cut = tmp_path / "cut.mcap"
    cut.write_bytes(log_bytes[:100])  # the header, before any attachment or message
    assert main(["recover", str(cut), "--out", str(tmp_path / "fixed.mcap")]) == 1
    assert "nothing salvaged: the log is cut short before its first message" in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cut.mcap"]  # no --out file, no .partial
    kept = tmp_path / "kept.mcap"
    kept.write_bytes(b"an earlier recovery")
    assert main(["recover", str(cut), "--out", str(kept), "--overwrite"]) == 1
    assert kept.read_bytes() == b"an earlier recovery"  # an empty copy replaces nothing
    recover(cut, tmp_path / "fixed.mcap")  # the function still writes what there is
    with pytest.raises(SessionLogError, match="the recorder writes it as the session starts") as caught:
        build_report(tmp_path / "fixed.mcap", tmp_path / "report")
    assert "explicitly" not in str(caught.value)  # report has no option to pass them
    assert main(["recover", str(recorded.path), "--out", str(tmp_path / "whole.mcap")]) == 0


def test_the_recover_command_checks_out_first_and_replaces_a_file_only_with_overwrite(tmp_path, recorded, capsys):
    from teleop.cli import main

    folder = tmp_path / "folder"
    folder.mkdir()
    assert main(["recover", str(recorded.path), "--out", str(folder)]) == 2
    assert f"--out {folder}: is a folder; expected a file name" in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == [folder] and not any(folder.iterdir())  # no .partial left
    other = tmp_path / "other.mcap"
    other.write_bytes(b"precious")
    assert main(["recover", str(recorded.path), "--out", str(other)]) == 2
    assert f"--out {other} exists: choose another name or pass --overwrite" in capsys.readouterr().err
    assert other.read_bytes() == b"precious"
    assert main(["recover", str(recorded.path), "--out", str(other), "--overwrite"]) == 0
    reader = LogReader(other)
    assert len(list(reader.messages())) == len(recorded.sent) and reader.complete


def test_recover_into_a_folder_leaves_no_partial_file(tmp_path, recorded):
    with pytest.raises(SessionLogError, match="cannot write the recovered log"):
        recover(recorded.path, tmp_path)
    assert not list(tmp_path.glob("*.partial"))


def test_a_log_cut_short_has_no_trailing_bytes(recorded, log_bytes, tmp_path):
    """trailing_bytes counts bytes after the footer of a complete log (another writer's), never the
    partial record a killed recorder left at the end of a cut log."""
    log = tmp_path / "cut.mcap"
    log.write_bytes(log_bytes[: len(log_bytes) // 2 + 7])
    report = recover(log, tmp_path / "fixed.mcap")
    assert report.cut_short and not report.complete
    assert report.salvaged_bytes < report.source_bytes
    assert report.trailing_bytes == 0


def test_an_out_that_is_the_source_by_another_spelling_is_refused(recorded, tmp_path):
    log = tmp_path / "s.mcap"
    shutil.copyfile(recorded.path, log)
    (tmp_path / "sub").mkdir()
    (tmp_path / "link.mcap").symlink_to(log)
    before = log.read_bytes()
    for out in (tmp_path / "sub" / ".." / "s.mcap", tmp_path / "link.mcap"):
        with pytest.raises(SessionLogError, match="is the log being recovered"):
            recover(log, out)
    assert log.read_bytes() == before


def test_lost_parts_name_their_log_by_its_full_path_when_recovered_by_a_relative_one(
    recorded, log_bytes, tmp_path, monkeypatch
):
    with recorded.path.open("rb") as f:
        first = min(make_reader(f).get_summary().chunk_indexes, key=lambda c: c.chunk_start_offset)
    data = bytearray(log_bytes)
    data[first.chunk_start_offset + first.chunk_length - 20] ^= 0xFF  # its CRC fails: the chunk is lost
    (tmp_path / "damaged.mcap").write_bytes(bytes(data))
    monkeypatch.chdir(tmp_path)
    report = recover("damaged.mcap", "fixed.mcap")
    assert report.lost and {entry["lost_in"] for entry in report.lost} == {str(tmp_path / "damaged.mcap")}
