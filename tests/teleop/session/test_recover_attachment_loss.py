"""An attachment or metadata record lost to damage stays said lost in a recovered copy (its ``recovery``
metadata lists it), without making any grasp or message lost: such a record holds none."""

from __future__ import annotations

import dataclasses
import io
import shutil
import struct

import pytest
from mcap.reader import make_reader
from mcap.writer import Writer
from support.session_logs import register_bus_channel

from teleop.bus.wire import encode, make_message
from teleop.session import LogReader
from teleop.session.export import export_session
from teleop.session.label import label_session
from teleop.session.logdamage import LostChunk
from teleop.session.logframes import pack_frames
from teleop.session.logscan import UNKNOWN_NS
from teleop.session.recover import recover

T0 = 1_700_000_000_000_000_000  # a log time (ns): 2023-11-14
NAMES = {"attachment": "notes.txt", "metadata": "rig"}
RECORDS = [("attachment", "an attachment record"), ("metadata", "a metadata record")]


def _event(event: str, grasp_id: str, seq: int):
    message = make_message("grasp_event", t_capture_s=1.0, event=event, grasp_id=grasp_id, object_name=None)
    return dataclasses.replace(message, source="robot", seq=seq)


def _log(path):
    """A complete log of grasp g0, then an attachment and a metadata record (NAMES), then grasp g1."""
    with path.open("wb") as f:
        writer = Writer(f)
        writer.start("compliance-teleop.session", "test")
        channel = register_bus_channel(writer, "grasp_event", "grasp_event")

        def add(log_time, message):
            writer.add_message(channel, log_time=log_time, data=pack_frames(encode(message)),
                               publish_time=log_time, sequence=message.seq)

        add(T0, _event("start", "g0", 0))
        add(T0 + 10, _event("end", "g0", 1))
        writer.add_attachment(T0 + 15, T0 + 15, NAMES["attachment"], "text/plain", b"the rig was re-taped")
        writer.add_metadata(NAMES["metadata"], {"gel_modulus_pa": "150000"})
        add(T0 + 20, _event("start", "g1", 2))
        add(T0 + 30, _event("end", "g1", 3))
        writer.finish()
    return path


def _index(path, kind, name):
    with path.open("rb") as f:
        summary = make_reader(f).get_summary()
    indexes = summary.attachment_indexes if kind == "attachment" else summary.metadata_indexes
    return next(index for index in indexes if index.name == name), summary


def _garble(path, kind, name, *, summary: bool = True):
    """Make the ``kind`` record ``name`` of ``path`` unreadable, its length and name intact (the length
    field after its name runs past the record); without ``summary``, cut the file after its last chunk
    (a killed recorder's log). Returns the record's first and last byte."""
    index, indexes = _index(path, kind, name)
    data = bytearray(path.read_bytes())
    after_name = index.offset + 9 + (16 if kind == "attachment" else 0) + 4 + len(name.encode())
    data[after_name : after_name + 4] = struct.pack("<I", 0xFFFFFFFF)
    if not summary:
        data = data[: max(c.chunk_start_offset + c.chunk_length for c in indexes.chunk_indexes)]
    path.write_bytes(bytes(data))
    return index.offset, index.offset + index.length


@pytest.mark.parametrize("summary", [True, False], ids=["complete", "cut-short"])
@pytest.mark.parametrize("kind, record", RECORDS)
def test_a_recovered_copy_of_a_log_that_lost_a_record_says_so_and_loses_no_grasp(tmp_path, kind, record,
                                                                                 summary):
    source = _log(tmp_path / "s.mcap")
    start, end = _garble(source, kind, NAMES[kind], summary=summary)
    assert f"{record} {NAMES[kind]!r}" in LogReader(source).info().damage
    report = recover(source, tmp_path / "fixed.mcap")
    assert [(c["kind"], c["start_byte"], c["end_byte"]) for c in report.lost] == [
        (f"{record.split(' ', 1)[1]} {NAMES[kind]!r}", start, end)]
    # Its log times are an empty span (first after last): readers that go by the times alone find no
    # message in it either.
    assert [(c["start_ns"], c["end_ns"]) for c in report.lost] == [(UNKNOWN_NS, 0)]
    reader = LogReader(tmp_path / "fixed.mcap")
    info = reader.info()
    assert info.complete and not info.mendable  # the copy is a whole file, recovering it mends nothing ...
    said = (f"lost before recovery: the {record.split(' ', 1)[1]} {NAMES[kind]!r} at bytes {start} to {end} "
            f"of {source.resolve()} is damaged")
    assert info.damage.startswith(said) and "no messages were lost" in info.damage  # ... but not whole
    times = [m.log_time_ns for m in reader.messages()]
    assert times == [T0, T0 + 10, T0 + 20, T0 + 30]  # every message kept ...
    assert not any(c.overlaps(first, last) for c in reader.lost for first in times for last in times)


