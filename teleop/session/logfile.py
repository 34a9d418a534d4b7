"""The session log: one MCAP file per teleoperation session, and how to read it back.

Layout (format :data:`FORMAT_VERSION`)
--------------------------------------
``Header``
    profile :data:`PROFILE`, library ``compliance-teleop <version>; mcap-python <version>``.
``Schema`` (one per bus message type, registered on the type's first message)
    name ``compliance-teleop/<type>``, encoding :data:`SCHEMA_ENCODING`, data a JSON object
    ``{"wire_version", "type", "fields", "arrays", "framing"}`` (the authority on each type
    is :mod:`teleop.bus.wire`).
``Channel`` (one per bus topic: ``frame/left``, ``force``, ``estimate``, ...)
    message encoding :data:`MESSAGE_ENCODING`, metadata ``{"type": <message type>}``.
``Message`` (one per bus message, in the order the recorder received them)
    ``data``: the message's ZeroMQ frames ``[topic, header, body, *buffers]`` exactly as
    received, never re-encoded, in this container (all integers little-endian uint32;
    :mod:`teleop.session.logframes` packs and unpacks it)::

        n + flags | len(frame 0) | ... | len(frame n-1) | frame 0 | ... | frame n-1

    with ``3 <= n <= 3 + MAX_BUFFERS`` and the stored frames filling the rest of the data.
    ``flags`` is 0, or :data:`~teleop.session.logframes.ELIDED` (``0x10000``, bit 16) for a
    JPEG or PNG ``frame`` message: its last frame (the image bytes) is listed with its length
    but not stored here, as the ``foxglove.CompressedImage`` message stored right before it, with
    the same ``log_time`` and ``sequence``, holds those very bytes as its ``data``; the reader
    puts them back, so it yields the frames exactly as received.
    ``log_time``: receive time in ns since the Unix epoch: the recording host's
    ``time.monotonic_ns()`` plus the session's :data:`TIME_OFFSET_KEY` (its wall clock less
    its monotonic clock, read once at the start), so times in the log are exact differences
    of the monotonic clock and Foxglove shows the date and time of day.
    ``publish_time``: the header's ``t_send_ns`` (the sender's ``time.monotonic_ns()``) plus
    the same offset, so on one host ``log_time - publish_time`` is the transit latency.
    ``sequence``: the header's ``seq`` modulo 2**32. The headers and bodies keep their own
    times (``t_send_ns``, ``t_capture_s``, ``t_s``: monotonic) exactly as sent.
Foxglove channels (:mod:`teleop.session.foxglove`: what each bus type becomes and why)
    ``/tactile/<finger>`` (``foxglove.CompressedImage``), ``/events`` (``foxglove.Log``), both
    protobuf with a ``FileDescriptorSet`` schema; ``/force``, ``/width``, ``/estimate``,
    ``/display``, ``/command`` as JSON with a JSON Schema. Each is written just before the bus
    message it comes from, with its receive time as ``log_time`` (a force or width sample:
    minus its age in its batch, but never before the topic's previous message), the same
    ``publish_time`` and ``sequence``; their ``timestamp`` fields are capture or sample
    times plus the offset. Readers of the
    bus messages skip these channels (all but the image data above).
``Attachment``
    :data:`SETTINGS_ATTACHMENT` (the resolved settings as JSON, ``settings_to_mapping``),
    ``calibration/<finger>/<file>`` (each sensor's calibration file as it was on disk),
    ``catalogue.toml`` or ``catalogue.csv`` (the object catalogue, for labels) and
    ``scene.toml`` when the session ran a scene.
``Metadata``
    :data:`SESSION_METADATA` at the start (software version, log format, scene, source,
    start time, clocks, endpoints), :data:`RIG_METADATA` (each finger's gel modulus,
    Poisson ratio and thickness, pixel pitch, markers; the gripper's finger stiffness:
    what Foxglove's metadata panel shows) and :data:`END_METADATA` at a clean stop (counts,
    refusals, gaps, the write error if there was one). A log without the latter was not
    closed cleanly.

A log without :data:`TIME_OFFSET_KEY` has the monotonic clock's times (:attr:`LogInfo.offset_ns`
0). Readers here use log times only as differences (replay pacing, ordering), so they read both.

Format 1 (before the Foxglove channels) had only the bus channels, message encoding
``compliance-teleop.multipart/1`` and no flags; :class:`LogReader` reads both.

Chunks are small (:data:`CHUNK_BYTES`) and closed at least every ``flush_interval_s``
(the recorder's option), and every chunk goes to the operating system as soon as it is
complete, so a recorder killed outright loses at most the chunk it had open. Such a log
has no summary or footer: :class:`LogReader` reads it front to back with mcap's
non-seeking reader up to its last complete record; ``teleop recover`` rewrites the
readable part as a complete file. A damaged record is skipped and reading goes on: at the
next record the summary's indexes point to when the summary and footer are intact, else
right after the damaged record when its length is sane, else at the next intact chunk
found further on; :attr:`LogReader.lost` lists what was skipped, with its log times.

Nothing read back is trusted: every stored message goes through
:func:`teleop.bus.wire.decode` (sizes, msgpack limits, schemas) before anyone sees it, and every
attachment's CRC-32 is checked (mcap's reader checks those of chunks only).
"""

