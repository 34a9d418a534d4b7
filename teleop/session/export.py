"""Export: the grasps of a session log as grasp records (``.grasp``), for training and evaluation.

A grasp runs from a ``grasp_event`` *start* to the *end* with the same ``grasp_id`` from the
same publisher (``source``: the robot node's; the estimator's forwarded ends do not count). It
holds the ``frame``, ``force`` and ``width`` messages that name its ``grasp_id``, and those that
name none (publishers that do not tag, as in the first session logs) but arrive (in receive order)
while it is the only grasp open and were captured at or after its start (``t_capture_s``: a
frame's capture time, a force or width batch's last sample). The robot node tags what it captures
from a grasp's start on and leaves what it captured before untagged (``teleop/node.py``), so an
untagged message captured before the start is not the grasp's (a camera that delivers late): it
is dropped and counted (:attr:`GraspExport.dropped`). No margin before the start is kept: the
estimator's no-contact reference is the frames before the contact onset, which the gripper
reaches after the start. Each keeps its capture times: frame times are the messages' ``t_capture_s``; force and width
samples are the messages' ``t_s``/``value`` arrays, concatenated in receive order. Frames
stay the bytes the camera produced (``jpeg``/``png``); ``raw`` frames are stored as
lossless PNG. Events ``grasp_start``/``grasp_end`` are the two grasp events' capture times,
``grasp_done`` (:data:`~teleop.record.GRASP_DONE_EVENT`) the *loading_end* marker's
when the robot sent one, and ``stopped_by_watchdog``/``stopped_by_device`` the ``robot_notice``
that ended the grasp, if one did (:mod:`teleop.session.export_notes`).

Records travel
--------------
The sensors come from the settings stored in the log (or those given). Each sensor's calibration
file goes inside every record (``GraspRecord.calibration_files``, record format version 3): from
the log's ``calibration/<finger>/<file>`` attachment, else from the file the sensor names when it
exists on this machine (given settings look at that file first). So does the gripper
(``record.gripper``: the finger stiffness, closing speed and target force the session ran with).
An exported record depends on no file outside it: a folder of them can be moved or shared. An
attachment the records would be built from (settings, calibration, catalogue) whose CRC-32 fails is
never used: the export is refused, naming it (given settings whose sensor's file is on this machine
take that file instead).

Names
-----
``<log stem>_<session id>_<grasp id>.grasp``: the session id is the session's start time from the
log's metadata (``20250101T120000.123Z``; a log without it: ``log-`` and 8 hex digits of a hash of
its first MiB), so two sessions whose grasps have the same ids never share a name, and exporting
one log again gives the same names. :func:`export_session` refuses to replace an existing file
unless asked (``overwrite``), and writes nothing under a final name before every record of the
log is written (records are written under hidden names and renamed at the end). One session
exported from two logs (a log cut short, then the log ``teleop recover`` made of it) would hold
each grasp twice under two names: a record in the folder of the same session id and grasp id
under another log's name is refused as well, or with ``overwrite`` replaced (removed once the new
records are in; :mod:`teleop.session.export_names`).

Labels
------
A grasp is labelled by the last ``label`` message the log holds for its ``grasp_id`` (written at
capture by the operator's console, or after the fact by ``teleop label``): its object, its modulus
(nil: the catalogue's modulus of that object, source ``catalogue``), source and detail; material
and shape come from the catalogue when the object is in it, else from the catalogues ``teleop
label`` took labels from (attached as ``label_catalogue-<n>``, :mod:`teleop.session.label`). A
grasp without a ``label`` message, whose start event names its object (simulated sessions), is labelled from the catalogue stored in
the log (or the one given), source ``catalogue``. Otherwise the record has no label. A record
exported without a modulus says why (:attr:`GraspExport.unlabelled`).

Provenance: source ``simulated`` or ``hardware`` as the session says, ``extra["session"]`` the
log's path (for reference only), ``extra["session_id"]`` the session id. Style ``operator`` for a
leader-follower grasp (:meth:`~teleop.bus.messages.RobotStateBody.followed_grasp`, as the
estimator service marks one live), else ``script``.

Refused messages
----------------
A stored message the reader refuses (corrupt, an unknown wire version: :attr:`LogReader.refused`)
is counted by reason (:attr:`SessionExport.refused`). One received while grasps were open may have
been theirs: their records are still written, with the count (:attr:`GraspExport.refused`,
``extra["refused_messages"]``), and the export is not complete.
"""