@pytest.mark.parametrize("kind, record", RECORDS)
def test_a_second_recovery_keeps_the_lost_record_once(tmp_path, kind, record):
    source = _log(tmp_path / "s.mcap")
    _garble(source, kind, NAMES[kind])
    recover(source, tmp_path / "once.mcap")
    report = recover(tmp_path / "once.mcap", tmp_path / "twice.mcap")
    assert [(c["kind"], c["lost_in"]) for c in report.lost] == [
        (f"{record.split(' ', 1)[1]} {NAMES[kind]!r}", str(source.resolve()))]
    reader = LogReader(tmp_path / "twice.mcap")
    info = reader.info()  # two recovery metadata records list the same record
    assert len(reader.lost) == 1 and info.damage.count("lost before recovery") == 1
    assert f"{NAMES[kind]!r}" in info.damage and str(source.resolve()) in info.damage


@pytest.mark.parametrize("kind, record", RECORDS)
def test_a_recovered_copy_that_lost_a_record_is_labelled_keeping_the_loss(tmp_path, kind, record):
    source = _log(tmp_path / "s.mcap")
    _garble(source, kind, NAMES[kind])
    fixed = tmp_path / "fixed.mcap"
    recover(source, fixed)
    damage = LogReader(fixed).info().damage
    assert f"{NAMES[kind]!r}" in damage
    csv_path = tmp_path / "labels.csv"
    csv_path.write_text("grasp_id,object,modulus_pa\ng0,foam,50000\ng1,foam,50000\n", encoding="utf-8")
    report = label_session(fixed, csv_path)
    assert report.grasps == 2
    assert [m.message.body["grasp_id"] for m in LogReader(fixed).messages(topics=("label",))] == ["g0", "g1"]
    assert LogReader(fixed).info().damage == damage  # the labelled copy still says what was lost


def test_export_of_a_recovered_session_that_lost_a_record_keeps_every_grasp(recorded, tmp_path):
    """The recorded session's rig metadata and scene attachment lost: its grasps are whole all the same."""
    source = tmp_path / "session.mcap"
    shutil.copyfile(recorded.path, source)
    data = bytearray(source.read_bytes())
    for kind, name in (("metadata", "rig"), ("attachment", "scene.toml")):
        index, _ = _index(source, kind, name)
        data[index.offset + 1 : index.offset + 9] = struct.pack("<Q", 2**40)  # its length past the end
        source.write_bytes(bytes(data))
    whole = {g.grasp_id for g in export_session(recorded.path, tmp_path / "whole") if g}
    fixed = tmp_path / "fixed.mcap"
    recover(source, fixed)
    results = export_session(fixed, tmp_path / "out")
    assert "'rig'" in results.damage and "'scene.toml'" in results.damage and not results.mendable
    assert whole and {g.grasp_id for g in results if g} == whole
    with io.BytesIO(fixed.read_bytes()) as f:
        assert [i.name for i in make_reader(f).get_summary().attachment_indexes if i.name == "scene.toml"] == []


def test_a_lost_record_overlaps_no_log_times_and_says_no_message_was_lost():
    lost = LostChunk.record(100, 200, "attachment", " 'notes.txt'")
    assert not lost.holds_messages and not lost.overlaps(0, 2**64)  # not even a grasp open from the start
    assert str(lost) == ("the attachment record 'notes.txt' at bytes 100 to 200 is damaged "
                         "(no messages were lost: it holds none)")
    assert LostChunk(100, 200, 0, 0).overlaps(0, 2**64)  # a chunk does
