"""What of a session log is lost or damaged: skipped parts, parts lost before a recovery, and
attachments whose checksum fails, and what a damaged record is
(:class:`~teleop.session.logfile.LogReader` uses these).

Lost parts
----------
A :class:`LostChunk` is a part of a log that could not be read, with the log times of the
messages it may have held: grasps overlapping it are not whole. A lost attachment or metadata
record is one too (:meth:`LostChunk.record`), holding no messages: it overlaps no grasp. ``teleop
recover`` copies only what it could read, so it lists every part lost in its source (and those its
source had lost before, when the source was itself recovered) in the ``lost`` entry of its
:data:`RECOVERY_METADATA` record, a JSON list of :meth:`LostChunk.as_mapping`; the reader of the
recovered log reads them back (:func:`recorded_losses`) and takes them as lost too.

Attachments
-----------
mcap's reader checks the checksums of chunks but not those of attachments: :func:`check_attachment`
computes an attachment's CRC-32 (over the record's fields before it, as the MCAP specification
says) and compares it with the stored one (0: none stored).
"""

from __future__ import annotations

import json
import os
import struct
import zlib
from collections.abc import Iterator
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from mcap.opcode import Opcode
from mcap.records import Attachment, Metadata
from mcap.stream_reader import StreamReader
from mcap.summary import Summary
from mcap.writer import Writer

from teleop.errors import SessionLogError
from teleop.session.logscan import UNKNOWN_NS, record_head, record_name

__all__ = [
    "RECOVERY_METADATA",
    "DamageKeepingWriter",
    "DamagedAttachment",
    "LostChunk",
    "check_attachment",
    "describe",
    "intact_attachment",
    "recorded_losses",
    "recovery_metadata",
    "skipped_in_summary",
]

RECOVERY_METADATA = "recovery"  # the metadata record `teleop recover` adds to what it writes
_LOST_KEY = "lost"  # ... its entry listing the parts lost (JSON)
_FIELDS = {"start_byte": int, "end_byte": int, "start_ns": int, "end_ns": int, "kind": str, "lost_in": str}
_RECORD_KINDS = ("attachment record", "metadata record")  # lost records that hold no messages


@dataclass(frozen=True)
class LostChunk:
    """A chunk skipped because it (or the record before it) is damaged: its bytes and log times; or
    another part skipped (:attr:`kind`), such as an attachment or metadata record (:meth:`record`).

    ``lost_in``: the log it was lost from, when that is not this one (a recovered log's source:
    the bytes are that log's); "" when it was skipped in this very file.
    """

    start_byte: int
    end_byte: int
    start_ns: int  # log time of its first message
    end_ns: int  # ... and of its last (UNKNOWN_NS: no message read after it)
    kind: str = "chunk"  # or what else was skipped (a log without summary: bytes not read; a record)
    lost_in: str = ""

    @classmethod
    def record(cls, start_byte: int, end_byte: int, opcode: str, named: str) -> LostChunk:
        """The ``opcode`` ("attachment" or "metadata") record at those bytes, lost; ``named``: its
        name as `` 'name'`` ("" when it does not read). It holds no messages: its log times are an
        empty span (first after last), which no message's overlaps for readers going by times alone."""
        return cls(start_byte, end_byte, UNKNOWN_NS, 0, f"{opcode} record{named}")

    @property
    def holds_messages(self) -> bool:
        """Whether messages may have been in it (a lost attachment or metadata record holds none)."""
        return not self.kind.startswith(_RECORD_KINDS)

    def overlaps(self, start_ns: int, end_ns: int) -> bool:
        """Whether messages logged between ``start_ns`` and ``end_ns`` may have been in it."""
        return self.holds_messages and self.start_ns <= end_ns and start_ns <= self.end_ns

    def as_mapping(self, path: Path | str) -> dict[str, Any]:
        """Its fields, as the recovery metadata stores them; ``path``: the log it was read from."""
        return {**asdict(self), "lost_in": self.lost_in or str(path)}

    def __str__(self) -> str:
        if not self.holds_messages:
            times = "no messages were lost: it holds none"
        elif self.kind == "chunk":
            times = f"messages logged from {self.start_ns} to {self.end_ns} ns lost"
        elif self.end_ns == UNKNOWN_NS:
            times = f"messages logged after {self.start_ns} ns lost"
        else:
            times = f"messages logged between {self.start_ns} and {self.end_ns} ns lost"
        if self.lost_in:
            return (f"lost before recovery: the {self.kind} at bytes {self.start_byte} to {self.end_byte} "
                    f"of {self.lost_in} is damaged ({times}; `teleop recover` could not copy it)")
        return f"the {self.kind} at bytes {self.start_byte} to {self.end_byte} is damaged ({times})"


