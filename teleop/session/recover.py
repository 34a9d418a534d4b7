"""Recovery: a session log cut short (recorder killed, disk full) rewritten as a complete MCAP file.

The damaged log is read front to back with mcap's non-seeking reader (CRCs checked), past
damaged records where it can (:class:`~teleop.session.logfile.LogReader`), up to its last
complete record; every complete record read (header, schemas,
channels, messages, attachments, metadata) is copied unchanged, message data byte for
byte, into a new file with a summary, indexes and footer. A ``recovery`` metadata record
says what was salvaged from where, and lists the parts lost (``lost``: those of the source,
with its byte offsets and the log times of what they held, attachment and metadata records
named and holding no messages, and those the source had lost before when it was itself
recovered), so readers of the copy take them as lost
(:mod:`teleop.session.logdamage`). An attachment whose CRC-32 fails is copied with its stored
CRC-32, not a fresh one, so the copy's readers find the damage too; it is named in
``damaged_attachments``. A message whose channel record was lost with a damaged chunk (a killed
recorder's log has no summary to repeat it), or whose schema record was, is kept when it tells what it is: a bus message
carries its topic and type, so its channel is registered again as the recorder registers it
(:class:`~teleop.session.foxglove_log.LogChannels`), and the messages on lost channels right
before it with its publish time and sequence, as many as its Foxglove forms
(:func:`~teleop.session.foxglove.foxglove_messages`), go on those forms' channels
(``rebuilt_channels``); any other is left out (``dropped``). Bytes after the footer of a source
otherwise complete are not read, but counted (``trailing_bytes``): such a file is what two writers
on one log leave, its footer the last one's.
"""

from __future__ import annotations

import json
from collections import Counter
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage
from google.protobuf.message import DecodeError
from mcap.records import Attachment, Channel, Header, Message, Metadata, Schema
from mcap.writer import CompressionType
from tqdm import tqdm

from teleop.bus.pubsub import DEFAULT_MAX_BYTES
from teleop.bus.wire import Message as BusMessage
from teleop.bus.wire import decode
from teleop.errors import MessageRejected, SessionLogError
from teleop.progress import progress_bar
from teleop.record import software_version
from teleop.session.foxglove import foxglove_messages
from teleop.session.foxglove_log import LogChannels
from teleop.session.logdamage import RECOVERY_METADATA, DamagedAttachment, DamageKeepingWriter
from teleop.session.logfile import CHUNK_BYTES, END_METADATA, LogReader, StoredFrames
from teleop.session.logframes import unpack_frames
from teleop.session.recordfile import rewriting

__all__ = ["RECOVERY_METADATA", "RecoveryReport", "check_not_source", "recover"]


@dataclass
class RecoveryReport:
    """What :func:`recover` salvaged."""

    source: str
    out: str
    complete: bool  # the source had its footer: nothing was missing
    closed_cleanly: bool  # the source has the recorder's end-of-session metadata
    damage: str | None  # what was damaged or cut short, where, and what was skipped
    damaged: bool = False  # a record was damaged (skipped, or reading stopped there)
    cut_short: bool = False  # the source ends inside a record or without its footer
    messages: int = 0  # bus messages (Foxglove channels are copied, not counted)
    topics: Counter[str] = field(default_factory=Counter)
    undecodable: int = 0  # messages on bus channels kept verbatim that are not valid bus messages
    dropped: int = 0  # messages left out: their channel record was lost and they do not tell what they are
    rebuilt_channels: list[str] = field(default_factory=list)  # topics whose lost channel records were rebuilt
    attachments: list[str] = field(default_factory=list)
    damaged_attachments: list[str] = field(default_factory=list)  # copied with their stored CRC-32
    metadata: list[str] = field(default_factory=list)
    salvaged_bytes: int = 0  # where the last complete record read ends (damage before it skipped)
    source_bytes: int = 0
    trailing_bytes: int = 0  # bytes after the footer of a complete source (not read): another writer's
    lost: list[dict[str, Any]] = field(default_factory=list)  # LostChunk.as_mapping of each part lost

    def as_dict(self) -> dict[str, Any]:
        out = {k: v for k, v in self.__dict__.items() if k != "topics"}
        out["topics"] = dict(sorted(self.topics.items()))
        return out


def check_not_source(source: Path, out: Path) -> None:
    """Refuse an ``out`` that is the log ``source`` itself (:class:`SessionLogError`)."""
    if out.exists() and source.exists() and out.resolve() == source.resolve():
        raise SessionLogError(
            f"--out {out} is the log being recovered: write the recovered log elsewhere"
        )


