"""Reading on after damage: the records after a damaged chunk that the summary indexes, the losses
of a log without one, with their times, and the messages on lost channels that recovery drops."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import pytest
from mcap.reader import make_reader
from mcap.records import Message
from mcap.stream_reader import StreamReader, breakup_chunk
from mcap.writer import CompressionType, Writer

from teleop.bus.wire import encode, make_message
from teleop.session import LogReader, recover
from teleop.session.foxglove import foxglove_messages
from teleop.session.logfile import (
    CHUNK_BYTES,
    END_METADATA,
    MESSAGE_ENCODING,
    PROFILE,
    SCHEMA_ENCODING,
    schema_data,
)
from teleop.session.logframes import pack_frames

NOTE = "notes.txt"  # an attachment written after the last chunk


def _copy_with_a_late_attachment(source: Path, out: Path, *, note_first: bool) -> None:
    """``source`` rewritten with its end metadata and the attachment :data:`NOTE` after its last chunk
    (``note_first``: the attachment right after the chunk, else the end metadata)."""
    with source.open("rb") as f:
        reader = make_reader(f)
        header = reader.get_header()
        attachments = list(reader.iter_attachments())
        metadata = list(reader.iter_metadata())
        messages = list(reader.iter_messages(log_time_order=False))
    with out.open("wb") as file:
        writer = Writer(file, chunk_size=CHUNK_BYTES, compression=CompressionType.ZSTD)
        writer.start(header.profile, header.library)
        for a in attachments:
            writer.add_attachment(a.create_time, a.log_time, a.name, a.media_type, a.data)
        for m in metadata:
            if m.name != END_METADATA:
                writer.add_metadata(m.name, dict(m.metadata))
        schemas, channels = {}, {}
        for schema, channel, message in messages:
            if schema.id not in schemas:
                schemas[schema.id] = writer.register_schema(schema.name, schema.encoding, schema.data)
            if channel.id not in channels:
                channels[channel.id] = writer.register_channel(
                    channel.topic, channel.message_encoding, schemas[schema.id], dict(channel.metadata)
                )
            writer.add_message(channels[channel.id], message.log_time, message.data, message.publish_time,
                               message.sequence)
        writer.flush()  # the last chunk, then what follows it
        end = next(m for m in metadata if m.name == END_METADATA)
        late = [lambda: writer.add_attachment(0, 0, NOTE, "text/plain", b"written after the last chunk"),
                lambda: writer.add_metadata(END_METADATA, dict(end.metadata))]
        for add in late if note_first else late[::-1]:
            add()
        writer.finish()


def _damage_last_chunk(path: Path) -> int:
    """Zero bytes in the middle of the last chunk of ``path``; where that chunk starts."""
    with path.open("rb") as f:
        last = max(make_reader(f).get_summary().chunk_indexes, key=lambda c: c.chunk_start_offset)
    data = bytearray(path.read_bytes())
    middle = last.chunk_start_offset + last.chunk_length // 2
    data[middle : middle + 64] = bytes(64)
    path.write_bytes(bytes(data))
    return last.chunk_start_offset


@pytest.mark.parametrize("note_first", [True, False], ids=["attachment-then-metadata", "metadata-then-attachment"])
def test_recover_reads_on_to_the_metadata_and_attachment_after_a_damaged_last_chunk(
    recorded, tmp_path, note_first
):
    log = tmp_path / "late.mcap"
    _copy_with_a_late_attachment(recorded.path, log, note_first=note_first)
    assert LogReader(log).info().complete
    chunk = _damage_last_chunk(log)

    report = recover(log, tmp_path / "fixed.mcap")
    assert report.damaged and f"skipped bytes {chunk} to" in report.damage
    assert report.closed_cleanly and END_METADATA in report.metadata
    assert NOTE in report.attachments
    with (tmp_path / "fixed.mcap").open("rb") as f:
        reader = make_reader(f)
        assert NOTE in {a.name for a in reader.iter_attachments()}
        assert END_METADATA in {m.name for m in reader.iter_metadata()}


def _first_message_ns(path: Path, chunk) -> int:
    """The log time of the first message (any channel) stored in ``chunk`` of ``path``, in file order."""
    with path.open("rb") as f:
        f.seek(chunk.chunk_start_offset)
        record = next(StreamReader(f, skip_magic=True, emit_chunks=True).records)
    return next(r.log_time for r in breakup_chunk(record) if isinstance(r, Message))


def test_a_chunk_skipped_in_a_log_without_summary_ends_at_the_next_message_read(recorded, tmp_path):
    whole = recorded.path.read_bytes()
    with recorded.path.open("rb") as f:
        chunks = sorted(make_reader(f).get_summary().chunk_indexes, key=lambda c: c.chunk_start_offset)
    target, after = chunks[len(chunks) // 2], chunks[len(chunks) // 2 + 1]
    data = bytearray(whole[: chunks[-1].chunk_start_offset])  # no summary, no footer: a killed recorder's log
    middle = target.chunk_start_offset + target.chunk_length // 2
    data[middle : middle + 64] = bytes(64)  # its length intact, its contents not
    damaged = tmp_path / "damaged.mcap"
    damaged.write_bytes(bytes(data))
    reader = LogReader(damaged)
    read = [m.log_time_ns for m in reader.messages()]
    assert any(t >= after.message_start_time for t in read)  # read on after the damage
    assert [(c.start_byte, c.end_byte, c.kind) for c in reader.lost] == [
        (target.chunk_start_offset, target.chunk_start_offset + target.chunk_length, "chunk")]
    lost = reader.lost[0]
    assert lost.start_ns <= target.message_start_time  # the message before it, the latest known
    assert lost.end_ns == _first_message_ns(recorded.path, after)


LOST_CHANNEL = 99  # a channel id no channel record in the log has (its record lost with a damaged chunk)


def _bus(kind: str, seq: int, **fields):
    """A bus message and its Foxglove forms (one each here)."""
    message = replace(make_message(kind, t_capture_s=float(seq), t_s=[float(seq)], **fields), source="robot", seq=seq)
    forms = foxglove_messages(message)
    assert len(forms) == 1
    return message, forms[0]


def _lost_channel_log(path: Path, *, junk_before: bool, forms_after: bool) -> None:
    """A log with a force message whose Foxglove form is on a lost channel: ``junk_before`` puts a message
    that tells nothing on another lost channel before that form; ``forms_after`` ends the log with the form,
    on a third lost channel, of a width message that is not there (the file ends before it)."""
    with path.open("wb") as f:
        writer = Writer(f)
        writer.start(PROFILE, "test")
        schema = writer.register_schema("compliance-teleop/force", SCHEMA_ENCODING, schema_data("force"))
        channel = writer.register_channel("force", MESSAGE_ENCODING, schema, {"type": "force"})
        if junk_before:
            writer.add_message(LOST_CHANNEL + 1, log_time=1, data=b'{"a": 1}', publish_time=1)
        message, form = _bus("force", 1, value_n=[1.0])
        writer.add_message(LOST_CHANNEL, log_time=2, data=form.data, publish_time=message.t_send_ns,
                           sequence=message.seq)
        writer.add_message(channel, log_time=2, data=pack_frames(encode(message)), publish_time=message.t_send_ns,
                           sequence=message.seq)
        if forms_after:
            unsent, form = _bus("width", 2, value_m=[0.05])
            writer.add_message(LOST_CHANNEL + 2, log_time=3, data=form.data, publish_time=unsent.t_send_ns,
                               sequence=unsent.seq)
        writer.finish()


@pytest.mark.parametrize(("junk_before", "forms_after"), [(False, True), (True, False)],
                         ids=["held-forms-at-the-end", "held-message-before-the-forms"])
def test_messages_held_on_lost_channels_that_no_bus_message_claims_are_dropped_and_counted(
    tmp_path, junk_before, forms_after
):
    log = tmp_path / "lost.mcap"
    _lost_channel_log(log, junk_before=junk_before, forms_after=forms_after)
    report = recover(log, tmp_path / "fixed.mcap")
    assert (report.messages, report.dropped, report.rebuilt_channels) == (1, 1, ["/force"])
    with (tmp_path / "fixed.mcap").open("rb") as f:
        kept = [(c.topic, m.log_time) for _, c, m in make_reader(f).iter_messages(log_time_order=False)]
    assert kept == [("/force", 2), ("force", 2)]  # the bus message and its form; neither of the others
