"""Labelling a session log after the fact: ``label`` messages for its grasps, from a CSV.

A session recorded on a rig knows which grasps happened but not always what was grasped. A
person writes a CSV with one row per grasp (``grasp_id``, ``object``, and optionally
``modulus_pa``, ``shore_a`` or ``shore_00``, ``source``, ``detail``; :func:`read_label_csv`,
:func:`teleop.labels.label_from_fields` for what each column means) and :func:`label_session`
writes one ``label`` bus message per row into the log:

* the log is copied record by record into a new file next to it (``<log>.partial``): its
  header, schemas, channels, every message (data, log time, publish time and sequence byte for
  byte, the Foxglove forms included), attachments and metadata, with the labels added on the
  ``label`` topic (each after its Foxglove JSON form, as the recorder writes them), and a
  ``labels`` metadata record saying what was added from where. A catalogue the labels came from
  other than the log's own (``--catalogue``, or the shipped one for a log without) is attached
  as ``label_catalogue-<n>.toml`` (or ``.csv``), unless the log holds it already: a label names
  its object and modulus, and ``teleop export`` takes the object's material and shape from there. The new file is flushed to disk
  and moved over the original (``os.replace``: atomic on one file system), so the log is either
  the old one or the new one, never half of each; no backup is kept. The log's lock and the
  ``.partial``'s are held meanwhile (:func:`~teleop.session.recordfile.rewriting`): a log a recorder
  is still writing, or another ``teleop label`` or ``teleop recover --out`` is rewriting, is refused.
* Each label is stamped just after its grasp: log time 1 ns after the grasp's last
  ``grasp_event`` (its end) or after the last label the log already holds for it, whichever is
  later, and the same time as its send time (``publish_time``; the header's ``t_send_ns`` is
  that less the log's clock offset, :attr:`~teleop.session.logfile.LogInfo.offset_ns`);
  ``t_capture_s`` is the grasp event's. It is sent as source :data:`LABEL_SOURCE_NAME`, its
  ``seq`` following that source's earlier labels in the log. It is written right after that
  grasp_event or label, so the file stays in receive order (a replay sends each label just
  after its grasp) and readers that take the last label per grasp (in file or log-time order)
  take the newest: labelling a grasp again replaces its label.

A grasp never ended (no ``end`` event from the publisher of its start: a log ``teleop recover``
salvaged, a robot stopped mid-grasp) is labelled all the same but named in
:attr:`LabelReport.unended`: ``teleop export`` skips it, so its label is not used.

Refused, with nothing written: a log cut short or with a record that cannot be read (``teleop
recover`` first, whose copy lists the record as lost: the labelled copy would leave it out and read
as whole; an attachment whose CRC-32 fails is not refused, as it is copied as stored, its damage
kept), an unknown column, and
CSV rows naming a grasp the log does not hold (the error lists the log's grasps), a grasp another
row names too, an object that is neither in the catalogue nor given a modulus or Shore hardness,
or a bad number: every such row is named in one error, so that a long CSV is mended in one go.
"""

from __future__ import annotations

import csv
import dataclasses
import json
import os
import re
import tempfile
import time
from collections.abc import Collection
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from mcap.records import Attachment, Channel, Header, Message, Metadata, Schema
from mcap.writer import CompressionType, Writer

from teleop.bus.wire import Message as BusMessage
from teleop.bus.wire import encode, make_message
from teleop.catalogue import default_catalogue_path, load_catalogue
from teleop.errors import SessionLogError, SettingsError
from teleop.labels import LabelError, ObjectLabel, label_from_fields
from teleop.record import software_version
from teleop.session.foxglove import foxglove_messages
from teleop.session.logdamage import DamagedAttachment, DamageKeepingWriter, intact_attachment
from teleop.session.logfile import (
    CATALOGUE_ATTACHMENTS,
    CHUNK_BYTES,
    MESSAGE_ENCODING,
    SCHEMA_ENCODING,
    LogInfo,
    LogReader,
    schema_data,
)
from teleop.session.logframes import pack_frames
from teleop.session.recordfile import rewriting

__all__ = [
    "CSV_COLUMNS",
    "LABELS_METADATA",
    "LABEL_CATALOGUE",
    "LABEL_SOURCE_NAME",
    "GraspLabel",
    "LabelReport",
    "label_catalogues",
    "label_session",
    "read_label_csv",
]