def recover(source: str | Path, out: str | Path, *, progress: bool = False) -> RecoveryReport:
    """Copy every complete record of the session log ``source`` into a complete MCAP ``out``.

    Works on complete logs too (the copy is then whole). ``out`` is written under a
    temporary name and renamed when done (:func:`~teleop.session.recordfile.rewriting`).

    Raises
    ------
    SessionLogError
        ``out`` is ``source`` or a log a recorder is writing or another process rewrites,
        ``source`` is not an MCAP file or has no header, or ``out`` cannot be written.
    """
    source, out = Path(source), Path(out)
    check_not_source(source, out)
    # Held to the rename, and removed if left (an error, or interrupted: Ctrl-C, SIGTERM).
    with rewriting(out, "write the recovered log elsewhere") as tmp:
        reader = LogReader(source)
        report = RecoveryReport(
            str(source), str(out), complete=False, closed_cleanly=False, damage=None
        )
        try:
            with (
                tmp.open("wb") as file,
                progress_bar(
                    desc=f"recover {source.name}", unit="B", unit_scale=True, enabled=progress
                ) as bar,
            ):
                _copy(
                    reader,
                    DamageKeepingWriter(file, chunk_size=CHUNK_BYTES, compression=CompressionType.ZSTD),
                    report,
                    bar,
                )
            tmp.replace(out)
        except OSError as exc:
            raise SessionLogError(
                f"cannot write the recovered log {out}: {exc.strerror or exc}"
            ) from exc
    return report


def _copy(reader: LogReader, writer: DamageKeepingWriter, report: RecoveryReport, bar: tqdm) -> None:
    """Copy what ``reader`` reads through ``writer``, noting it in ``report``."""
    schemas: dict[int, int] = {}  # source id -> id in the copy (the summary repeats them)
    channels: dict[int, tuple[int, str]] = {}
    stored = StoredFrames()  # puts elided image data back, to check each bus message decodes
    orphans: dict[int, Channel] = {}  # channel records whose schema record was lost, by source id
    lost = _LostChannels(writer, stored, channels, report)
    started = False
    for record in reader.records():
        bar.update(reader.good_bytes - bar.n)
        if isinstance(record, Header):
            writer.start(record.profile, record.library)
            started = True
        elif not started:
            break
        elif isinstance(record, Schema) and record.id not in schemas:
            stored.add(record)
            schemas[record.id] = writer.register_schema(record.name, record.encoding, record.data)
        elif isinstance(record, Channel) and record.id not in channels:
            if record.schema_id in (0, *schemas):
                _register(writer, stored, channels, schemas, record)
            else:  # its schema record a damaged chunk took: rebuilt from its messages, schema and all
                orphans[record.id] = record
        elif isinstance(record, Message):
            if record.channel_id in channels and not stored.is_bus(record):
                _write(writer, channels[record.channel_id][0], record)
                stored.note(record)
                continue
            message = lost.decode(record)
            if record.channel_id not in channels:
                orphan = orphans.get(record.channel_id)
                if message is None and (orphan is None or orphan.topic.startswith("/")):
                    lost.hold(record)  # perhaps a Foxglove form of the bus message next
                    continue
                if message is None:  # a bus message that does not decode: kept verbatim, as on a known channel
                    _register(writer, stored, channels, schemas, orphans.pop(record.channel_id))
                else:
                    lost.rebuild_bus(record, message)
            lost.place_forms(record, message)
            channel, topic = channels[record.channel_id]
            _write(writer, channel, record)
            report.messages += 1
            report.topics[topic] += 1
            report.undecodable += message is None
        elif isinstance(record, Attachment):
            if isinstance(record, DamagedAttachment):
                writer.add_damaged_attachment(record)
                report.damaged_attachments.append(record.name)
            else:
                writer.add_attachment(
                    record.create_time, record.log_time, record.name, record.media_type, record.data
                )
            report.attachments.append(record.name)
        elif isinstance(record, Metadata):
            writer.add_metadata(record.name, dict(record.metadata))
            report.metadata.append(record.name)
    lost.drop_held()
    if not started:
        raise SessionLogError(
            f"{reader.path} has no readable MCAP header record: nothing to recover"
        )
    report.complete = reader.complete
    report.damage, report.damaged, report.cut_short = reader.damage, reader.damaged, reader.cut
    report.closed_cleanly = END_METADATA in report.metadata
    report.salvaged_bytes = reader.good_bytes
    report.source_bytes = reader.path.stat().st_size
    if reader.complete:
        report.trailing_bytes = report.source_bytes - reader.good_bytes
    report.lost = [chunk.as_mapping(reader.path.resolve()) for chunk in reader.lost]
    writer.add_metadata(
        RECOVERY_METADATA,
        {
            "source": str(reader.path.resolve()),
            "recovered_utc": datetime.now(UTC).isoformat(),
            "software_version": software_version(),
            **{
                key: json.dumps(value)
                for key, value in report.as_dict().items()
                if key not in ("source", "out")
            },
        },
    )
    writer.finish()


