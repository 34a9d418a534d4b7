"""Recovery of messages whose channel record a damaged chunk took: bus messages (which carry their
topic and type) and their Foxglove forms go on rebuilt channels; what tells nothing is dropped and
said so."""

from __future__ import annotations

import io
import json
from collections import Counter
from dataclasses import replace

import pytest
from mcap.reader import make_reader
from mcap.records import Channel, Chunk, Message, Schema
from mcap.stream_reader import StreamReader, breakup_chunk
from mcap.writer import Writer
from support.session_logs import register_bus_channel

from teleop.bus.wire import encode, make_message
from teleop.cli import main
from teleop.session import LogReader
from teleop.session.foxglove import foxglove_messages
from teleop.session.logdamage import RECOVERY_METADATA
from teleop.session.logfile import MESSAGE_ENCODING, PROFILE, SCHEMA_ENCODING, schema_data
from teleop.session.logframes import pack_frames
from teleop.session.recover import recover


@pytest.fixture(scope="module")
def whole(recorded) -> bytes:
    return recorded.path.read_bytes()


def _first_chunk(whole: bytes):
    """The first chunk's index, and the records in it (the channels of the first topics among them)."""
    with io.BytesIO(whole) as f:
        index = min(make_reader(f).get_summary().chunk_indexes, key=lambda c: c.chunk_start_offset)
    with io.BytesIO(whole[index.chunk_start_offset :]) as f:
        chunk = next(StreamReader(f, skip_magic=True, emit_chunks=True).records)
    assert isinstance(chunk, Chunk)
    return index, breakup_chunk(chunk)


def _by_topic(path) -> Counter[str]:
    with open(path, "rb") as f:
        return Counter(channel.topic for _, channel, _ in make_reader(f).iter_messages(log_time_order=False))