from __future__ import annotations

import json
import logging
from collections import Counter
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage
from google.protobuf.message import DecodeError
from mcap.opcode import Opcode
from mcap.reader import SeekingReader
from mcap.records import Attachment, Channel, Header, McapRecord, Message, Metadata, Schema
from mcap.stream_reader import StreamReader
from mcap.summary import Summary

from teleop.bus.pubsub import DEFAULT_MAX_BYTES
from teleop.bus.wire import SCHEMA_VERSION, SCHEMAS, decode
from teleop.bus.wire import Message as BusMessage
from teleop.errors import MessageRejected, SessionLogError
from teleop.session.foxglove import IMAGE_SCHEMA
from teleop.session.logdamage import (
    RECOVERY_METADATA,
    DamagedAttachment,
    LostChunk,
    check_attachment,
    describe,
    recorded_losses,
    recovery_metadata,
    skipped_in_summary,
)
from teleop.session.logframes import FRAMING, elides, unpack_frames
from teleop.session.logscan import (
    OPCODES,
    UNKNOWN_NS,
    check_format,
    next_chunk,
    record_head,
    record_name,
)
from teleop.settings import Settings, migrated, settings_from_mapping

__all__ = [
    "BUS_ENCODINGS",
    "CHUNK_BYTES",
    "END_METADATA",
    "FORMAT_VERSION",
    "MESSAGE_ENCODING",
    "PROFILE",
    "RIG_METADATA",
    "SCHEMA_ENCODING",
    "SESSION_METADATA",
    "SETTINGS_ATTACHMENT",
    "TIME_OFFSET_KEY",
    "LogInfo",
    "LogReader",
    "LoggedMessage",
    "LostChunk",
    "StoredFrames",
    "schema_data",
]

log = logging.getLogger(__name__)

PROFILE = "compliance-teleop.session"
FORMAT_VERSION = 2  # in the session metadata as "log_format"; 1: no Foxglove channels
MESSAGE_ENCODING = f"compliance-teleop.multipart/{FORMAT_VERSION}"
BUS_ENCODINGS = ("compliance-teleop.multipart/1", MESSAGE_ENCODING)  # channels of bus messages
SCHEMA_ENCODING = "compliance-teleop.wire/1"
SETTINGS_ATTACHMENT = "settings.json"
CATALOGUE_ATTACHMENTS = ("catalogue.toml", "catalogue.csv")  # the recorder's --objects, as it attaches it
SESSION_METADATA = "session"
RIG_METADATA = "rig"
END_METADATA = "session_end"
TIME_OFFSET_KEY = "log_time_offset_ns"  # session metadata: log time = monotonic ns + this
CHUNK_BYTES = 256 * 1024
_MAGIC = b"\x89MCAP0\r\n"


def schema_data(kind: str) -> bytes:
    """The schema record's data for bus message type ``kind`` (JSON, see the module docstring)."""
    schema = SCHEMAS[kind]
    return json.dumps(
        {
            "wire_version": SCHEMA_VERSION,
            "type": kind,
            "fields": sorted(schema.fields),
            "arrays": sorted(schema.arrays),
            "framing": FRAMING,
        },
        sort_keys=True,
    ).encode("utf-8")