def _register(
    writer: DamageKeepingWriter,
    stored: StoredFrames,
    channels: dict[int, tuple[int, str]],
    schemas: dict[int, int],
    record: Channel,
) -> None:
    """Register the source's channel ``record`` in the copy (its schema's copy, or none if that was lost)."""
    stored.add(record)
    copy = writer.register_channel(record.topic, record.message_encoding, schemas.get(record.schema_id, 0),
                                   dict(record.metadata))
    channels[record.id] = (copy, record.topic)


def _write(writer: DamageKeepingWriter, channel: int, record: Message) -> None:
    """Copy ``record`` onto the copy's ``channel``, its data byte for byte."""
    writer.add_message(
        channel,
        log_time=record.log_time,
        data=record.data,
        publish_time=record.publish_time,
        sequence=record.sequence,
    )


class _Registrar(LogChannels):
    """The recorder's registration of schemas and channels, writing no message: each one's channel
    is noted instead (``placed``), for the message being copied to go on; so which channel a bus
    message or a Foxglove form goes on is said in :class:`LogChannels` alone."""

    def __init__(self, writer: DamageKeepingWriter):
        super().__init__(writer)
        self.placed: list[int] = []

    def _add(self, channel: int, data: bytes, message: BusMessage, log_time_ns: int) -> None:
        self.placed.append(channel)


class _LostChannels:
    """The channels whose records a damaged chunk took, rebuilt from their messages (module notes).

    ``channels`` (source channel id -> the copy's channel and its topic) and ``stored`` are
    :func:`_copy`'s: a rebuilt channel joins them, so the rest of its messages are copied as any.
    """

    def __init__(
        self,
        writer: DamageKeepingWriter,
        stored: StoredFrames,
        channels: dict[int, tuple[int, str]],
        report: RecoveryReport,
    ):
        self.writer, self.stored, self.channels, self.report = writer, stored, channels, report
        self.registrar = _Registrar(writer)
        self.held: list[Message] = []  # messages on lost channels, in file order, not yet placed

    def decode(self, record: Message) -> BusMessage | None:
        """``record`` decoded as a bus message; None when it is not one (or its image data is lost)."""
        try:
            return decode(self._frames(record), max_bytes=DEFAULT_MAX_BYTES)
        except MessageRejected:
            return None

    def hold(self, record: Message) -> None:
        self.held.append(record)

    def rebuild_bus(self, record: Message, message: BusMessage) -> None:
        """Register the channel of ``record``, the bus message ``message``, as the recorder does."""
        self.registrar.placed.clear()
        self.registrar.write_bus(message, (), 0, elide_image=False)
        self._rebuilt(record.channel_id, self.registrar.placed[0], message.topic)

    def place_forms(self, record: Message, message: BusMessage | None) -> None:
        """Write the held messages that are the Foxglove forms of the bus message ``record`` (they
        come right before it), on their rebuilt channels; drop any other held."""
        held, self.held = self.held, []
        mine = [h for h in held if (h.publish_time, h.sequence) == (record.publish_time, record.sequence)]
        forms = [] if message is None else foxglove_messages(message)
        if not mine or len(mine) != len(forms) or held[-len(mine):] != mine:
            self.report.dropped += len(held)
            return
        self.report.dropped += len(held) - len(mine)
        self.registrar.placed.clear()
        self.registrar.write_foxglove(message, 0, forms)
        for form, channel, item in zip(forms, self.registrar.placed, mine, strict=True):
            if item.channel_id not in self.channels:
                self._rebuilt(item.channel_id, channel, form.topic)
                # a stand-in schema id (the lost one is unknown): tells an image channel's messages
                stand_in = -1 - item.channel_id
                self.stored.add(Schema(id=stand_in, data=b"", encoding=form.schema_encoding, name=form.schema_name))
                self.stored.add(Channel(id=item.channel_id, topic=form.topic, message_encoding=form.message_encoding,
                                        metadata={}, schema_id=stand_in))
            _write(self.writer, self.channels[item.channel_id][0], item)
            self.stored.note(item)

    def drop_held(self) -> None:
        """Count what is still held at the end (no bus message followed it) as dropped."""
        self.report.dropped += len(self.held)
        self.held = []

    def _rebuilt(self, source_id: int, channel: int, topic: str) -> None:
        self.channels[source_id] = (channel, topic)
        self.report.rebuilt_channels.append(topic)

    def _frames(self, record: Message) -> list[memoryview]:
        try:
            return self.stored.frames(record)
        except MessageRejected:  # its image may be held, its channel lost: stored does not know it
            image = self._held_image(record)
            if image is None:
                raise
            return unpack_frames(record.data, elided=image)

    def _held_image(self, record: Message) -> bytes | None:
        """The image bytes ``record`` elides, from the held message right before it, if that is one."""
        if not self.held or (self.held[-1].log_time, self.held[-1].sequence) != (record.log_time, record.sequence):
            return None
        try:
            return CompressedImage.FromString(self.held[-1].data).data
        except DecodeError:
            return None
