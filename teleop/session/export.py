"""Export: the grasps of a session log as grasp records (``.grasp``), for training and evaluation.

A grasp runs from a ``grasp_event`` *start* to the *end* with the same ``grasp_id``. It
holds the ``frame``, ``force`` and ``width`` messages that name its ``grasp_id``, and
those that name none but arrive (in receive order) while it is the only grasp open. Each
keeps its capture times: frame times are the messages' ``t_capture_s``; force and width
samples are the messages' ``t_s``/``value`` arrays, concatenated in receive order. Frames
stay the bytes the camera produced (``jpeg``/``png``); ``raw`` frames are stored as
lossless PNG. Events ``grasp_start``/``grasp_end`` are the two grasp events' capture times,
and ``grasp_done`` (:data:`~teleop.record.GRASP_DONE_EVENT`) the *loading_end* marker's
when the robot sent one.

The sensors come from the settings stored in the log; a calibration file stored in the
log is written under ``<out>/calibration/<finger>/`` and the exported sensors point to it.
So does the gripper (``record.gripper``: the finger stiffness, closing speed and target force
the session ran with). When the start event names the object (simulated sessions), the record
is labelled from the catalogue stored in the log (or the one given); otherwise it has no label.
Provenance: source ``simulated`` or ``hardware`` as the session says, ``extra["session"]``
the log's path.
"""

from __future__ import annotations

import dataclasses
import logging
import re
import tempfile
from collections import defaultdict
from collections.abc import Iterator
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path

import cv2
import numpy as np
from tqdm import tqdm

from teleop.bus.pubsub import DEFAULT_MAX_BYTES
from teleop.bus.wire import Message
from teleop.catalogue import ObjectSpec, load_catalogue
from teleop.errors import SessionLogError
from teleop.record import (
    GRASP_DONE_EVENT,
    FrameStream,
    GraspRecord,
    Label,
    Provenance,
    Samples,
    software_version,
    write_record,
)
from teleop.session.logfile import LogInfo, LogReader
from teleop.settings import Settings

