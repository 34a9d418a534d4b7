"""Damage in a log without a summary (a killed recorder's) is skipped, said as damage (not a cut),
and what follows it is salvaged; logs of a newer format are refused."""

from __future__ import annotations

import io
import struct

import pytest
from mcap.reader import make_reader

from teleop.cli import main
from teleop.errors import SessionLogError
from teleop.session import LogReader
from teleop.session.recover import recover


@pytest.fixture(scope="module")
def whole(recorded) -> bytes:
    return recorded.path.read_bytes()


@pytest.fixture(scope="module")
def summary(whole):
    with io.BytesIO(whole) as f:
        return make_reader(f).get_summary()


def _frames(path):
    return [m.frames for m in LogReader(path).messages()]


def test_a_damaged_attachment_in_a_cut_short_log_is_skipped_and_every_message_salvaged(
    tmp_path, whole, summary, capsys
):
    attachment = min(summary.attachment_indexes, key=lambda a: a.offset)
    cut = len(whole) * 3 // 4  # no summary, no footer: a killed recorder's log
    plain = tmp_path / "cut.mcap"
    plain.write_bytes(whole[:cut])
    data = bytearray(whole[:cut])
    at = attachment.offset + 9 + 16 + 4 + 1  # inside the attachment's name
    data[at : at + 4] = bytes(b ^ 0xA5 for b in data[at : at + 4])
    damaged = tmp_path / "damaged.mcap"
    damaged.write_bytes(bytes(data))
    reader = LogReader(damaged)
    read = [m.frames for m in reader.messages()]
    assert read and read == _frames(plain)  # nothing after the damage is lost
    assert reader.damaged and reader.cut and reader.stopped
    assert [(c.start_byte, c.end_byte, c.holds_messages) for c in reader.lost] == [
        (attachment.offset, attachment.offset + attachment.length, False)]  # lost, holding no message
    assert reader.damage.startswith(f"damaged record after byte {attachment.offset} ")
    assert f"skipped it (bytes {attachment.offset} to {attachment.offset + attachment.length}: attachment" in (
        reader.damage
    )
    report = recover(damaged, tmp_path / "fixed.mcap")
    assert report.messages == len(read) and report.damaged and report.cut_short
    assert attachment.name not in report.attachments and [c["start_byte"] for c in report.lost] == [attachment.offset]
    assert main(["recover", str(damaged), "--out", str(tmp_path / "fixed2.mcap")]) == 0
    err = capsys.readouterr().err
    assert f"{damaged}: damaged and cut short (damaged record after byte {attachment.offset}" in err
    assert "nothing salvaged" not in err and f"salvaged {len(read)} messages" in err