LABEL_SOURCE_NAME = "teleop label"  # the header source of labels written after the fact
LABELS_METADATA = "labels"
LABEL_CATALOGUE = "label_catalogue"  # attachments label_catalogue-<n>.toml/.csv: catalogues labels came from
REQUIRED_COLUMNS = ("grasp_id", "object")
CSV_COLUMNS = (*REQUIRED_COLUMNS, "modulus_pa", "shore_a", "shore_00", "source", "detail")
_LISTED_GRASPS = 30  # grasp ids named in an error before "..."
_LISTED_ROWS = 20  # refused rows named in an error before "... and N more"


@dataclass(frozen=True)
class GraspLabel:
    """One CSV row: the grasp and its label, and the row it came from (``file:line``)."""

    grasp_id: str
    label: ObjectLabel
    where: str


@dataclass
class LabelReport:
    """What :func:`label_session` wrote."""

    log: str
    csv: str
    labels: list[dict[str, Any]] = field(default_factory=list)  # each label's body, as written
    relabelled: list[str] = field(default_factory=list)  # grasps that had a label before
    unended: list[str] = field(default_factory=list)  # labelled grasps without an end: export skips them
    messages: int = 0  # messages of the original kept (bus and Foxglove)
    grasps: int = 0  # grasps in the log

    def as_dict(self) -> dict[str, Any]:
        return dict(self.__dict__)


def label_catalogues(attachments: dict[str, bytes]) -> list[str]:
    """The names of the catalogues ``teleop label`` attached to a log, oldest first."""
    numbered = ((re.fullmatch(rf"{LABEL_CATALOGUE}-(\d+)\.(toml|csv)", name), name) for name in attachments)
    return [name for _, name in sorted((int(match[1]), name) for match, name in numbered if match)]


def _catalogue_objects(catalogue: str | Path | None, attachments: dict[str, bytes]
                       ) -> tuple[tuple, str, tuple[str, bytes] | None]:
    """The catalogue's entries, its name for errors, and the attachment to add: ``catalogue``, else the
    log's, else the shipped. A label keeps only the object's name and modulus, so a catalogue other
    than the log's goes into the log too: export takes the object's material and shape from it."""
    if catalogue is None:
        for name in CATALOGUE_ATTACHMENTS:
            if name in attachments:
                with tempfile.TemporaryDirectory() as folder:
                    path = Path(folder) / name
                    path.write_bytes(attachments[name])
                    try:
                        objects = load_catalogue(path, recorded=True)
                    except SettingsError as exc:
                        raise SettingsError(
                            f"the log's {name} attachment: {str(exc).replace(str(path), name)}"
                        ) from None
                return objects, f"the log's {name}", None
    path = default_catalogue_path() if catalogue is None else Path(catalogue)
    objects = load_catalogue(path)
    data = path.read_bytes()
    earlier = label_catalogues(attachments)
    if any(attachments[name] == data for name in earlier):
        return objects, str(path), None
    return objects, str(path), (f"{LABEL_CATALOGUE}-{len(earlier) + 1}{path.suffix.lower()}", data)