__all__ = ["GraspExport", "export_session", "session_grasps"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class GraspExport:
    """One grasp of a session: its record, or (falsy) the reason there is none."""

    grasp_id: str
    record: GraspRecord | None = None
    reason: str = ""
    path: Path | None = None  # where export_session wrote it

    def __bool__(self) -> bool:
        return self.record is not None


@dataclass
class _OpenGrasp:
    grasp_id: str
    start_s: float
    object_name: str | None
    frames: dict[str, list[tuple[float, str, np.ndarray]]] = field(
        default_factory=lambda: defaultdict(list)
    )
    force: list[tuple[np.ndarray, np.ndarray]] = field(default_factory=list)
    width: list[tuple[np.ndarray, np.ndarray]] = field(default_factory=list)
    loading_end_s: float | None = None

    def add(self, message: Message) -> None:
        body = message.body
        if message.type == "frame":
            data = body["data"] if body["encoding"] == "raw" else body["data"].tobytes()
            self.frames[body["finger"]].append((message.t_capture_s, body["encoding"], data))
        elif message.type == "force":
            self.force.append((body["t_s"], body["value_n"]))
        else:
            self.width.append((body["t_s"], body["value_m"]))


def _samples(parts: list[tuple[np.ndarray, np.ndarray]]) -> Samples:
    return Samples(np.concatenate([t for t, _ in parts]), np.concatenate([v for _, v in parts]))


def _frame_stream(
    finger: str, frames: list[tuple[float, str, np.ndarray | bytes]]
) -> FrameStream | str:
    """The frames of one finger as a FrameStream, or the reason they cannot be one."""
    t_s = [t for t, _, _ in frames]
    encodings = {encoding for _, encoding, _ in frames}
    if len(encodings) > 1:
        return (
            f"finger {finger!r} sent frames in several encodings ({', '.join(sorted(encodings))})"
        )
    encoding = encodings.pop()
    if encoding == "raw":
        data = [d for _, _, d in frames]
        if any(d.dtype != np.uint8 for d in data):
            return (
                f"finger {finger!r} sent 16-bit raw frames; a grasp record holds 8-bit BGR frames"
            )
        return FrameStream.from_frames(finger, t_s, data, encoding="png")
    encoded = [d for _, _, d in frames]
    first = cv2.imdecode(np.frombuffer(encoded[0], dtype=np.uint8), cv2.IMREAD_COLOR)
    if first is None:
        return f"finger {finger!r}: the first {encoding} frame does not decode"
    return FrameStream(
        finger=finger,
        t_s=np.asarray(t_s),
        encoded=tuple(encoded),
        encoding=encoding,
        shape=tuple(first.shape),
    )


def _load_objects(info: LogInfo, catalogue: str | Path | None) -> dict[str, ObjectSpec]:
    """Objects by name: from ``catalogue``, else from the catalogue stored in the log, else none."""
    if catalogue is not None:
        return {obj.name: obj for obj in load_catalogue(catalogue)}
    for name, data in info.attachments.items():
        if name in ("catalogue.toml", "catalogue.csv"):
            with tempfile.TemporaryDirectory() as tmp:
                path = Path(tmp) / name
                path.write_bytes(data)
                return {obj.name: obj for obj in load_catalogue(path)}
    return {}


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
    ):
        self.path = path
        self.settings = settings
        self.objects = objects
        self.source = source
        self.session_version = session_version
        self.open: dict[str, _OpenGrasp] = {}
        self.ended: set[str] = set()
        self.unassigned = 0

    def feed(self, message: Message) -> Iterator[GraspExport]:
        body = message.body
        if message.type == "grasp_event":
            grasp_id = body["grasp_id"]
            if body["event"] == "start":
                if grasp_id in self.open:
                    yield GraspExport(
                        grasp_id, reason="started again before it ended; the first start is dropped"
                    )
                self.open[grasp_id] = _OpenGrasp(grasp_id, message.t_capture_s, body["object_name"])
            elif body["event"] == "loading_end":  # the grasp goes on
                if grasp_id in self.open:
                    self.open[grasp_id].loading_end_s = message.t_capture_s
            elif grasp_id in self.open:
                self.ended.add(grasp_id)
                yield self.build(self.open.pop(grasp_id), message.t_capture_s)
            elif grasp_id not in self.ended:  # other nodes may announce an end again
                log.warning("%s: grasp %r ends but never started; ignored", self.path, grasp_id)
        elif message.type in ("frame", "force", "width"):
            grasp_id = body["grasp_id"]
            if grasp_id is None and len(self.open) == 1:
                grasp_id = next(iter(self.open))
            if grasp_id in self.open:
                self.open[grasp_id].add(message)
            else:
                self.unassigned += 1

    def unfinished(self) -> Iterator[GraspExport]:
        for grasp_id in self.open:
            yield GraspExport(grasp_id, reason="the log stops before the grasp's end event")
        self.open.clear()

    def build(self, grasp: _OpenGrasp, end_s: float) -> GraspExport:
        gid = grasp.grasp_id
        if not grasp.frames:
            return GraspExport(gid, reason="no tactile frames during the grasp")
        if not grasp.force or not grasp.width:
            return GraspExport(
                gid, reason=f"no {'force' if not grasp.force else 'width'} samples during the grasp"
            )
        fingers = {s.finger for s in self.settings.sensors}
        streams = []
        for finger, frames in sorted(grasp.frames.items()):
            if finger not in fingers:
                return GraspExport(
                    gid,
                    reason=f"frames from finger {finger!r}, which the settings have no sensor on",
                )
            stream = _frame_stream(finger, frames)
            if isinstance(stream, str):
                return GraspExport(gid, reason=stream)
            streams.append(stream)
        record = GraspRecord(
            sensors=self.settings.sensors,
            gripper=self.settings.gripper,
            frames=tuple(streams),
            force_n=_samples(grasp.force),
            width_m=_samples(grasp.width),
            provenance=Provenance(
                source=self.source,
                software_version=self.session_version,
                model="session",
                created_utc=datetime.now(UTC).isoformat(),
                extra={
                    "session": str(self.path.resolve()),
                    "grasp_id": gid,
                    "exported_by": software_version(),
                },
            ),
            label=self.label(grasp.object_name),
            events={"grasp_start": grasp.start_s, "grasp_end": end_s,
                    **({} if grasp.loading_end_s is None else {GRASP_DONE_EVENT: grasp.loading_end_s})},
        )
        return GraspExport(gid, record=record)

    def label(self, object_name: str | None) -> Label | None:
        if object_name is None:
            return None
        obj = self.objects.get(object_name)
        if obj is None:
            log.warning(
                "%s: object %r is not in the catalogue; its grasps carry no modulus",
                self.path,
                object_name,
            )
            return Label(object_name=object_name)
        return Label(
            object_name=obj.name, modulus_pa=obj.modulus_pa, material=obj.material, shape=obj.shape
        )


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
        whether it is simulated or hardware (and ``source`` was not given).
    """
    reader = LogReader(Path(path), max_bytes=max_bytes)
    info = reader.info()
    yield from _grasps(reader, info, settings=settings, catalogue=catalogue, source=source)


def _grasps(
    reader: LogReader,
    info: LogInfo,
    *,
    settings: Settings | None,
    catalogue: str | Path | None,
    source: str | None,
) -> Iterator[GraspExport]:
    path = reader.path
    settings = settings if settings is not None else info.settings()
    source = source or info.session.get("source")
    if source not in ("simulated", "hardware"):
        raise SessionLogError(
            f"{path}: the session metadata gives source {source!r}; "
            "pass simulated or hardware explicitly"
        )
    assembler = _Assembler(
        path=path,
        settings=settings,
        objects=_load_objects(info, catalogue),
        source=source,
        session_version=info.session.get("software_version", "0+unknown"),
    )
    for logged in reader.messages(("grasp_event", "frame", "force", "width")):
        yield from assembler.feed(logged.message)
    yield from assembler.unfinished()
    if assembler.unassigned:
        log.info("%s: %d frame/force/width messages outside any grasp", path, assembler.unassigned)


def _safe_name(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9._-]+", "_", name)


def _calibrated_settings(info: LogInfo, settings: Settings, out: Path) -> Settings:
    """``settings``; a sensor whose calibration the log stores points to a copy in ``out``."""
    sensors = []
    for sensor in settings.sensors:
        stored = f"calibration/{sensor.finger}/{Path(sensor.calibration).name}"
        if sensor.calibration and stored in info.attachments:
            dest = out / "calibration" / _safe_name(sensor.finger) / _safe_name(Path(stored).name)
            dest.parent.mkdir(parents=True, exist_ok=True)
            dest.write_bytes(info.attachments[stored])
            sensor = dataclasses.replace(sensor, calibration=str(dest.resolve()))
        sensors.append(sensor)
    return dataclasses.replace(settings, sensors=tuple(sensors))


def export_session(
    path: str | Path,
    out: str | Path,
    *,
    settings: Settings | None = None,
    catalogue: str | Path | None = None,
    source: str | None = None,
    progress: bool = False,
) -> list[GraspExport]:
    """Write every complete grasp of a session log as ``<out>/<log>_<grasp_id>.grasp``.

    Takes the options of :func:`session_grasps`. Returns one :class:`GraspExport` per grasp
    (``path`` set where a record was written, ``reason`` where none could be).

    Raises
    ------
    SessionLogError
        As :func:`session_grasps`, or ``out`` cannot be created.
    """
    path, out = Path(path), Path(out)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise SessionLogError(
            f"cannot create the export directory {out}: {exc.strerror or exc}"
        ) from exc
    reader = LogReader(path)
    info = reader.info()
    settings = _calibrated_settings(
        info, settings if settings is not None else info.settings(), out
    )
    results = []
    grasps = _grasps(reader, info, settings=settings, catalogue=catalogue, source=source)
    for grasp in tqdm(grasps, desc=f"export {path.name}", unit="grasp", disable=not progress):
        if grasp:
            dest = write_record(
                grasp.record, out / f"{_safe_name(path.stem)}_{_safe_name(grasp.grasp_id)}.grasp"
            )
            grasp = dataclasses.replace(grasp, path=dest)
        else:
            log.warning("%s: grasp %r not exported: %s", path, grasp.grasp_id, grasp.reason)
        results.append(grasp)
    return results