def recorded_losses(metadata: dict[str, str], path: Path) -> list[LostChunk]:
    """The parts lost before recovery that the recovery metadata ``metadata`` of log ``path`` lists.

    Recovery metadata written before it listed them has none (its ``damage`` entry says what).

    Raises
    ------
    SessionLogError
        The list is not JSON, or an entry is not an object of the fields of :class:`LostChunk`.
    """
    text = metadata.get(_LOST_KEY)
    if text is None:
        return []
    expected = (f"expected a JSON list of objects with {', '.join(_FIELDS)} "
                "(integers, and the kind and log as strings)")
    try:
        entries = json.loads(text)
    except json.JSONDecodeError as exc:
        raise SessionLogError(f"{path}: {RECOVERY_METADATA} metadata {_LOST_KEY!r} is not JSON ({exc}); "
                              f"{expected}") from exc
    if not isinstance(entries, list):
        raise SessionLogError(f"{path}: {RECOVERY_METADATA} metadata {_LOST_KEY!r}: {expected}")
    lost = []
    for entry in entries:
        if not (isinstance(entry, dict) and entry.keys() == _FIELDS.keys() and all(
                type(entry[k]) is kind for k, kind in _FIELDS.items())):
            raise SessionLogError(f"{path}: {RECOVERY_METADATA} metadata {_LOST_KEY!r} holds {entry!r}; "
                                  f"{expected}")
        lost.append(LostChunk(**entry))
    return lost


class DamageKeepingWriter(Writer):
    """mcap's writer, which can also copy a damaged attachment with the CRC-32 it was stored with, so
    that readers of the copy find the damage too (``teleop recover``, ``teleop label``)."""

    def __init__(self, output: Any, **options: Any):
        super().__init__(output, **options)
        self._file = output

    def add_damaged_attachment(self, record: DamagedAttachment) -> None:
        """Write ``record`` with its stored CRC-32 in place of the one computed afresh (the writer
        writes each attachment out at once: its record ends where the file stands)."""
        self.add_attachment(record.create_time, record.log_time, record.name, record.media_type, record.data)
        end = self._file.tell()
        self._file.seek(end - 4)
        self._file.write(struct.pack("<I", record.stored_crc))
        self._file.seek(end)


@dataclass
class DamagedAttachment(Attachment):
    """An attachment whose contents do not match its stored CRC-32, as read; where it lies."""

    stored_crc: int = 0
    crc: int = 0  # the CRC-32 of what was read
    start_byte: int = 0
    end_byte: int = 0

    def __str__(self) -> str:
        return (f"attachment {self.name!r} at bytes {self.start_byte} to {self.end_byte} is damaged "
                f"(its contents' CRC-32 {self.crc:#010x} is not the stored {self.stored_crc:#010x})")


def intact_attachment(info: Any, name: str, *, log: Path, instead: str) -> bytes | None:
    """The attachment ``name`` of ``info`` (the :class:`~teleop.session.logfile.LogInfo` of log
    ``log``), None when the log has none; SessionLogError naming its damage and ``instead`` (what to
    do) when its CRC-32 failed: nothing is built from what the damage left."""
    if name in info.damaged_attachments:
        raise SessionLogError(f"{log}: {info.damaged_attachments[name]}: nothing can be built from it; "
                              f"{instead}; nothing was written")
    return info.attachments.get(name)


def check_attachment(file: Any, record: Attachment, end: int) -> Attachment:
    """``record``, read from ``file`` and ending at byte ``end``; a :class:`DamagedAttachment` if its
    CRC-32 fails. Leaves ``file`` at ``end``."""
    name, media_type = record.name.encode("utf-8"), record.media_type.encode("utf-8")
    head = (struct.pack("<QQI", record.log_time, record.create_time, len(name)) + name
            + struct.pack("<I", len(media_type)) + media_type + struct.pack("<Q", len(record.data)))
    file.seek(end - 4)
    stored = struct.unpack("<I", file.read(4))[0]
    file.seek(end)
    crc = zlib.crc32(record.data, zlib.crc32(head))
    if stored == 0 or stored == crc:
        return record
    return DamagedAttachment(
        record.create_time, record.log_time, record.name, record.media_type, record.data,
        stored_crc=stored, crc=crc, start_byte=end - 9 - len(head) - len(record.data) - 4, end_byte=end,
    )


