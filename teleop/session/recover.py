"""Recovery: a session log cut short (recorder killed, disk full) rewritten as a complete MCAP file.

The damaged log is read front to back with mcap's non-seeking reader (CRCs checked), past
damaged records where it can (:class:`~teleop.session.logfile.LogReader`), up to its last
complete record; every complete record read (header, schemas,
channels, messages, attachments, metadata) is copied unchanged, message data byte for
byte, into a new file with a summary, indexes and footer. A ``recovery`` metadata record
says what was salvaged from where, and lists the parts lost (``lost``: those of the source,
with its byte offsets and the log times of what they held, and those the source had lost
before when it was itself recovered), so readers of the copy take them as lost
(:mod:`teleop.session.logdamage`). An attachment whose CRC-32 fails is copied with its stored
CRC-32, not a fresh one, so the copy's readers find the damage too; it is named in
``damaged_attachments``. Bytes after the footer of a source otherwise complete are not read, but
counted (``trailing_bytes``): such a file is what two writers on one log leave, its footer the
last one's.
"""

from __future__ import annotations

import json
from collections import Counter
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from mcap.records import Attachment, Channel, Header, Message, Metadata, Schema
from mcap.writer import CompressionType
from tqdm import tqdm

from teleop.bus.pubsub import DEFAULT_MAX_BYTES
from teleop.bus.wire import decode
from teleop.errors import MessageRejected, SessionLogError
from teleop.progress import progress_bar
from teleop.record import software_version
from teleop.session.logdamage import RECOVERY_METADATA, DamagedAttachment, DamageKeepingWriter
from teleop.session.logfile import CHUNK_BYTES, END_METADATA, LogReader, StoredFrames
from teleop.session.recordfile import refuse_if_held

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
    undecodable: int = 0  # complete messages kept verbatim that are not valid bus messages
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
    temporary name and renamed when done.

    Raises
    ------
    SessionLogError
        ``out`` is ``source`` or a log a recorder is writing, ``source`` is not an MCAP file or
        has no header, or ``out`` cannot be written.
    """
    source, out = Path(source), Path(out)
    check_not_source(source, out)
    refuse_if_held(out, "write the recovered log elsewhere")
    reader = LogReader(source)
    report = RecoveryReport(
        str(source), str(out), complete=False, closed_cleanly=False, damage=None
    )
    tmp = out.with_name(out.name + ".partial")
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
        tmp.unlink(missing_ok=True)
        raise SessionLogError(
            f"cannot write the recovered log {out}: {exc.strerror or exc}"
        ) from exc
    except BaseException:  # SessionLogError, or interrupted (Ctrl-C, SIGTERM): no temporary left behind
        tmp.unlink(missing_ok=True)
        raise
    return report


def _copy(reader: LogReader, writer: DamageKeepingWriter, report: RecoveryReport, bar: tqdm) -> None:
    """Copy what ``reader`` reads through ``writer``, noting it in ``report``."""
    schemas: dict[int, int] = {}  # source id -> id in the copy (the summary repeats them)
    channels: dict[int, tuple[int, str]] = {}
    stored = StoredFrames()  # puts elided image data back, to check each bus message decodes
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
            stored.add(record)
            copy = writer.register_channel(
                record.topic,
                record.message_encoding,
                schemas.get(record.schema_id, 0),
                dict(record.metadata),
            )
            channels[record.id] = (copy, record.topic)
        elif isinstance(record, Message):
            if record.channel_id not in channels:
                report.undecodable += 1  # no channel says what it is: cannot be written validly
                continue
            channel, topic = channels[record.channel_id]
            writer.add_message(
                channel,
                log_time=record.log_time,
                data=record.data,
                publish_time=record.publish_time,
                sequence=record.sequence,
            )
            if not stored.is_bus(record):
                stored.note(record)
                continue
            report.messages += 1
            report.topics[topic] += 1
            report.undecodable += not _decodes(stored, record)
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


def _decodes(stored: StoredFrames, record: Message) -> bool:
    try:
        decode(stored.frames(record), max_bytes=DEFAULT_MAX_BYTES)
    except MessageRejected:
        return False
    return True
