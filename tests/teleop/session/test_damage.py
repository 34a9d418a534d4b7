"""A session log damaged in the middle: the damage is said, with where, and what is after it is read."""

from __future__ import annotations

import json
import struct
import subprocess
import sys
from pathlib import Path

import pytest
from mcap.reader import make_reader
from mcap.records import Message
from mcap.stream_reader import StreamReader, breakup_chunk
from mcap.writer import Writer

import teleop.cli
from teleop.errors import SessionLogError
from teleop.session import LogReader, export_session, recover, replay, session_grasps
from teleop.session.logdamage import LostChunk, recorded_losses
from teleop.system.report import build_report

TELEOP = Path(sys.executable).parent / "teleop"


@pytest.fixture(scope="module")
def damaged(recorded, tmp_path_factory):
    """The recorded session with a chunk inside grasp g0 (before g1 starts) zeroed in its middle."""
    events = {(m.message.fields.grasp_id, m.message.fields.event): m.log_time_ns
              for m in LogReader(recorded.path).messages(("grasp_event",))}
    with recorded.path.open("rb") as f:
        chunks = make_reader(f).get_summary().chunk_indexes
    inside = [c for c in chunks if events["g0", "start"] < c.message_start_time
              and c.message_end_time < events["g1", "start"]]
    if not inside:
        pytest.skip("the recording put no chunk strictly inside grasp g0")
    target = inside[0]
    data = bytearray(recorded.path.read_bytes())
    middle = target.chunk_start_offset + target.chunk_length // 2
    data[middle : middle + 200] = bytes(200)
    path = tmp_path_factory.mktemp("damaged") / "zeroed.mcap"
    path.write_bytes(bytes(data))
    return path, target


def test_info_says_a_damaged_middle_chunk_is_damaged_and_where(damaged):
    path, target = damaged
    info = LogReader(path).info()
    assert not info.complete and info.damage
    assert f"after byte {target.chunk_start_offset} " in info.damage
    assert f"skipped bytes {target.chunk_start_offset} to" in info.damage


def _held(path: Path, index) -> tuple[set[tuple[int, int]], set[tuple[int, int]]]:
    """The (log time, sequence) of the bus messages and of the Foxglove forms the chunk at ``index`` holds."""
    with path.open("rb") as f:
        topics = {c.id: c.topic for c in make_reader(f).get_summary().channels.values()}
        f.seek(index.chunk_start_offset)
        chunk = next(StreamReader(f, skip_magic=True, emit_chunks=True).records)
    held = [(topics[r.channel_id], (r.log_time, r.sequence)) for r in breakup_chunk(chunk) if isinstance(r, Message)]
    return {key for topic, key in held if not topic.startswith("/")}, {key for topic, key in held if topic.startswith("/")}


def test_reading_goes_on_after_a_damaged_chunk_when_the_summary_is_intact(recorded, damaged):
    path, target = damaged
    whole = [(m.message.topic, (m.log_time_ns, m.message.seq)) for m in LogReader(recorded.path).messages()]
    reader = LogReader(path)
    read = [(m.log_time_ns, m.message.seq) for m in reader.messages()]
    assert not reader.complete and reader.damage
    assert [(c.start_byte, c.start_ns, c.end_ns) for c in reader.lost] == [
        (target.chunk_start_offset, target.message_start_time, target.message_end_time)]
    bus, forms = _held(recorded.path, target)
    # the chunk's messages, and the frames whose image (stored just before them) it holds
    lost = [key for topic, key in whole if key in bus or (topic.startswith("frame/") and key in forms)]
    assert lost and read == sorted(read)  # still in log-time order
    assert set(read) == {key for _, key in whole} - set(lost)  # every message outside the damaged chunk is there
    assert max(read) == max(key for _, key in whole)