class StoredFrames:
    """The bus frames of stored messages read in file order, elided image data put back.

    Feed it every ``Schema`` and ``Channel`` record (:meth:`add`); for each ``Message``
    record, :meth:`is_bus` says whether it is a bus message (its channel is unknown or has
    a bus encoding): if not, :meth:`note` it (an image may carry the next one's frame data),
    else :meth:`frames` gives its frames.
    """

    def __init__(self) -> None:
        self.channels: dict[int, Channel] = {}
        self._schemas: dict[int, str] = {}  # id -> name
        self._image: Message | None = None  # the latest foxglove.CompressedImage record

    def add(self, record: Schema | Channel) -> None:
        if isinstance(record, Schema):
            self._schemas[record.id] = record.name
        else:
            self.channels[record.id] = record

    def is_bus(self, record: Message) -> bool:
        channel = self.channels.get(record.channel_id)
        return channel is None or channel.message_encoding in BUS_ENCODINGS

    def note(self, record: Message) -> None:
        """Keep ``record`` if it is an image (the next bus message may elide its bytes)."""
        channel = self.channels.get(record.channel_id)
        if channel is not None and self._schemas.get(channel.schema_id) == IMAGE_SCHEMA:
            self._image = record

    def frames(self, record: Message) -> list[memoryview]:
        """The frames of the bus message ``record``, exactly as they were received.

        Raises
        ------
        MessageRejected
            The container is not well formed, or its elided image data is not right before it.
        """
        image, self._image = self._image, None
        if not elides(record.data):
            return unpack_frames(record.data)
        if image is None or (image.log_time, image.sequence) != (
            record.log_time,
            record.sequence,
        ):
            return unpack_frames(record.data)  # refused: the image data is not there
        try:
            data = CompressedImage.FromString(image.data).data
        except DecodeError as exc:
            raise MessageRejected(
                "corrupt", f"the image message holding this frame's data does not parse ({exc})"
            ) from exc
        return unpack_frames(record.data, elided=data)


@dataclass(frozen=True)
class LoggedMessage:
    """One stored bus message: when it was received and sent, its frames, and it decoded."""

    log_time_ns: int
    publish_time_ns: int
    frames: tuple[memoryview, ...]
    message: BusMessage