def skipped_in_summary(summary: Summary, start: int, end: int) -> tuple[list[LostChunk], str]:
    """The chunks, attachment and metadata records that ``summary`` indexes between bytes ``start``
    and ``end`` (skipped for damage) as lost parts, and what was skipped, as text."""
    chunks = [c for c in summary.chunk_indexes if start <= c.chunk_start_offset < end]
    records = [("attachment", a) for a in summary.attachment_indexes if start <= a.offset < end]
    records += [("metadata", m) for m in summary.metadata_indexes if start <= m.offset < end]
    lost = [
        LostChunk(c.chunk_start_offset, c.chunk_start_offset + c.chunk_length, c.message_start_time,
                  c.message_end_time)
        for c in chunks
    ]
    lost += [LostChunk.record(i.offset, i.offset + i.length, opcode, f" {i.name!r}") for opcode, i in records]
    times = ""
    if chunks:
        first = min(c.message_start_time for c in chunks)
        last = max(c.message_end_time for c in chunks)
        times = f", messages logged from {first} to {last} ns"
    named = [f"{opcode} {i.name!r}" for opcode, i in records]
    also = f"; lost: {', '.join(named)}" if named else ""
    return lost, (
        f"; skipped bytes {start} to {end} ({len(chunks)} chunk(s) lost{times}{also}) "
        "and read on from there"
    )


def recovery_metadata(file: Any, summary: Summary | None, size: int) -> Iterator[dict[str, str]]:
    """The :data:`RECOVERY_METADATA` records that ``summary`` (of ``file``, ``size`` bytes) indexes,
    as read; one that does not read is left to reading the file front to back to find."""
    if summary is None:
        return
    for index in summary.metadata_indexes:
        if index.name != RECOVERY_METADATA:
            continue
        file.seek(index.offset)
        try:
            record = next(StreamReader(file, skip_magic=True, record_size_limit=max(size, 1)).records)
        except Exception:  # any parse failure: the front-to-back read says what it is
            continue
        if isinstance(record, Metadata) and record.name == RECOVERY_METADATA:
            yield dict(record.metadata)


def describe(exc: Exception, file: Any, start: int, size: int, good_bytes: int, uncut: str | None) -> str:
    """What is wrong with the record at byte ``start`` of ``file`` (``size`` bytes when it was opened,
    read without fault up to ``good_bytes``); ``exc``: the failure reading it; ``uncut``: why the file
    is not cut short (None: nothing says so). A file that grew while it was read (a log still being
    written) is described as it was read, with its size now and a word that it grew (or shrank: cut
    or replaced meanwhile)."""
    now = _size_now(file, size)
    total = max(now, size)  # the byte read is within what was there, grown or cut since
    grew = ("" if now == size else
            f"; the file grew from {size} to {now} bytes while it was read: it is still being written" if now > size
            else f"; the file shrank from {size} to {now} bytes while it was read: it was cut or replaced")
    if good_bytes == size:
        return (
            f"the file ends after its last complete record (byte {size}) "
            "without a summary and footer" + grew
        )
    what = type(exc).__name__ + (f": {exc}" if str(exc) else "")
    head = record_head(file, start)
    if head is None:
        kind = "record"
    else:
        try:
            kind = Opcode(head[0]).name.lower() + " record"
        except ValueError:
            kind = f"record of unknown opcode {head[0]:#x}"
        kind += record_name(file, start, head[0])
    kind = ("an " if kind[0] in "aeiou" else "a ") + kind
    if head is None or start + 9 + head[1] > size:
        length = "" if head is None else f" of {head[1]} bytes"
        if uncut is None:  # really cut short, unless a later chunk shows it is damage (LogReader._read_on)
            return (
                f"the file ends inside the record after byte {start} of {total} "
                f"({kind}{length} starts at byte {start}){grew}"
            )
        return (
            f"damaged record after byte {start} of {total} ({kind} whose length{length} runs "
            f"past the end of the file, though {uncut}){grew}"
        )
    return f"damaged record after byte {start} of {total} ({kind} of {head[1]} bytes: {what}){grew}"


def _size_now(file: Any, size: int) -> int:
    """The size of ``file`` now (a log still being written grows while it is read); ``size`` for a
    file object that has no file on disk."""
    try:
        return os.fstat(file.fileno()).st_size
    except (AttributeError, OSError, ValueError):  # an in-memory file: no descriptor
        return size