def test_export_keeps_the_grasps_after_the_damage_and_says_why_the_damaged_one_is_skipped(
    damaged, recorded, tmp_path
):
    path, target = damaged
    results = export_session(path, tmp_path / "out")
    by_id = {g.grasp_id: g for g in results}
    assert not results.complete and f"byte {target.chunk_start_offset}" in results.damage
    assert not by_id["g0"] and "damaged" in by_id["g0"].reason
    assert f"bytes {target.chunk_start_offset} to" in by_id["g0"].reason
    assert by_id["g1"] and by_id["g1"].path.exists()
    whole = {g.grasp_id: g for g in session_grasps(recorded.path)}
    got, want = by_id["g1"].record, whole["g1"].record
    assert got.force_n.t_s.tolist() == want.force_n.t_s.tolist() and got.events == want.events
    assert [len(s.t_s) for s in got.frames] == [len(s.t_s) for s in want.frames]
    assert not by_id["g2"] and by_id["g2"].reason == whole["g2"].reason  # never ended, as in the whole log


def test_the_export_command_says_the_log_is_damaged_and_incomplete(damaged, tmp_path):
    path, target = damaged
    result = subprocess.run([str(TELEOP), "export", str(path), "--out", str(tmp_path / "out"), "--json"],
                            capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    summary = json.loads(result.stdout.strip().splitlines()[-1])
    assert summary["complete"] is False
    assert f"byte {target.chunk_start_offset}" in result.stderr and "teleop recover" in result.stderr


def test_the_report_says_the_log_is_damaged_where_and_what_to_do(damaged, tmp_path):
    path, target = damaged
    page = build_report(path, tmp_path / "report").index.read_text(encoding="utf-8")
    assert "the log is damaged" in page and f"byte {target.chunk_start_offset}" in page
    assert "teleop recover" in page


def test_two_damaged_chunks_in_a_row_are_both_skipped_and_reading_ends(recorded, tmp_path):
    # Damage across a chunk boundary: the chunk where reading goes on is damaged too.
    with recorded.path.open("rb") as f:
        chunks = sorted(make_reader(f).get_summary().chunk_indexes, key=lambda c: c.chunk_start_offset)
    first, second = chunks[2], chunks[3]
    data = bytearray(recorded.path.read_bytes())
    for chunk in (first, second):
        middle = chunk.chunk_start_offset + chunk.chunk_length // 2
        data[middle : middle + 200] = bytes(200)
    path = tmp_path / "two.mcap"
    path.write_bytes(bytes(data))
    reader = LogReader(path)
    read = list(reader.messages())
    assert [c.start_byte for c in reader.lost] == [first.chunk_start_offset, second.chunk_start_offset]
    assert read and not reader.complete


class _Sink:
    """Stands in for a Publisher: takes every message, sends nothing."""

    max_bytes = 8 * 1024 * 1024
    heartbeat_s = 1.0

    def publish(self, message):
        return message

    def heartbeat_if_due(self, now_s=None):
        return False


@pytest.fixture(scope="module")
def recovered(damaged, tmp_path_factory):
    """The damaged log recovered (a complete file that lacks the damaged chunk's messages), and the report."""
    path, _ = damaged
    out = tmp_path_factory.mktemp("recovered") / "fixed.mcap"
    return out, recover(path, out)


def test_a_recovered_log_reads_the_parts_its_source_lost_as_lost(damaged, recovered):
    path, target = damaged
    recovered, report = recovered
    assert [(c["start_byte"], c["lost_in"]) for c in report.lost] == [
        (target.chunk_start_offset, str(path.resolve()))]  # in its recovery metadata
    reader = LogReader(recovered)
    records = reader.records()
    next(records)  # the header: the recovery metadata, at the end, is taken before it
    records.close()
    assert [(c.start_ns, c.end_ns, c.lost_in) for c in reader.lost] == [
        (target.message_start_time, target.message_end_time, str(path.resolve()))]
    info = reader.info()
    assert info.complete  # the file itself is whole (it can be labelled) ...
    assert "lost before recovery" in info.damage and f"bytes {target.chunk_start_offset} to" in info.damage


def test_export_of_a_recovered_log_skips_the_grasp_its_source_lost_part_of(damaged, recovered, tmp_path, capsys):
    path, target = damaged
    results = export_session(recovered[0], tmp_path / "out")
    by_id = {g.grasp_id: g for g in results}
    assert not results.complete and "lost before recovery" in results.damage
    assert not by_id["g0"] and by_id["g0"].reason.startswith("part of its data is lost")
    assert "lost before recovery" in by_id["g0"].reason and str(path.resolve()) in by_id["g0"].reason
    assert by_id["g1"] and by_id["g1"].path.exists()
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == [by_id["g1"].path.name]
    assert not results.mendable  # nothing left for `teleop recover` to mend ...
    assert teleop.cli.main(["export", str(recovered[0]), "--out", str(tmp_path / "again")]) == 0
    note = capsys.readouterr().err
    assert "lost before recovery" in note and "FIXED.mcap" not in note  # ... so it is not advised


def test_replay_and_report_of_a_recovered_log_say_what_its_source_lost(damaged, recovered, tmp_path):
    path, target = damaged
    recovered, _ = recovered
    stats = replay(recovered, _Sink(), speed=None)
    assert stats.damage and "lost before recovery" in stats.damage and not stats.stopped
    page = build_report(recovered, tmp_path / "report").index.read_text(encoding="utf-8")
    assert "lost before recovery" in page and f"bytes {target.chunk_start_offset} to" in page
    assert "FIXED.mcap" not in page  # the file is whole: recovering it again mends nothing


def test_a_log_recovered_twice_keeps_the_first_losses_once(damaged, recovered, tmp_path):
    path, target = damaged
    twice = tmp_path / "twice.mcap"
    report = recover(recovered[0], twice)
    assert report.complete and "lost before recovery" in report.damage  # whole file, earlier losses
    assert [c["lost_in"] for c in report.lost] == [str(path.resolve())]
    reader = LogReader(twice)
    reader.info()  # two recovery metadata records list the same part
    assert [(c.start_byte, c.lost_in) for c in reader.lost] == [(target.chunk_start_offset, str(path.resolve()))]
    by_id = {g.grasp_id: g for g in export_session(twice, tmp_path / "out")}
    assert not by_id["g0"] and "lost before recovery" in by_id["g0"].reason and by_id["g1"]


def test_a_grasp_touching_a_lost_part_at_either_end_overlaps_it():
    lost = LostChunk(0, 10, start_ns=100, end_ns=200)
    assert lost.overlaps(50, 100) and lost.overlaps(200, 300) and lost.overlaps(120, 180)
    assert not lost.overlaps(50, 99) and not lost.overlaps(201, 300)


def test_a_lost_entry_with_a_field_of_the_wrong_type_is_refused_naming_the_log(tmp_path):
    good = {"start_byte": 1, "end_byte": 2, "start_ns": 3, "end_ns": 4, "kind": "chunk", "lost_in": "x.mcap"}
    log = tmp_path / "r.mcap"
    assert recorded_losses({"lost": json.dumps([good])}, log) == [LostChunk(1, 2, 3, 4, "chunk", "x.mcap")]
    for key, bad in (("start_byte", "1"), ("end_ns", 4.0), ("kind", 7)):
        with pytest.raises(SessionLogError, match="r.mcap"):
            recorded_losses({"lost": json.dumps([{**good, key: bad}])}, log)


def test_a_damaged_record_in_a_log_without_chunks_leaves_it_mendable(tmp_path):
    """A log written without chunks has a summary but no chunk index: the summary cannot say what a damaged
    record took, so the reader reads on front to back, and what it could not read makes the log mendable
    (``teleop label`` refuses it rather than rewriting it without the messages)."""
    path = tmp_path / "plain.mcap"
    with path.open("wb") as f:
        writer = Writer(f, use_chunking=False)
        writer.start("compliance-teleop.session", "test")
        channel = writer.register_channel("/note", "json", 0, {})
        for n in range(5):
            writer.add_message(channel, log_time=n + 1, data=b'{"n": %d}' % n, publish_time=n + 1, sequence=n)
        writer.add_metadata("session_end", {"messages": "5"})
        writer.finish()
    data = bytearray(path.read_bytes())
    start = data.index(b'{"n": 2}') - (1 + 8 + 2 + 4 + 8 + 8)  # opcode, length, channel, sequence, times
    assert data[start] == 0x05  # a message record
    data[start + 1 : start + 9] = struct.pack("<Q", 2**40)
    path.write_bytes(bytes(data))
    info = LogReader(path).info()
    assert info.mendable and not info.complete and info.damage