from __future__ import annotations

import contextlib
import dataclasses
import hashlib
import logging
from collections.abc import Iterator
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path

from teleop.bus.pubsub import DEFAULT_MAX_BYTES
from teleop.bus.wire import Message
from teleop.catalogue import ObjectSpec
from teleop.errors import SessionLogError
from teleop.progress import progress_bar
from teleop.record import (
    GRASP_DONE_EVENT,
    GraspRecord,
    Label,
    Provenance,
    software_version,
    write_record,
)
from teleop.session.export_calibration import carried_calibrations
from teleop.session.export_names import record_name, same_grasp_records
from teleop.session.export_notes import LogNotes, log_notes
from teleop.session.export_objects import catalogue_objects, label_catalogue_objects
from teleop.session.export_streams import OpenGrasp, concatenated_samples, frame_stream
from teleop.session.logdamage import intact_attachment
from teleop.session.logfile import SETTINGS_ATTACHMENT, LogInfo, LogReader
from teleop.settings import Settings

__all__ = ["GraspExport", "SessionExport", "export_session", "session_grasps", "session_id"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class GraspExport:
    """One grasp of a session: its record, or (falsy) the reason there is none.

    ``unlabelled``: for a record without a modulus to train on, why ("" when it has one).
    ``dropped``: untagged messages captured before the grasp's start, left out (module notes),
    by stream (``frame/left``, ``force``, ...).
    ``refused``: stored messages received while the grasp was open that the reader refused (module
    notes): its record may miss data.
    """

    grasp_id: str
    record: GraspRecord | None = None
    reason: str = ""
    path: Path | None = None  # where export_session wrote it
    unlabelled: str = ""
    dropped: dict[str, int] = field(default_factory=dict)
    refused: int = 0

    def __bool__(self) -> bool:
        return self.record is not None


class SessionExport(list[GraspExport]):
    """What :func:`export_session` did: one :class:`GraspExport` per grasp, in order, and about the log.

    Attributes
    ----------
    session_id : str
        The session's id in the record names (:func:`session_id`).
    complete : bool
        The log was read to its end and nothing of it is lost (False: cut short or damaged, or a
        recovered log whose source lost data, :attr:`damage` says where; or stored messages were
        refused, :attr:`refused`).
    damage : str or None
    refused : dict of str to int
        Stored messages the export read that the reader refused, by reason (module notes).
    read : int
        Grasp event, frame, force and width messages read (not refused).
    mendable : bool
        ``teleop recover`` would make a whole file of more of the log (:attr:`LogReader.mendable`): not
        so for a recovered log's earlier losses, nor a damaged attachment.
    stray_labels : list of str
        ``label`` messages naming a grasp id the log has no grasp for, one line each.
    replaced : list of Path
        Records of the same grasps exported from another log of the session, removed (``overwrite``).
    """

    def __init__(self, grasps: list[GraspExport], *, session_id: str, complete: bool, damage: str | None,
                 refused: dict[str, int], read: int, mendable: bool, stray_labels: list[str], replaced: list[Path]):
        super().__init__(grasps)
        self.session_id = session_id
        self.complete = complete
        self.damage = damage
        self.refused, self.read = refused, read
        self.mendable = mendable
        self.stray_labels = stray_labels
        self.replaced = replaced


class _Assembler:
    """Turns the message stream of a session into grasps."""

    def __init__(
        self,
        *,
        path: Path,
        settings: Settings,
        objects: dict[str, ObjectSpec],
        source: str,
        session_version: str,
        session: str,
        calibration_files: dict[str, bytes],
        reader: LogReader | None = None,
        label_objects: dict[str, ObjectSpec] | None = None,  # of the catalogues `teleop label` attached
        notes: LogNotes | None = None,  # labels, followed grasps, notices that ended grasps
    ):
        self.path = path
        self.settings = settings
        self.objects = objects
        self.label_objects = label_objects or {}
        self.source = source
        self.session_version = session_version
        self.session = session
        self.notes = notes or LogNotes()
        self.calibration_files = calibration_files
        self.reader = reader  # its damage and lost chunks, as read so far
        self.open: dict[str, OpenGrasp] = {}
        self.ended: set[str] = set()
        self.ended_by_others: dict[str, str] = {}  # open grasp -> who else ended it (the estimator, its node silent)
        self.unassigned = 0
        self.refused: dict[str, int] = {}  # open grasp -> refused messages received while it was open
        self.refused_total = 0  # the reader's count when last looked at

    def note_refused(self, total: int) -> None:
        """The reader has refused ``total`` messages so far: those since the last look were received
        while the open grasps were open, so may have been theirs."""
        for grasp_id in self.open:
            self.refused[grasp_id] += total - self.refused_total
        self.refused_total = total

    def _lost(self, start_ns: int | None, end_ns: int) -> str:
        """The lost chunks that may have held messages logged between ``start_ns`` (None: the
        start of the log) and ``end_ns``, as text ("" if none)."""
        lost = [] if self.reader is None else self.reader.lost
        return "; ".join(str(c) for c in lost if c.overlaps(start_ns or 0, end_ns))

    def feed(self, message: Message, log_time_ns: int | None = None) -> Iterator[GraspExport]:
        """The grasps ``message`` (logged at ``log_time_ns``: to tell what damage lost) ends."""
        body = message.fields
        if message.type == "grasp_event":
            grasp_id = body.grasp_id
            grasp = self.open.get(grasp_id)
            if body.event == "start":
                if grasp is not None:
                    yield GraspExport(grasp_id, reason="started again before it ended; the first start is dropped",
                                      dropped=dict(grasp.dropped), refused=self.refused[grasp_id])
                self.refused[grasp_id] = 0
                self.open[grasp_id] = OpenGrasp(grasp_id, message.t_capture_s, body.object_name,
                                                 message.source, start_log_ns=log_time_ns)
            elif grasp is None or message.source != grasp.source:
                # The estimator forwards ends, and ends a grasp a restarted node started again
                # before the robot ends the new one: only the start's publisher ends a grasp.
                if grasp is not None and body.event == "end":
                    self.ended_by_others[grasp_id] = message.source or "another publisher"
                if grasp is None and body.event == "end" and grasp_id not in self.ended:
                    lost = "" if log_time_ns is None else self._lost(None, log_time_ns)
                    if lost:  # its start was in a chunk damage lost
                        self.ended.add(grasp_id)
                        yield GraspExport(grasp_id, reason=f"its start event is lost: the log is damaged ({lost})")
                    else:
                        log.warning("%s: grasp %r ends but never started; ignored", self.path, grasp_id)
            elif body.event == "loading_end":  # the grasp goes on
                grasp.loading_end_s = message.t_capture_s
            else:
                self.ended.add(grasp_id)
                grasp, refused = self.open.pop(grasp_id), self.refused.pop(grasp_id)
                lost = "" if log_time_ns is None else self._lost(grasp.start_log_ns, log_time_ns)
                if lost:
                    yield GraspExport(grasp_id, reason=f"part of its data is lost: the log is damaged ({lost})",
                                      dropped=dict(grasp.dropped), refused=refused)
                    return
                yield dataclasses.replace(self.build(grasp, message.t_capture_s, refused), dropped=dict(grasp.dropped),
                                          refused=refused)
        elif message.type in ("frame", "force", "width"):
            grasp_id = body.grasp_id
            if grasp_id is None and len(self.open) == 1:
                grasp = next(iter(self.open.values()))
                if message.t_capture_s < grasp.start_s:  # captured before the grasp: not its (module notes)
                    grasp.dropped[message.topic] += 1
                    return
                grasp_id = grasp.grasp_id
            if grasp_id in self.open:
                self.open[grasp_id].add(message)
            else:
                self.unassigned += 1

    def unfinished(self) -> Iterator[GraspExport]:
        reader = self.reader
        for grasp_id, grasp in self.open.items():
            reason = "the log stops before the grasp's end event"
            if lost := self._lost(grasp.start_log_ns, 2**64):
                reason = f"its end event is lost: the log is damaged ({lost})"
            elif grasp_id in self.ended_by_others:  # the log goes on: its node restarted or went silent
                reason = (f"its publisher {grasp.source!r} never ended it (the {self.ended_by_others[grasp_id]} "
                          "did: the robot node restarted or went silent during the grasp)")
            elif reader is not None and reader.stopped and reader.damage:
                reason = f"the log stops at damage before the grasp's end event ({reader.damage})"
            yield GraspExport(grasp_id, reason=reason, dropped=dict(grasp.dropped), refused=self.refused[grasp_id])
        self.open.clear()
        self.refused.clear()

    def build(self, grasp: OpenGrasp, end_s: float, refused: int = 0) -> GraspExport:
        gid = grasp.grasp_id
        if not grasp.frames:
            return GraspExport(gid, reason="no tactile frames during the grasp")
        if not grasp.force or not grasp.width:
            return GraspExport(gid, reason=f"no {'force' if not grasp.force else 'width'} samples during the grasp")
        fingers = {s.finger for s in self.settings.sensors}
        streams = []
        for finger, frames in sorted(grasp.frames.items()):
            if finger not in fingers:
                return GraspExport(gid, reason=f"frames from finger {finger!r}, which the settings have no sensor on")
            stream = frame_stream(finger, frames)
            if isinstance(stream, str):
                return GraspExport(gid, reason=stream)
            streams.append(stream)
        label, unlabelled = self.label(gid, grasp.object_name)
        record = GraspRecord(
            sensors=self.settings.sensors,
            gripper=self.settings.gripper,
            frames=tuple(streams),
            force_n=concatenated_samples(grasp.force),
            width_m=concatenated_samples(grasp.width),
            provenance=Provenance(
                source=self.source,
                software_version=self.session_version,
                model="session",
                created_utc=datetime.now(UTC).isoformat(),
                extra={
                    "session": str(self.path.resolve()),
                    "session_id": self.session,
                    "grasp_id": gid,
                    "exported_by": software_version(),
                    **({"refused_messages": refused} if refused else {}),
                },
                style="operator" if gid in self.notes.followed else "script",
            ),
            label=label,
            events={"grasp_start": grasp.start_s, "grasp_end": end_s,
                    **({} if grasp.loading_end_s is None else {GRASP_DONE_EVENT: grasp.loading_end_s}),
                    **self.stopped_by(grasp, end_s)},
            calibration_files=self.calibration_files,
        )
        return GraspExport(gid, record=record, unlabelled=unlabelled)

    def stopped_by(self, grasp: OpenGrasp, end_s: float) -> dict[str, float]:
        """``stopped_by_<event>``: when a robot notice ended the grasp (its first within the grasp)."""
        events = self.notes.stops.get(grasp.grasp_id, {})
        within = {event: [t for t in times if grasp.start_s <= t <= end_s] for event, times in events.items()}
        return {f"stopped_by_{event}": min(times) for event, times in within.items() if times}

    def label(self, grasp_id: str, object_name: str | None) -> tuple[Label | None, str]:
        """The grasp's label (module notes) and, when it has no modulus, why."""
        given = self.notes.labels.get(grasp_id)
        if given is None:
            if object_name is None:
                return None, (
                    "no label: the log names no object for this grasp "
                    "(attach one with `teleop label LOG --csv FILE`)"
                )
            obj = self.objects.get(object_name)
            if obj is None:
                return Label(object_name=object_name), (
                    f"object {object_name!r} is not in the catalogue, so it has no modulus "
                    "(give it one with `teleop label`, or export with --objects CATALOGUE)"
                )
            return Label(
                object_name=obj.name, modulus_pa=obj.modulus_pa, material=obj.material, shape=obj.shape
            ), ""
        name, modulus, source, detail = given.object_name, given.modulus_pa, given.source, given.detail
        # A label holds no material or shape: the log's catalogue (or --objects) has them, else the one
        # `teleop label --catalogue` took the label from.
        obj = self.objects.get(name) or self.label_objects.get(name)
        material, shape = (obj.material, obj.shape) if obj is not None else ("", "")
        if modulus is None:
            if obj is None:
                return Label(object_name=name, source=source, detail=detail), (
                    f"its label names object {name!r} without a modulus, and the catalogue has no "
                    "object of that name (label it with a modulus or a Shore hardness, or export "
                    "with --objects CATALOGUE)"
                )
            modulus, source = obj.modulus_pa, "catalogue"
        return Label(object_name=name, modulus_pa=float(modulus), material=material, shape=shape,
                     source=source, detail=detail), ""


def session_grasps(
    path: str | Path,
    *,
    settings: Settings | None = None,
    catalogue: str | Path | None = None,
    source: str | None = None,
    max_bytes: int = DEFAULT_MAX_BYTES,
) -> Iterator[GraspExport]:
    """Every grasp of a session log, in the order the grasps ended (unfinished ones last, falsy).

    Parameters
    ----------
    path : str or Path
        The session log.
    settings : Settings, optional
        Sensors of the records; default: the settings stored in the log.
    catalogue : str or Path, optional
        Object catalogue for labels; default: the one stored in the log (if any).
    source : {"simulated", "hardware"}, optional
        Provenance source; default: what the log's session metadata says.

    Raises
    ------
    SessionLogError
        The log cannot be read, holds no settings (and none were given), or does not say
        whether it is simulated or hardware (and ``source`` was not given), or an attachment
        the records would be built from is damaged.
    """
    reader = LogReader(Path(path), max_bytes=max_bytes)
    info = reader.info()
    yield from _grasps(reader, info, settings=settings, catalogue=catalogue, source=source)


def session_id(info: LogInfo, path: str | Path) -> str:
    """The id of the session in a log: its start time (UTC) from the session metadata,
    ``20250101T120000.123Z``; without it, ``log-`` and 8 hex digits of the SHA-256 of the log's
    first MiB."""
    start = info.session.get("start_utc")
    if start:
        try:
            when = datetime.fromisoformat(start).astimezone(UTC)
        except ValueError:
            log.warning("%s: session start_utc %r is not an ISO time", path, start)
        else:
            return f"{when:%Y%m%dT%H%M%S}.{when.microsecond // 1000:03d}Z"
    try:
        with Path(path).open("rb") as f:
            head = f.read(1 << 20)
    except OSError as exc:
        raise SessionLogError(f"cannot read session log {path}: {exc.strerror or exc}") from exc
    return f"log-{hashlib.sha256(head).hexdigest()[:8]}"


@dataclass
class _Found:
    """What reading a log's grasps learnt besides them, for :class:`SessionExport`."""

    stray_labels: list[str] = field(default_factory=list)
    read: int = 0  # grasp messages decoded


def _warn_other_sensors(path: Path, *, ran: Settings, given: Settings) -> None:
    """Warn when the given settings' sensors are not those the session ran with (its records would
    claim another sensor: another model, serial or optics is estimated differently)."""
    ran_by = {s.finger: s for s in ran.sensors}
    for sensor in given.sensors:
        other = ran_by.get(sensor.finger)
        keys = ("model", "optics", "serial")
        differ = [k for k in keys if other is not None and getattr(other, k) != getattr(sensor, k)]
        if differ:
            log.warning("%s: the session ran finger %r with %s; the given settings say %s: its records will "
                        "carry the given sensor", path, sensor.finger,
                        ", ".join(f"{k} {getattr(other, k)!r}" for k in differ),
                        ", ".join(f"{k} {getattr(sensor, k)!r}" for k in differ))


def _grasps(reader: LogReader, info: LogInfo, *, settings: Settings | None, catalogue: str | Path | None,
            source: str | None, found: _Found | None = None) -> Iterator[GraspExport]:
    path = reader.path
    if not info.session and not info.complete:  # the metadata precedes every message
        raise SessionLogError(
            f"{path} is cut short before its session metadata ({info.damage}): no grasp in it "
            "can be read"
        )
    given = settings is not None
    if not given and intact_attachment(info, SETTINGS_ATTACHMENT, log=path, instead="pass --settings, the settings "
                                       "TOML the session ran with") is None:
        raise SessionLogError(f"{path}: the log has no {SETTINGS_ATTACHMENT} attachment: pass --settings, "
                              "the settings TOML the session ran with")
    if given and SETTINGS_ATTACHMENT in info.attachments:
        _warn_other_sensors(path, ran=info.settings(), given=settings)
    settings = settings if given else info.settings()
    source = source or info.session.get("source")
    if source not in ("simulated", "hardware"):
        raise SessionLogError(
            f"{path}: the session metadata gives source {source!r}; give the source "
            "(simulated or hardware) explicitly"
        )
    objects, label_objects = catalogue_objects(info, catalogue, log=path), label_catalogue_objects(info, log=path)
    settings, files = carried_calibrations(info, settings, path, disk_first=given)
    notes = log_notes(reader)
    found = found or _Found()
    assembler = _Assembler(
        path=path, settings=settings, objects=objects, label_objects=label_objects, source=source,
        session_version=info.session.get("software_version", "0+unknown"), session=session_id(info, path),
        calibration_files=files, reader=reader, notes=notes,
    )
    assembler.refused_total = sum(reader.refused.values())  # the notes' messages: no grasp's
    seen = set()
    for logged in reader.messages(("grasp_event", "frame", "force", "width")):
        found.read += 1
        assembler.note_refused(sum(reader.refused.values()))
        for grasp in assembler.feed(logged.message, logged.log_time_ns):
            seen.add(grasp.grasp_id)
            yield grasp
    assembler.note_refused(sum(reader.refused.values()))  # after the last message read
    for grasp in assembler.unfinished():
        seen.add(grasp.grasp_id)
        yield grasp
    if assembler.unassigned:
        log.info("%s: %d frame/force/width messages outside any grasp", path, assembler.unassigned)
    for grasp_id in sorted(set(notes.labels) - seen):
        line = (f"a label names grasp {grasp_id!r} (object {notes.labels[grasp_id].object_name!r}), "
                "but the log has no grasp of that id")
        log.warning("%s: %s", path, line)
        found.stray_labels.append(line)


def export_session(
    path: str | Path,
    out: str | Path,
    *,
    settings: Settings | None = None,
    catalogue: str | Path | None = None,
    source: str | None = None,
    overwrite: bool = False,
    progress: bool = False,
) -> SessionExport:
    """Write every complete grasp of a session log as ``<out>/<log>_<session id>_<grasp id>.grasp``.

    Takes the options of :func:`session_grasps`. Records are written under hidden names and
    renamed once every grasp of the log is done, so an error leaves no new record behind (nor
    ``out``, where this call created it).
    Returns one :class:`GraspExport` per grasp (``path`` set where a record was written,
    ``reason`` where none could be), with what it learnt about the log (:class:`SessionExport`).

    Parameters
    ----------
    overwrite : bool
        Replace records of those names already in ``out``, and remove the records of the same
        grasps exported from another log of the session (default: refuse).

    Raises
    ------
    SessionLogError
        As :func:`session_grasps`; ``out`` cannot be created or written; or a record's name is
        taken in ``out``, or ``out`` holds one of its grasps exported from another log, and
        ``overwrite`` is False (the message names the files).
    """
    path, out = Path(path), Path(out)
    reader = LogReader(path)  # read first: a log that cannot be read creates no folder
    info = reader.info()
    created = not out.exists()
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise SessionLogError(f"cannot create the export directory {out}: {exc.strerror or exc}") from exc
    sid = session_id(info, path)
    found = _Found()
    results: list[GraspExport] = []
    staged: list[tuple[Path, Path]] = []  # (hidden name, final name)
    replaced: list[Path] = []  # the same grasps' records under another log's name
    names: set[str] = set()
    records = sorted(out.glob("*.grasp"))  # as they were before this export: whose grasps it may repeat
    done = False
    grasps = _grasps(reader, info, settings=settings, catalogue=catalogue, source=source, found=found)
    try:
        for grasp in progress_bar(grasps, desc=f"export {path.name}", unit="grasp", enabled=progress):
            if grasp:
                name = record_name(path, sid, grasp.grasp_id, names)
                dest = out / name
                if dest.exists() and not overwrite:
                    raise SessionLogError(
                        f"{dest} already exists (grasp {grasp.grasp_id!r} of session {sid} of {path}, "
                        "exported before?): pass --overwrite to replace it, or export into another "
                        "folder; nothing was written"
                    )
                twins = same_grasp_records(records, path, name, sid, grasp.grasp_id)
                if twins and not overwrite:
                    other, origin = twins[0]
                    raise SessionLogError(
                        f"{other} holds grasp {grasp.grasp_id!r} of session {sid} already (exported from "
                        f"{origin}); {path} would write it again as {dest}, and a dataset would count it "
                        "twice: pass --overwrite to replace it, or export into another folder; nothing "
                        "was written"
                    )
                replaced += [other for other, _ in twins]
                hidden = write_record(grasp.record, out / f".{name}.exporting")
                staged.append((hidden, dest))
                grasp = dataclasses.replace(grasp, path=dest)
                if grasp.unlabelled:
                    log.info("%s: grasp %r has no modulus: %s", path, grasp.grasp_id, grasp.unlabelled)
            else:
                log.warning("%s: grasp %r not exported: %s", path, grasp.grasp_id, grasp.reason)
            for topic, count in grasp.dropped.items():
                log.info("%s: grasp %r: dropped %d untagged %s message(s) captured before its start",
                            path, grasp.grasp_id, count, topic)
            results.append(grasp)
        for hidden, dest in staged:
            hidden.replace(dest)
        for other in replaced:
            other.unlink(missing_ok=True)
        done = True
    except OSError as exc:
        raise SessionLogError(f"cannot write the records of {path} into {out}: {exc.strerror or exc}") from exc
    finally:
        for hidden, _ in staged:
            hidden.unlink(missing_ok=True)
        if created and not done:
            # The log's settings and grasps are checked as they are read, after out is made.
            with contextlib.suppress(OSError):
                out.rmdir()
    # info() checks every chunk and attachment: damage anywhere counts, and so do losses before a recovery.
    refused = dict(reader.refused)
    complete = info.complete and info.damage is None and not refused
    return SessionExport(results, session_id=sid, complete=complete, damage=info.damage, refused=refused,
                         read=found.read, mendable=info.mendable, stray_labels=found.stray_labels,
                         replaced=replaced)