def test_messages_whose_channel_record_was_lost_are_recovered_on_rebuilt_channels(tmp_path, recorded, whole, capsys):
    """A killed recorder's log (no summary to repeat the channels) whose first chunk is damaged."""
    index, lost_records = _first_chunk(whole)
    lost_messages = [r for r in lost_records if isinstance(r, Message)]
    topic_of = {r.id: r.topic for r in lost_records if isinstance(r, Channel)}
    lost_topics = set(topic_of.values())
    plain = tmp_path / "cut.mcap"  # no summary, no footer
    plain.write_bytes(whole[: len(whole) * 3 // 4])
    data = bytearray(plain.read_bytes())
    data[index.chunk_start_offset + index.chunk_length - 20] ^= 0xFF  # inside the compressed records
    damaged = tmp_path / "damaged.mcap"
    damaged.write_bytes(bytes(data))
    recover(plain, tmp_path / "plain_fixed.mcap")
    lost_keys = {(r.log_time, r.publish_time) for r in lost_messages}  # an elided frame's too
    expected = [m for m in LogReader(plain).messages() if (m.log_time_ns, m.publish_time_ns) not in lost_keys]
    fixed = tmp_path / "fixed.mcap"
    assert main(["recover", str(damaged), "--out", str(fixed), "--json"]) == 0
    out, err = capsys.readouterr()
    report = json.loads(out.splitlines()[-1])
    assert [loss["start_byte"] for loss in report["lost"]] == [index.chunk_start_offset]
    recovered = list(LogReader(fixed).messages())
    assert [m.frames for m in recovered] == [m.frames for m in expected]
    end_ns = max(r.log_time for r in lost_messages)
    late = {m.message.topic for m in recovered if m.message.topic in lost_topics and m.log_time_ns > end_ns}
    later = {m.message.topic for m in expected if m.log_time_ns > end_ns}
    assert {"force", "grasp_event", "command"} <= late == later & lost_topics  # the old recovery had none of them
    # the Foxglove forms too: all the source's but the lost chunk's, their channels rebuilt
    counts = _by_topic(fixed)
    lost_counts = Counter(topic_of[r.channel_id] for r in lost_messages)
    assert counts == _by_topic(tmp_path / "plain_fixed.mcap") - lost_counts
    assert {"/tactile/left", "/force", "/events"} <= set(report["rebuilt_channels"])
    with io.BytesIO(whole) as f:  # a channel whose schema record the chunk held is rebuilt too, unless its
        orphaned = {c.topic for c in make_reader(f).get_summary().channels.values()  # first message is
                    if c.schema_id in {r.id for r in lost_records if isinstance(r, Schema)}}  # kept verbatim
    rebuilt = set(report["rebuilt_channels"])
    assert {t for t in lost_topics if counts[t]} <= rebuilt <= {t for t in lost_topics | orphaned if counts[t]}
    # an elided frame whose image was in the lost chunk is kept verbatim, and said so
    assert report["dropped"] == 0 and report["messages"] - report["undecodable"] == len(recovered)
    assert ("kept verbatim" in err) == bool(report["undecodable"]) and "dropped" not in err
    assert "channels rebuilt from their messages (their records were lost with the damage): " in err
    recovery = LogReader(fixed).info().metadata[RECOVERY_METADATA]
    assert json.loads(recovery["dropped"]) == 0
    assert json.loads(recovery["rebuilt_channels"]) == report["rebuilt_channels"]


def test_a_message_on_a_lost_channel_that_tells_nothing_is_dropped_and_said_so(tmp_path, capsys):
    """Not a bus message, nor the Foxglove form of the one after it: it cannot be written validly."""
    heartbeat = replace(make_message("heartbeat", t_capture_s=1.0, interval_s=1.0), source="robot", seq=1)
    log = tmp_path / "orphan.mcap"
    with log.open("wb") as f:
        writer = Writer(f)
        writer.start(PROFILE, "test")
        channel = register_bus_channel(writer, "heartbeat", "heartbeat")
        writer.add_message(channel + 7, log_time=1, data=b'{"a": 1}', publish_time=1)  # its channel: none
        writer.add_message(channel, log_time=2, data=pack_frames(encode(heartbeat)), publish_time=2)
        writer.finish()
    report = recover(log, tmp_path / "fixed.mcap")
    assert (report.messages, report.dropped, report.undecodable, report.rebuilt_channels) == (1, 1, 0, [])
    assert main(["recover", str(log), "--out", str(tmp_path / "fixed2.mcap")]) == 0
    err = capsys.readouterr().err
    assert "1 messages dropped" in err and "kept verbatim" not in err
    assert [m.message.topic for m in LogReader(tmp_path / "fixed2.mcap").messages()] == ["heartbeat"]


T0 = 1_700_000_000_000_000_000  # a log time (ns): 2023-11-14


def _log_with_held(path, order):
    """A log whose grasp_event is preceded by messages on channels that have no record: its Foxglove
    form ("form", same publish time and sequence) and an unrelated one ("junk"), in ``order``."""
    event = replace(make_message("grasp_event", t_capture_s=1.0, event="start", grasp_id="g0", object_name=None),
                    source="robot", seq=3)
    (form,) = foxglove_messages(event)
    with path.open("wb") as f:
        writer = Writer(f)
        writer.start(PROFILE, "test")
        schema = writer.register_schema("compliance-teleop/grasp_event", SCHEMA_ENCODING, schema_data("grasp_event"))
        channel = writer.register_channel("grasp_event", MESSAGE_ENCODING, schema, {"type": "grasp_event"})
        for what in order:
            if what == "form":
                writer.add_message(channel + 20, log_time=T0, data=form.data, publish_time=T0, sequence=3)
            else:
                writer.add_message(channel + 30, log_time=T0 - 5, data=b"junk", publish_time=T0 - 5, sequence=9)
        writer.add_message(channel, log_time=T0, data=pack_frames(encode(event)), publish_time=T0, sequence=3)
        writer.finish()
    return path


def test_an_unrelated_message_before_a_form_is_dropped_while_the_form_is_kept(tmp_path):
    report = recover(_log_with_held(tmp_path / "a.mcap", ["junk", "form"]), tmp_path / "fixed.mcap")
    assert report.dropped == 1
    assert report.rebuilt_channels == ["/events"]


def test_a_form_not_right_before_its_bus_message_is_dropped(tmp_path):
    report = recover(_log_with_held(tmp_path / "b.mcap", ["form", "junk"]), tmp_path / "fixed.mcap")
    assert report.dropped == 2
    assert report.rebuilt_channels == []


def test_a_message_without_channel_at_the_end_of_the_log_is_dropped(tmp_path):
    """After the last bus message no bus message can claim it as its form."""
    heartbeat = replace(make_message("heartbeat", t_capture_s=1.0, interval_s=1.0), source="robot", seq=1)
    log = tmp_path / "d.mcap"
    with log.open("wb") as f:
        writer = Writer(f)
        writer.start(PROFILE, "test")
        channel = register_bus_channel(writer, "heartbeat", "heartbeat")
        writer.add_message(channel, log_time=T0, data=pack_frames(encode(heartbeat)), publish_time=T0, sequence=1)
        writer.add_message(channel + 7, log_time=T0 + 1, data=b"junk", publish_time=T0 + 1, sequence=2)
        writer.finish()
    report = recover(log, tmp_path / "fixed.mcap")
    assert (report.messages, report.dropped) == (1, 1)


def test_messages_on_a_channel_without_schema_are_copied(tmp_path):
    """MCAP schema id 0: a channel with no schema; its messages are copied, not dropped."""
    log = tmp_path / "e.mcap"
    with log.open("wb") as f:
        writer = Writer(f)
        writer.start(PROFILE, "test")
        channel = writer.register_channel("/note", "json", 0, {})
        writer.add_message(channel, log_time=T0, data=b'{"a": 1}', publish_time=T0, sequence=1)
        writer.finish()
    assert recover(log, tmp_path / "fixed.mcap").dropped == 0
    with (tmp_path / "fixed.mcap").open("rb") as f:
        assert [(c.topic, bytes(m.data)) for _, c, m in make_reader(f).iter_messages()] == [("/note", b'{"a": 1}')]