def read_label_csv(path: str | Path, catalogue: Any = (), *, where: str = "the catalogue",
                   grasps: Collection[str] | None = None, log: str = "the log") -> list[GraspLabel]:
    """The rows of a label CSV, each made a label (:func:`teleop.labels.label_from_fields`).

    Columns: ``grasp_id`` and ``object`` (required), ``modulus_pa``, ``shore_a``, ``shore_00``,
    ``source``, ``detail`` (optional); a header row first; blank rows skipped; one row per grasp.
    ``grasps``: the grasp ids of ``log`` a row may name (None: any).

    Raises
    ------
    LabelError
        The file cannot be read, has no rows, lacks a required column or has an unknown one, or
        rows do not make labels or name a grasp an earlier row names (every such row is named,
        by file and line).
    """
    path = Path(path)
    try:
        with path.open(newline="", encoding="utf-8-sig") as fh:
            reader = csv.DictReader(fh)
            columns = [c.strip() for c in (reader.fieldnames or [])]
            rows = [(reader.line_num, row) for row in reader]
    except OSError as exc:
        raise LabelError(f"cannot read the label CSV {path}: {exc.strerror or exc}") from exc
    except (UnicodeDecodeError, csv.Error) as exc:
        raise LabelError(f"{path}: not a readable UTF-8 CSV file ({exc})") from exc
    missing = [c for c in REQUIRED_COLUMNS if c not in columns]
    if missing:
        raise LabelError(
            f"{path}: expected a header row with columns {', '.join(REQUIRED_COLUMNS)} (and optionally "
            f"{', '.join(CSV_COLUMNS[2:])}); missing {', '.join(missing)}"
        )
    unknown = [c for c in columns if c not in CSV_COLUMNS]
    if unknown:
        raise LabelError(f"{path}: unknown column(s) {', '.join(map(repr, unknown))}; the columns are {', '.join(CSV_COLUMNS)}")
    out, errors, stray = [], [], False
    first_line: dict[str, int] = {}  # grasp id -> the row that named it first
    for line, row in rows:
        cells = {(k or "").strip(): (v or "").strip() for k, v in row.items() if isinstance(k, str)}
        if None in row:
            errors.append(f"{path}:{line}: more cells than the header has columns")
            continue
        if not any(cells.values()):
            continue
        where_row = f"{path}:{line}"
        grasp_id = cells.get("grasp_id", "")
        if not grasp_id:
            errors.append(f"{where_row}: the grasp_id is empty")
            continue
        if grasps is not None and grasp_id not in grasps:
            errors.append(f"{where_row}: grasp {grasp_id!r} is not in {log}")
            stray = True
            continue
        # Two labels for one grasp: which one is meant is the writer's to say, not the file order's.
        if grasp_id in first_line:
            errors.append(f"{where_row}: grasp {grasp_id!r} is also on line {first_line[grasp_id]}; "
                          "give each grasp one row")
            continue
        first_line[grasp_id] = line
        try:
            label = label_from_fields(
                cells.get("object", ""),
                catalogue=catalogue,
                modulus_pa=cells.get("modulus_pa"),
                shore_a=cells.get("shore_a"),
                shore_00=cells.get("shore_00"),
                source=cells.get("source"),
                detail=cells.get("detail", ""),
                where=where,
            )
        except LabelError as exc:
            errors.append(f"{where_row} (grasp {grasp_id}): {exc}")
            continue
        out.append(GraspLabel(grasp_id, label, where_row))
    if errors:
        listing = ("; " if len(errors) == 1 else "\n") + _grasp_list(grasps) if stray else ""
        raise LabelError(_each_row(errors) + listing)
    if not out:
        raise LabelError(f"{path}: no label rows under the header")
    return out


_Anchor = tuple[str, int, int]  # a stored bus message: (topic, log time, sequence)


@dataclass
class _Grasp:
    log_time_ns: int = 0  # of its last grasp_event, then of its last label
    anchor: _Anchor = ("", 0, 0)  # that message: a new label is written right after it
    t_capture_s: float = 0.0
    labelled: bool = False
    started_by: str | None = None  # the publisher of its last start: only its end ends it (as export)
    ended: bool = False  # once: export then writes a record of this grasp id, which takes the label

    def saw(self, topic: str, log_time_ns: int, seq: int) -> None:
        if log_time_ns >= self.log_time_ns:  # equal times: the later in the file is the newer
            self.log_time_ns, self.anchor = log_time_ns, (topic, log_time_ns, seq % 2**32)


@dataclass(frozen=True)
class _Label:
    anchor: _Anchor
    log_time_ns: int
    message: BusMessage


def _survey(reader: LogReader) -> tuple[dict[str, _Grasp], int]:
    """The log's grasps (from their events and labels) and the next seq of our source's labels."""
    grasps: dict[str, _Grasp] = {}
    seq = 0
    for logged in reader.messages(topics=("grasp_event", "label")):
        message = logged.message
        grasp_id = message.fields.grasp_id
        if message.type == "grasp_event":
            grasp = grasps.setdefault(grasp_id, _Grasp())
            grasp.saw(message.topic, logged.log_time_ns, message.seq)
            grasp.t_capture_s = message.t_capture_s
            if message.fields.event == "start":
                grasp.started_by = message.source
            elif message.fields.event == "end" and message.source == grasp.started_by:
                grasp.ended = True
        elif message.type == "label" and grasp_id in grasps:
            grasp = grasps[grasp_id]
            grasp.saw(message.topic, logged.log_time_ns, message.seq)
            grasp.labelled = True
            if message.source == LABEL_SOURCE_NAME:
                seq = max(seq, message.seq + 1)
    if reader.mendable:
        raise SessionLogError(_cut_short(reader.path, reader.damage))
    return grasps, seq


def _cut_short(log: Path, damage: str | None) -> str:
    return (f"{log} is cut short or damaged ({damage}): make it a complete file first with "
            f"`teleop recover {log} --out FIXED.mcap`, then label FIXED.mcap")