def test_a_chunk_with_a_damaged_length_in_a_cut_short_log_is_skipped_to_the_next_chunk(tmp_path, whole, summary):
    chunks = sorted(summary.chunk_indexes, key=lambda c: c.chunk_start_offset)
    target, after = chunks[len(chunks) // 2], chunks[len(chunks) // 2 + 1]
    cut = chunks[-2].chunk_start_offset + 10  # no summary; the file ends inside a chunk
    data = bytearray(whole[:cut])
    data[target.chunk_start_offset + 1 : target.chunk_start_offset + 9] = (2**62).to_bytes(8, "little")
    damaged = tmp_path / "damaged.mcap"
    damaged.write_bytes(bytes(data))
    reader = LogReader(damaged)
    read = [m.log_time_ns for m in reader.messages()]
    assert reader.damage.startswith(f"damaged record after byte {target.chunk_start_offset} ")
    assert "though an intact chunk follows" in reader.damage and "the file ends inside the record" in (
        reader.damage)  # ... the last, incomplete chunk: that one is a cut
    assert f"skipped bytes {target.chunk_start_offset} to {after.chunk_start_offset} (unreadable" in reader.damage
    assert reader.damaged and reader.cut and [(c.start_byte, c.end_byte) for c in reader.lost] == [
        (target.chunk_start_offset, after.chunk_start_offset)]
    lost = reader.lost[0]
    assert lost.start_ns <= target.message_start_time and lost.end_ns >= after.message_start_time
    assert any(t > target.message_end_time for t in read)  # read on after the damage
    assert not any(target.message_start_time < t < target.message_end_time for t in read)


def test_a_damaged_attachment_length_in_a_complete_log_is_damage_and_names_the_attachment(
    tmp_path, whole, summary
):
    attachment = min(summary.attachment_indexes, key=lambda a: a.offset)
    data = bytearray(whole)
    start = attachment.offset + 1
    data[start : start + 4] = bytes(b ^ 0xA5 for b in data[start : start + 4])
    damaged = tmp_path / "damaged.mcap"
    damaged.write_bytes(bytes(data))
    reader = LogReader(damaged)
    info = reader.info()
    assert "the file ends" not in info.damage and not reader.cut and not reader.stopped
    assert info.damage.startswith(f"damaged record after byte {attachment.offset} of {len(whole)}")
    assert f"lost: attachment {attachment.name!r}" in info.damage


def _with_format(tmp_path, whole, version: bytes):
    key = b"log_format\x01\x00\x00\x00"
    assert whole.count(key) == 1
    at = whole.index(key) + len(key)
    path = tmp_path / f"v{version.decode()}.mcap"
    path.write_bytes(whole[:at] + version + whole[at + 1 :])
    return path


def test_a_log_of_a_newer_or_unknown_format_is_refused_and_known_ones_read(tmp_path, whole, recorded):
    for version in (b"9", b"x", b"0"):
        path = _with_format(tmp_path, whole, version)
        with pytest.raises(SessionLogError, match=rf"log_format = '{version.decode()}': expected an integer from 1 to 2"):
            LogReader(path).info()
        with pytest.raises(SessionLogError, match="log_format"):
            list(LogReader(path).messages())
        with pytest.raises(SessionLogError, match="log_format"):
            recover(path, tmp_path / "fixed.mcap")
        assert not (tmp_path / "fixed.mcap").exists()
    for version in (b"1", b"2"):
        assert len(list(LogReader(_with_format(tmp_path, whole, version)).messages())) == len(recorded.sent)


_QUICK = ["--endpoint", "tcp://127.0.0.1:*", "--as-fast-as-possible"]


@pytest.mark.parametrize(("option", "value"), [
    ("--wait-subscriber-s", "inf"), ("--wait-subscriber-s", "1e300"), ("--linger-s", "inf"),
    ("--linger-s", "nan"), ("--speed", "1e-300")])
def test_replay_refuses_unbounded_waits_and_speeds(recorded, capsys, option, value):
    args = ["replay", str(recorded.path), "--endpoint", "tcp://127.0.0.1:*", option, value]
    assert main(args) == 2
    err = capsys.readouterr().err
    assert f"error: {option} " in err and "expected a number" in err and "Traceback" not in err


def test_replay_of_a_log_with_no_readable_message_says_so_not_that_a_filter_matched_nothing(
    tmp_path, whole, capsys
):
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(whole[:200])
    assert main(["replay", str(cut), *_QUICK, "--wait-subscriber-s", "0", "--linger-s", "0"]) == 1
    err = capsys.readouterr().err
    assert "nothing replayed: the log holds no readable message (the file ends inside the record" in err
    assert "--recorded-from" not in err and "the log stops early: the file ends" in err


def test_replay_past_a_damaged_chunk_says_it_read_on(tmp_path, whole, summary, capsys):
    target = sorted(summary.chunk_indexes, key=lambda c: c.chunk_start_offset)[3]
    data = bytearray(whole)
    data[target.chunk_start_offset + target.chunk_length - 20] ^= 0xFF
    damaged = tmp_path / "damaged.mcap"
    damaged.write_bytes(bytes(data))
    assert main(["replay", str(damaged), *_QUICK, "--wait-subscriber-s", "0", "--linger-s", "0"]) == 0
    err = capsys.readouterr().err
    assert "the log is damaged; replay read on past it: damaged record" in err and "stopped early" not in err


def _chunks(summary):
    return sorted(summary.chunk_indexes, key=lambda c: c.chunk_start_offset)


def _without_summary(whole, summary) -> bytearray:
    """``whole`` up to the end of its last chunk: what a killed recorder leaves (no summary, no footer)."""
    last = _chunks(summary)[-1]
    return bytearray(whole[: last.chunk_start_offset + last.chunk_length])


def test_a_chunk_skipped_in_a_log_without_summary_holds_the_times_between_its_neighbours(tmp_path, whole, summary):
    """The part lost spans the log times from the last message read before it to the first read after
    it, not from the start of time."""
    chunks = _chunks(summary)
    k = len(chunks) // 2
    bad, before, after = chunks[k], chunks[k - 1], chunks[k + 1]
    data = _without_summary(whole, summary)
    data[bad.chunk_start_offset + bad.chunk_length - 20] ^= 0xFF
    path = tmp_path / "killed.mcap"
    path.write_bytes(bytes(data))
    reader = LogReader(path)
    list(reader.messages())
    (lost,) = reader.lost
    assert (lost.start_byte, lost.end_byte) == (bad.chunk_start_offset, bad.chunk_start_offset + bad.chunk_length)
    assert (lost.start_ns, lost.end_ns) == (before.message_end_time, after.message_start_time)
    assert not lost.overlaps(0, before.message_end_time - 1)


def test_an_unreadable_part_in_a_log_without_summary_holds_the_times_between_its_neighbours(
    tmp_path, whole, summary
):
    """As a skipped chunk, but the chunk's length field is garbage: reading goes on at the next intact chunk."""
    chunks = _chunks(summary)
    k = len(chunks) // 2
    bad, before, after = chunks[k], chunks[k - 1], chunks[k + 1]
    data = _without_summary(whole, summary)
    data[bad.chunk_start_offset + 1 : bad.chunk_start_offset + 9] = struct.pack("<Q", 2**40)
    path = tmp_path / "garbled.mcap"
    path.write_bytes(bytes(data))
    reader = LogReader(path)
    list(reader.messages())
    (lost,) = reader.lost
    assert lost.kind == "unreadable part"
    assert (lost.start_byte, lost.end_byte) == (bad.chunk_start_offset, after.chunk_start_offset)
    assert (lost.start_ns, lost.end_ns) == (before.message_end_time, after.message_start_time)


def test_the_scan_for_the_next_chunk_passes_over_one_whose_times_run_backwards(tmp_path, whole, summary):
    """A "chunk" whose first message time is after its last is not one: reading goes on at the real next chunk."""
    chunks = _chunks(summary)
    k = len(chunks) // 2
    bad, after = chunks[k], chunks[k + 1]
    assert bad.chunk_length > 200
    data = _without_summary(whole, summary)
    data[bad.chunk_start_offset + 1 : bad.chunk_start_offset + 9] = struct.pack("<Q", 2**40)
    fake = struct.pack("<BQQQQII", 0x06, 40, 10, 5, 0, 0, 0) + struct.pack("<Q", 0)  # a chunk head, times 10 > 5
    at = bad.chunk_start_offset + 100
    data[at : at + len(fake)] = fake
    path = tmp_path / "garbled.mcap"
    path.write_bytes(bytes(data))
    reader = LogReader(path)
    list(reader.messages())
    assert [(c.start_byte, c.end_byte) for c in reader.lost] == [(bad.chunk_start_offset, after.chunk_start_offset)]


def test_a_damaged_last_chunk_that_ends_the_file_is_called_damaged_not_cut(tmp_path, whole, summary):
    chunk = _chunks(summary)[len(summary.chunk_indexes) // 2]
    end = chunk.chunk_start_offset + chunk.chunk_length
    data = bytearray(whole[:end])
    data[end - 20] ^= 0xFF
    path = tmp_path / "cut.mcap"
    path.write_bytes(bytes(data))
    damage = LogReader(path).info().damage
    assert (f"damaged record after byte {chunk.chunk_start_offset} of {end} (a chunk record of "
            f"{chunk.chunk_length - 9} bytes:") in damage


def test_a_garbled_attachment_length_is_said_with_the_attachment_and_the_length(tmp_path, whole, summary):
    attachment = next(a for a in summary.attachment_indexes if a.name.startswith("calibration/"))
    data = bytearray(whole)
    data[attachment.offset + 1 : attachment.offset + 9] = struct.pack("<Q", 2**40)
    path = tmp_path / "s.mcap"
    path.write_bytes(bytes(data))
    damage = LogReader(path).info().damage
    assert f"(an attachment record {attachment.name!r} whose length of {2**40} bytes" in damage
    assert f"lost: attachment {attachment.name!r}" in damage