@dataclass(frozen=True)
class LogInfo:
    """Everything in a log but its messages.

    ``attachments`` holds the intact attachments only; ``damaged_attachments`` says, by name,
    what is wrong with each of the others (their checksum fails).
    """

    profile: str
    attachments: dict[str, bytes]
    metadata: dict[str, dict[str, str]]
    complete: bool  # as LogReader.complete: the footer was reached and nothing in the file is damaged
    damage: str | None  # what was damaged (where, and what was skipped) or lost before recovery
    damaged_attachments: dict[str, str] = field(default_factory=dict)
    mendable: bool = False  # as LogReader.mendable

    @property
    def session(self) -> dict[str, str]:
        """The session metadata written at the start (empty if absent)."""
        return self.metadata.get(SESSION_METADATA, {})

    @property
    def offset_ns(self) -> int:
        """What the recorder added to its monotonic times to make the log's (0: an older log).

        Raises
        ------
        SessionLogError
            The session metadata's offset is not an integer.
        """
        text = self.session.get(TIME_OFFSET_KEY, "0")
        try:
            return int(text)
        except ValueError:
            raise SessionLogError(
                f"session metadata {TIME_OFFSET_KEY} = {text!r}: expected an integer"
            ) from None

    def settings(self) -> Settings:
        """The settings the session ran with, from the settings attachment.

        Raises
        ------
        SessionLogError
            The log has no settings attachment, it is damaged, or it does not hold valid settings.
        """
        data = self.attachments.get(SETTINGS_ATTACHMENT)
        if SETTINGS_ATTACHMENT in self.damaged_attachments:
            raise SessionLogError(
                f"{self.damaged_attachments[SETTINGS_ATTACHMENT]}: the settings the session ran with "
                "cannot be trusted"
            )
        if data is None:
            raise SessionLogError(
                f"the log has no {SETTINGS_ATTACHMENT} attachment (the recorder writes it as the session "
                "starts: a log cut short before it holds no session)"
            )
        try:
            mapping = json.loads(data.decode("utf-8"))
        except (UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise SessionLogError(f"attachment {SETTINGS_ATTACHMENT} is not JSON ({exc})") from exc
        if not isinstance(mapping, dict):
            raise SessionLogError(f"attachment {SETTINGS_ATTACHMENT} is not a JSON object")
        return settings_from_mapping(migrated(mapping), source=f"attachment {SETTINGS_ATTACHMENT}")


@dataclass
class LogReader:
    """Reads a session log front to back, whether or not it was closed cleanly.

    Uses mcap's non-seeking :class:`~mcap.stream_reader.StreamReader` with CRC checks, so a
    log cut short by a crash or a full disk reads up to its last complete record; reading
    stops there (:attr:`stopped`), :attr:`damage` says why, and :attr:`good_bytes` how far it
    got. Damage in a log with an intact summary skips the damaged chunks (:attr:`lost`) and
    reads on (:meth:`records`); :attr:`damage` says what and where, and :attr:`complete` is
    False. An attachment whose CRC-32 fails is damage too. A log ``teleop recover`` wrote has
    the parts lost from its source in :attr:`lost` and :attr:`damage` as well (from its
    recovery metadata, :mod:`teleop.session.logdamage`), though the file itself is complete.

    Parameters
    ----------
    path : str or Path
        The ``.mcap`` file.
    max_bytes : int
        Largest bus message accepted when decoding (as a subscriber's limit).
    """

    path: Path
    max_bytes: int = DEFAULT_MAX_BYTES
    damage: str | None = None
    complete: bool = False
    good_bytes: int = 0
    refused: Counter[str] = field(default_factory=Counter)
    lost: list[LostChunk] = field(default_factory=list)  # skipped for damage, or lost before recovery
    stopped: bool = False  # reading stopped at damage (nothing after it could be read)
    cut: bool = False  # ... because the file ends inside a record, or without its footer
    damaged: bool = False  # a record was damaged (not only cut short by the file's end)

    def __post_init__(self) -> None:
        self.path = Path(self.path)

    def records(self, *, emit_chunks: bool = False) -> Iterator[McapRecord]:
        """Every readable record up to the footer (chunks opened unless asked).

        At a damaged record, reading goes on at the next record the file's summary indexes
        (a chunk, attachment or metadata record) when the summary and footer are intact; the
        chunks, attachments and metadata records skipped are in :attr:`lost` (the latter holding
        no messages), and the summary's schemas and channels are
        yielded again before reading on (a skipped chunk may have held the first of them).
        Without an intact summary (a log cut short) reading stops at the damage.
        An attachment whose CRC-32 fails is yielded as a
        :class:`~teleop.session.logdamage.DamagedAttachment`. :attr:`damage` says what was
        damaged and where, and what was lost before a recovery; :attr:`complete` is True only
        when the footer was reached and nothing in the file is damaged. The parts lost before
        a recovery are in :attr:`lost` before the first message is yielded (the recovery
        metadata, at the file's end, is read first through the summary when it is intact).

        Raises
        ------
        SessionLogError
            The file cannot be opened, or does not start like an MCAP file.
        """
        self.damage, self.complete, self.good_bytes, self.stopped = None, False, 0, False
        self.cut = self.damaged = False
        self.lost.clear()
        try:
            file = self.path.open("rb")
        except OSError as exc:
            raise SessionLogError(
                f"cannot read session log {self.path}: {exc.strerror or exc}"
            ) from exc
        with file:
            if file.read(len(_MAGIC)) != _MAGIC:
                raise SessionLogError(
                    f"{self.path} is not an MCAP session log (no MCAP magic at the start)"
                )
            # No complete record is longer than the file: a larger length field is damage.
            size = self.path.stat().st_size
            damages: list[str] = []  # in this file
            summary = self._summary(file)
            for metadata in recovery_metadata(file, summary, size):
                self._take_losses(metadata, damages)
            file.seek(0)
            skip_magic = False
            resumed_at = -1  # where reading last went on after damage
            last_ns, pending = 0, None  # the latest message's log time; a skip not yet followed by one
            while True:
                stream = StreamReader(
                    file,
                    skip_magic=skip_magic,
                    emit_chunks=emit_chunks,
                    validate_crcs=True,
                    record_size_limit=max(size, 1),
                ).records
                while True:
                    try:
                        record = next(stream)
                    except StopIteration:  # the footer and the closing magic were read
                        self.complete, self.good_bytes = not damages, file.tell()
                        self._say(damages)
                        return
                    except Exception as exc:  # any parse failure: the bytes from here are unusable
                        failure = exc
                        break
                    # Records inside a chunk come once the whole chunk has been read.
                    self.good_bytes = file.tell()
                    if isinstance(record, Message):
                        last_ns = record.log_time
                        if pending is not None:  # the messages lost lie before this one
                            self.lost[pending] = replace(self.lost[pending], end_ns=last_ns)
                            pending = None
                    elif isinstance(record, Metadata) and record.name == SESSION_METADATA:
                        check_format(self.path, record.metadata, FORMAT_VERSION)
                    elif isinstance(record, Metadata) and record.name == RECOVERY_METADATA:
                        self._take_losses(record.metadata, damages)  # unless the summary gave them
                    elif isinstance(record, Attachment):
                        record = check_attachment(file, record, self.good_bytes)
                        if isinstance(record, DamagedAttachment):
                            damages.append(str(record))
                            self.damaged = True
                            self._say(damages)
                            log.warning("%s: %s", self.path, record)
                    yield record
                # Past the last resume too: a damaged record there reads nothing, and good_bytes stays put.
                damaged_at = max(self.good_bytes, resumed_at, len(_MAGIC))
                what = describe(
                    failure, file, damaged_at, size, self.good_bytes,
                    None if summary is None else "the file has its footer",
                )
                if summary is not None:
                    resume = self._resume_at(summary, damaged_at)
                    if resume is not None:
                        lost, skipped = skipped_in_summary(summary, damaged_at, resume)
                        self.lost += lost
                        what += skipped
                else:
                    resume, skipped = self._read_on(file, damaged_at, size, last_ns)
                    if resume is not None:
                        if what.startswith("the file ends inside"):  # an intact chunk follows: damage
                            what = describe(
                                failure, file, damaged_at, size, self.good_bytes, "an intact chunk follows"
                            )
                        what += skipped
                        skip = self.lost[-1] if self.lost else None  # its end: the next message's time
                        if skip and not skip.lost_in and skip.start_byte == damaged_at and skip.holds_messages:
                            pending = len(self.lost) - 1
                damages.append(what)
                self._say(damages)
                self.damaged = self.damaged or not what.startswith("the file ends")
                if resume is None:
                    self.stopped, self.cut = True, what.startswith("the file ends")
                    log.warning("%s: stopped reading at byte %d: %s", self.path, self.good_bytes, what)
                    return
                log.warning("%s: %s", self.path, what)
                if summary is not None:
                    yield from summary.schemas.values()
                    yield from summary.channels.values()
                file.seek(resume)
                resumed_at, skip_magic = resume, True

    @property
    def mendable(self) -> bool:
        """Whether ``teleop recover`` makes a whole file of more of it (cut short, or parts skipped)."""
        return self.stopped or self.cut or any(not c.lost_in and c.holds_messages for c in self.lost)

    def _say(self, damages: list[str]) -> None:
        """Set :attr:`damage`: the parts lost before recovery, then ``damages`` (this file's)."""
        said = [str(c) for c in self.lost if c.lost_in] + damages
        self.damage = "; ".join(said) or None

    def _take_losses(self, metadata: dict[str, str], damages: list[str]) -> None:
        """Add the parts the recovery metadata ``metadata`` lists as lost to :attr:`lost` (once)."""
        for chunk in recorded_losses(metadata, self.path):
            if chunk not in self.lost:
                self.lost.append(chunk)
        self._say(damages)

    def _summary(self, file: Any) -> Summary | None:
        """The file's summary (chunk indexes, schemas, channels), if it and the footer are intact."""
        try:
            file.seek(0)  # the reader checks the magic where the file stands
            summary = SeekingReader(
                file, validate_crcs=True, record_size_limit=max(self.path.stat().st_size, 1)
            ).get_summary()
        except Exception:  # no footer (cut short) or a damaged summary: nothing to go on with
            return None
        if summary is None or not summary.chunk_indexes:
            return None
        return summary

    @staticmethod
    def _resume_at(summary: Summary | None, damaged_at: int) -> int | None:
        """The first record the summary indexes after byte ``damaged_at`` (None: none)."""
        if summary is None:
            return None
        starts = [c.chunk_start_offset for c in summary.chunk_indexes]
        starts += [a.offset for a in summary.attachment_indexes]
        starts += [m.offset for m in summary.metadata_indexes]
        later = [s for s in starts if s > damaged_at]
        return min(later, default=None)

    def _read_on(self, file: Any, start: int, size: int, last_ns: int) -> tuple[int | None, str]:
        """Where to read on after the damaged record at byte ``start`` of a log without summary
        (None: nowhere), and what is skipped, as text; a skipped chunk, attachment, metadata record or
        region goes in :attr:`lost`."""
        head = record_head(file, start)
        if head is not None and head[0] in OPCODES and start + 9 + head[1] <= size:
            end = start + 9 + head[1]
            after = record_head(file, end)  # the record after it must look like one
            if end == size or (after is not None and after[0] in OPCODES and after[1] <= size):
                kind, named = Opcode(head[0]).name.lower(), record_name(file, start, head[0])
                lost = f": {kind}{named} lost"
                if head[0] in (Opcode.CHUNK, Opcode.MESSAGE):
                    self.lost.append(LostChunk(start, end, last_ns, UNKNOWN_NS, kind))
                    lost = ": the messages in it lost"
                elif head[0] in (Opcode.ATTACHMENT, Opcode.METADATA):  # holds no messages
                    self.lost.append(LostChunk.record(start, end, kind, named))
                return end, f"; skipped it (bytes {start} to {end}{lost}) and read on"
        found = next_chunk(file, start + 1, size)
        if found is None:
            return None, ""
        self.lost.append(LostChunk(start, found, last_ns, UNKNOWN_NS, "unreadable part"))
        return found, (
            f"; skipped bytes {start} to {found} (unreadable: whatever they held is lost) "
            "and read on at the next intact chunk"
        )

    def info(self) -> LogInfo:
        """Profile, attachments and metadata, and whether the log is whole.

        One pass that opens the chunks, so their checksums and compression are checked and
        :attr:`LogInfo.damage` includes damage inside them (and in attachments).
        """
        profile, attachments, metadata, damaged = "", {}, {}, {}
        for record in self.records():
            if isinstance(record, Header):
                profile = record.profile
            elif isinstance(record, DamagedAttachment):  # kept out of attachments: none may use it unawares
                damaged[record.name] = str(record)
                attachments.pop(record.name, None)
            elif isinstance(record, Attachment):
                attachments[record.name] = bytes(record.data)
                damaged.pop(record.name, None)
            elif isinstance(record, Metadata):
                metadata[record.name] = dict(record.metadata)
        return LogInfo(profile, attachments, metadata, self.complete, self.damage, damaged, self.mendable)

    def messages(self, topics: Iterable[str] | None = None) -> Iterator[LoggedMessage]:
        """Stored bus messages, decoded and checked, in the order they were received.

        ``topics``: topic prefixes to keep (``None``: all); Foxglove channels are never
        yielded. Frames are exactly as received (elided image data put back). A stored
        message that does not decode is logged, counted in :attr:`refused` by reason and
        skipped.
        """
        prefixes = None if topics is None else tuple(topics)
        stored = StoredFrames()
        for record in self.records():
            if isinstance(record, Schema | Channel):
                stored.add(record)
                continue
            if not isinstance(record, Message):
                continue
            if not stored.is_bus(record):
                stored.note(record)
                continue
            channel = stored.channels.get(record.channel_id)
            topic = None if channel is None else channel.topic
            if prefixes is not None and (topic is None or not topic.startswith(prefixes)):
                continue
            try:
                frames = stored.frames(record)
                message = decode(frames, max_bytes=self.max_bytes)
                if message.topic != topic:
                    raise MessageRejected(
                        "bad_header", f"message topic {message.topic!r} stored on channel {topic!r}"
                    )
            except MessageRejected as exc:
                self.refused[exc.reason] += 1
                log.warning(
                    "%s: skipped a stored message (channel %d, log time %d ns): %s",
                    self.path, record.channel_id, record.log_time, exc,
                )
                continue
            yield LoggedMessage(record.log_time, record.publish_time, tuple(frames), message)