def _kept_damage(reader: LogReader, info: LogInfo) -> str | None:
    """The damage the labelled copy keeps, as :attr:`LogReader.damage` says it: the parts lost before a
    recovery (chunks, attachment and metadata records, in the copied recovery metadata) and the
    attachments whose CRC-32 fails (copied as stored).
    A record skipped for damage (an attachment or metadata record whose length is garbled) is not
    kept: the copy would read as whole."""
    kept = [str(chunk) for chunk in reader.lost if chunk.lost_in] + list(info.damaged_attachments.values())
    return "; ".join(kept) or None


def _each_row(errors: list[str]) -> str:
    """One error, or every row's under a count (so that a long CSV is mended in one go)."""
    if len(errors) == 1:
        return errors[0]
    shown = errors[:_LISTED_ROWS]
    more = [f"... and {len(errors) - len(shown)} more"] if len(errors) > len(shown) else []
    return "\n  ".join([f"{len(errors)} rows are refused:", *shown, *more])


def _grasp_list(grasps: Collection[str]) -> str:
    names = list(grasps)
    if not names:
        return "the log holds no grasps"
    shown = ", ".join(names[:_LISTED_GRASPS])
    more = f", ... ({len(names)} in all)" if len(names) > _LISTED_GRASPS else ""
    return f"the log's grasps are {shown}{more}"


def label_session(
    log: str | Path,
    csv_path: str | Path,
    *,
    catalogue: str | Path | None = None,
) -> LabelReport:
    """Write the labels of ``csv_path`` into the session log ``log`` (module notes).

    ``catalogue``: the object catalogue for rows without a modulus; None: the catalogue attached
    to the log, else the shipped one.

    Raises
    ------
    SessionLogError
        The log cannot be read, is not a session log, is cut short or has a record that cannot be
        read (an attachment whose CRC-32 fails is copied as stored), is held by a recorder still
        writing it, or the new log cannot be written (the original is then left as it was).
    LabelError
        The CSV is bad, names a grasp not in the log, or an object without a modulus.
    SettingsError
        The catalogue cannot be read.
    """
    log = Path(log)
    # Held to the rename, the log read only once held: a recorder still writing it would lose all it
    # writes after, and of two rewrites at once the later would drop the other's labels.
    with rewriting(log, "wait until it has stopped, then label the log") as tmp:
        return _label_session(log, tmp, Path(csv_path), catalogue)


def _label_session(log: Path, tmp: Path, csv_path: Path, catalogue: str | Path | None) -> LabelReport:
    reader = LogReader(log)
    info = reader.info()
    if info.mendable:  # a damaged attachment is not: it is copied as it is, its damage kept
        raise SessionLogError(_cut_short(log, info.damage))
    if info.damage != _kept_damage(reader, info):
        raise SessionLogError(
            f"{log}: {info.damage}: the labelled copy would leave out what could not be read and read as "
            f"whole, erasing the loss, so the log is unchanged; `teleop recover {log} --out FIXED.mcap` "
            "copies what can be read and notes this damage in the copy's recovery metadata, then label FIXED.mcap"
        )
    for name in CATALOGUE_ATTACHMENTS if catalogue is None else ():  # the one the labels would check
        intact_attachment(info, name, log=log, instead="pass --objects CATALOGUE")
    objects, where, attachment = _catalogue_objects(catalogue, info.attachments)
    grasps, seq = _survey(reader)
    rows = read_label_csv(csv_path, objects, where=where, grasps=grasps, log=str(log))
    report = LabelReport(str(log), str(csv_path), grasps=len(grasps))
    labels = []
    for row in rows:
        grasp = grasps[row.grasp_id]
        if grasp.labelled:
            report.relabelled.append(row.grasp_id)
        if not grasp.ended:
            report.unended.append(row.grasp_id)
        log_time_ns = grasp.log_time_ns + 1
        message = make_message("label", t_capture_s=grasp.t_capture_s, **row.label.body(row.grasp_id))
        message = dataclasses.replace(message, source=LABEL_SOURCE_NAME, seq=seq,
                                      t_send_ns=log_time_ns - info.offset_ns)
        seq += 1
        labels.append(_Label(grasp.anchor, log_time_ns, message))
        report.labels.append(message.fields.as_dict())
    try:
        with tmp.open("wb") as file:
            writer = DamageKeepingWriter(file, chunk_size=CHUNK_BYTES, compression=CompressionType.ZSTD)
            report.messages = _copy_with_labels(reader, writer, labels, csv_path, info.offset_ns, attachment)
            file.flush()
            os.fsync(file.fileno())
        tmp.replace(log)
    except OSError as exc:  # rewriting() removes the partial copy
        raise SessionLogError(f"cannot write the labelled log next to {log}: {exc.strerror or exc}; "
                              "the log is unchanged") from exc
    return report


def _copy_with_labels(reader: LogReader, writer: Writer, labels: list[_Label], csv_path: Path,
                      offset_ns: int, attachment: tuple[str, bytes] | None) -> int:
    """Copy every record of ``reader``'s log into ``writer``, each label right after its anchor, and
    add ``attachment`` (name, data) if any; returns the messages copied. ``offset_ns``: the log's
    clock offset (its Foxglove timestamps')."""
    schemas: dict[int, int] = {}  # schema id in the log -> in the copy
    channels: dict[int, int] = {}  # channel id in the log -> in the copy
    topics: dict[int, str] = {}  # channel id in the log -> topic
    # What the copy registered, so that a label's schema or channel and the log's are one.
    copy_schemas: dict[tuple[str, str, bytes], int] = {}
    copy_channels: dict[tuple[str, str, int], int] = {}
    pending: dict[_Anchor, list[_Label]] = {}
    for label in labels:
        pending.setdefault(label.anchor, []).append(label)

    def schema(name: str, encoding: str, data: bytes) -> int:
        key = (name, encoding, bytes(data))
        if key not in copy_schemas:
            copy_schemas[key] = writer.register_schema(name, encoding, data)
        return copy_schemas[key]

    def channel(topic: str, encoding: str, schema_id: int, metadata: dict[str, str]) -> int:
        key = (topic, encoding, schema_id)
        if key not in copy_channels:
            copy_channels[key] = writer.register_channel(topic, encoding, schema_id, metadata)
        return copy_channels[key]

    def add_label(label: _Label) -> None:
        message, at, sequence = label.message, label.log_time_ns, label.message.seq % 2**32
        for item in foxglove_messages(message, offset_ns):
            target = channel(item.topic, item.message_encoding,
                             schema(item.schema_name, item.schema_encoding, item.schema_data), {})
            writer.add_message(target, log_time=at - item.age_ns, data=item.data, publish_time=at,
                               sequence=sequence)
        name = f"compliance-teleop/{message.type}"
        target = channel(message.topic, MESSAGE_ENCODING,
                         schema(name, SCHEMA_ENCODING, schema_data(message.type)), {"type": message.type})
        writer.add_message(target, log_time=at, data=pack_frames(encode(message)), publish_time=at,
                           sequence=sequence)

    copied = 0
    started = False
    for record in reader.records():
        if isinstance(record, Header):
            writer.start(record.profile, record.library)
            started = True
        elif not started:
            break
        elif isinstance(record, Schema) and record.id not in schemas:
            schemas[record.id] = schema(record.name, record.encoding, record.data)
        elif isinstance(record, Channel) and record.id not in channels:
            channels[record.id] = channel(record.topic, record.message_encoding,
                                          schemas.get(record.schema_id, 0), dict(record.metadata))
            topics[record.id] = record.topic
        elif isinstance(record, Message):
            if record.channel_id not in channels:
                continue  # no channel says what it is (never in a log the recorder wrote)
            writer.add_message(
                channels[record.channel_id],
                log_time=record.log_time,
                data=record.data,
                publish_time=record.publish_time,
                sequence=record.sequence,
            )
            copied += 1
            for label in pending.pop((topics[record.channel_id], record.log_time, record.sequence), ()):
                add_label(label)
        elif isinstance(record, DamagedAttachment):  # copied as stored: its damage stays found
            writer.add_damaged_attachment(record)
        elif isinstance(record, Attachment):
            writer.add_attachment(record.create_time, record.log_time, record.name, record.media_type, record.data)
        elif isinstance(record, Metadata):
            writer.add_metadata(record.name, dict(record.metadata))
    if attachment is not None:
        name, data = attachment
        now_ns = time.time_ns()  # a log time is wall time already (monotonic plus the log's offset)
        writer.add_attachment(now_ns, now_ns, name, "text/plain", data)
    if not started or reader.mendable:  # changed since it was read
        raise SessionLogError(
            f"{reader.path} could not be read to its end ({reader.damage or 'no header'}); the log is unchanged"
        )
    if pending:  # changed since it was surveyed
        raise SessionLogError(
            f"{reader.path} changed while it was labelled (the last event of grasp "
            f"{next(iter(pending.values()))[0].message.fields.grasp_id} is gone); the log is unchanged"
        )
    writer.add_metadata(
        LABELS_METADATA,
        {
            "labelled_utc": datetime.now(UTC).isoformat(),
            "software_version": software_version(),
            "csv": str(csv_path),
            "labels": json.dumps([label.message.fields.grasp_id for label in labels]),
        },
    )
    writer.finish()
    return copied
