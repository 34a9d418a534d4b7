"""The grasp record: one grasp on disk, as simulation, capture, training and evaluation use it.

Format (version 3)
------------------
A grasp record is a ZIP archive (suffix ``.grasp``) holding:

``record.json``
    ``{"format": "compliance-teleop.grasp", "version": 3, ...}`` (or 1 or 2: below) with the
    sensors (full :class:`~teleop.settings.SensorSettings` per finger: identity,
    warp calibration and gel; a ``camera_source`` URL's password as ``***``), optionally
    the gripper (below), the optional label, the provenance, named events
    (``{"contact": t_s, ...}``; :data:`GRASP_DONE_EVENT` is the time the gripper's
    grasp command completed: the fingers stopped at the target force and hold it
    until the release) and, per finger, the frame encoding, count and shape.
``force/t_s.npy``, ``force/value_n.npy``
    Load-cell samples: time (s) and normal force (N), float64, 1-D, same length.
``width/t_s.npy``, ``width/value_m.npy``
    Gripper width samples: time (s) and width (m), float64, 1-D, same length.
``frames/<finger>/t_s.npy``
    Capture time (s) of each tactile frame, float64.
``frames/<finger>/<index:06d>.<jpg|png>``
    Each frame exactly as captured: ``jpeg`` keeps the camera's own JPEG bytes
    (an MJPG stream, or the simulated camera's compression, quality stated in
    the header); ``png`` is lossless. Frames decode to uint8 BGR, H x W x 3.
``calibration/<name>.npy`` (optional)
    Numeric arrays the sensor calibration needs (e.g. a no-contact frame).
``sensors/<finger>/<file>`` (optional, version 3)
    A sensor's colour-to-gradient calibration file (the ``.npz`` of ``estimator calibrate``), byte
    for byte, listed in the header's ``calibration_files`` (``{finger: member}``); that sensor's
    ``calibration`` in the header is the member's name.

Version 2 adds ``provenance.style``: how the grasp was driven, ``"script"`` (the paper's grasp: close
at a constant speed to one target force, hold, release; the gripper reports when its fingers
stopped, :data:`GRASP_DONE_EVENT`) or ``"operator"`` (a person, or the simulated one, drove the
fingers' target width continuously: variable speed, pauses, back-offs; no ``grasp_done`` event).
A record whose style is ``"script"`` is written as version 1 without the key, byte for byte as
before, so that older readers keep reading it; this reader reads both versions (a version-1
record's style is ``"script"``).

The optional ``gripper`` entry (full :class:`~teleop.settings.GripperSettings` as configured for
the grasp: finger stiffness as calibrated, closing speed, target force, ...) lets a reader use the
rig's own values; records without it (older ones, imports) leave them to the reader's settings.
Readers that do not know it ignore it, so it needed no new version.

Version 3 adds ``calibration_files``: a record that carries its sensors' calibration files inside
it (``teleop export`` writes such records) depends on no file outside it, so a folder of records
can be moved or shared. A reader gets the sensor's ``calibration`` as the path of a copy of the file
in a private cache folder (:func:`calibration_cache`; one file per content, written once), so every
tool that opens the file a sensor names works unchanged. Records without calibration files are
written as version 1 or 2 as before, byte for byte.

The label's ``source`` (one of :data:`teleop.labels.LABEL_SOURCES`: where its modulus comes from) and
``detail`` (e.g. the Shore hardness read) are written only when they are not the defaults
(``"catalogue"``, ``""``), so records labelled from a catalogue keep their bytes; readers that do
not know them ignore them, and this reader reads a label without them as a catalogue label.

All timestamps of one record are seconds on one clock. ``.npy`` members are
read with ``allow_pickle=False``. Writing then reading gives back every array
and every frame byte for byte.

A reader that meets a damaged or incomplete file raises
:class:`~teleop.errors.RecordError` naming the file, the member or field, and
what was expected (the header's values are checked in :mod:`teleop.record_header`); one whose
member, or whole, would inflate far beyond what a record holds (a ZIP bomb) is refused before or
while it is read (limits in ``_Reader``'s notes).
"""

from __future__ import annotations

import dataclasses
import hashlib
import io
import json
import os
import re
import stat
import tempfile
import zipfile
import zlib
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from teleop import record_header
from teleop.errors import RecordError
from teleop.grasp_data import (
    ENCODINGS,
    GRASP_DONE_EVENT,
    STYLES,
    FrameStream,
    GraspRecord,
    Label,
    Provenance,
    Samples,
    decode_image,
    reduce_image,
    software_version,
)
from teleop.redact import redacted
from teleop.settings import SensorSettings, settings_to_mapping

__all__ = [
    "FORMAT_NAME",
    "FORMAT_VERSION",
    "GRASP_DONE_EVENT",
    "READABLE_VERSIONS",
    "STYLES",
    "FrameStream",
    "GraspRecord",
    "Label",
    "Provenance",
    "Samples",
    "calibration_cache",
    "calibration_copy",
    "decode_image",
    "find_records",
    "safe_name",
    "read_record",
    "reduce_image",
    "software_version",
    "write_record",
]

FORMAT_NAME = "compliance-teleop.grasp"
FORMAT_VERSION = 3
READABLE_VERSIONS = (1, 2, 3)
# Members every training sample (estimator.training.samples, an .npz written by numpy.savez)
# holds: enough to recognise one without importing the estimator.
_SAMPLE_MEMBERS = frozenset({"format.npy", "version.npy", "rgb_diff.npy", "depth_m.npy"})
# --------------------------------------------------------------------------- writing


def _npy_bytes(array: np.ndarray) -> bytes:
    buf = io.BytesIO()
    np.save(buf, np.ascontiguousarray(array), allow_pickle=False)
    return buf.getvalue()


def _jsonable(value: Any) -> Any:
    if dataclasses.is_dataclass(value):
        return {k: _jsonable(v) for k, v in dataclasses.asdict(value).items()}
    if isinstance(value, Mapping):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_jsonable(v) for v in value]
    if isinstance(value, np.generic):
        return value.item()
    return value


def _member(name: str, compression: int) -> zipfile.ZipInfo:
    """A ZIP member stamped 1980-01-01: the same record always gives the same file bytes."""
    info = zipfile.ZipInfo(name, date_time=(1980, 1, 1, 0, 0, 0))
    info.compress_type = compression
    info.external_attr = 0o644 << 16
    return info


def partial_path(path: Path) -> Path:
    """The temporary name :func:`write_record` writes the record ``path`` under, then renames."""
    return path.with_name(path.name + ".partial")


def write_record(record: GraspRecord, path: str | Path) -> Path:
    """Write ``record`` to ``path`` (a ``.grasp`` ZIP); returns the path.

    The file is written to a temporary name and renamed, so a crash never
    leaves a half-written record under the final name.
    """
    path = Path(path)
    provenance = _jsonable(record.provenance)
    if record.provenance.style == "script":
        del provenance["style"]  # version 1, as older readers read it (module notes)
    files = {finger: _calibration_member(record.sensor(finger)) for finger in sorted(record.calibration_files)}
    sensors = []
    for sensor in record.sensors:
        table = redacted(settings_to_mapping(sensor))  # records are shared: no camera stream's password
        if sensor.finger in files:
            table["calibration"] = files[sensor.finger]
        sensors.append(table)
    header = {
        "format": FORMAT_NAME,
        "version": 3 if files else 2 if "style" in provenance else 1,
        "sensors": sensors,
        **({} if record.gripper is None else {"gripper": settings_to_mapping(record.gripper)}),
        "label": _label_json(record.label) if record.label is not None else None,
        "provenance": provenance,
        "events": {k: float(v) for k, v in record.events.items()},
        "fingers": {
            s.finger: {
                "encoding": s.encoding,
                "jpeg_quality": s.jpeg_quality,
                "count": len(s),
                "shape": list(s.shape) if s.shape else None,
            }
            for s in record.frames
        },
        "calibration": sorted(record.calibration),
        **({"calibration_files": files} if files else {}),
    }
    tmp = partial_path(path)
    try:
        with zipfile.ZipFile(tmp, "w") as zf:
            zf.writestr(_member("record.json", zipfile.ZIP_DEFLATED), json.dumps(header, indent=1, allow_nan=False))
            for name, samples in (("force", record.force_n), ("width", record.width_m)):
                unit = "n" if name == "force" else "m"
                zf.writestr(_member(f"{name}/t_s.npy", zipfile.ZIP_DEFLATED), _npy_bytes(samples.t_s))
                zf.writestr(_member(f"{name}/value_{unit}.npy", zipfile.ZIP_DEFLATED), _npy_bytes(samples.value))
            for stream in record.frames:
                zf.writestr(_member(f"frames/{stream.finger}/t_s.npy", zipfile.ZIP_DEFLATED), _npy_bytes(stream.t_s))
                ext = ENCODINGS[stream.encoding]
                for i, data in enumerate(stream.encoded):
                    zf.writestr(_member(f"frames/{stream.finger}/{i:06d}{ext}", zipfile.ZIP_STORED), data)
            for name, array in record.calibration.items():
                zf.writestr(_member(f"calibration/{name}.npy", zipfile.ZIP_DEFLATED), _npy_bytes(np.asarray(array)))
            for finger, member in files.items():
                zf.writestr(_member(member, zipfile.ZIP_STORED), bytes(record.calibration_files[finger]))
        tmp.replace(path)
    except BaseException:
        # Interrupted (Ctrl-C, a stopped worker) or failed: no temporary left beside the records.
        tmp.unlink(missing_ok=True)
        raise
    return path


def _label_json(label: Label) -> dict[str, Any]:
    """The label as written: ``source`` and ``detail`` only when not the defaults (module notes)."""
    table = _jsonable(label)
    if label.source == "catalogue":
        del table["source"]
    if not label.detail:
        del table["detail"]
    return table


def _calibration_member(sensor: SensorSettings) -> str:
    """The member holding ``sensor``'s calibration file: ``sensors/<finger>/<its file name>``."""
    name = re.sub(r"[^A-Za-z0-9._-]+", "_", Path(sensor.calibration).name) if sensor.calibration else ""
    return f"sensors/{sensor.finger}/{name or 'calibration.npz'}"


_CACHE: list[Path] = []  # the folder calibration_cache chose, once per process


def calibration_cache() -> Path:
    """The folder where the calibration files carried by records are copied when they are read.

    ``<temp>/compliance-teleop-<user id>/calibration``, created private (mode 0700); when that
    folder exists but belongs to another user or others may write to it, a fresh private folder
    of this process instead. Files in it are named by their content's SHA-256, so records carrying
    the same calibration share one copy, and a copy is never changed once written.
    """
    if _CACHE:
        return _CACHE[0]
    uid = os.getuid() if hasattr(os, "getuid") else 0
    root = Path(tempfile.gettempdir()) / f"compliance-teleop-{uid}"
    try:
        root.mkdir(mode=0o700, exist_ok=True)
        info = root.lstat()
        private = (stat.S_ISDIR(info.st_mode) and not info.st_mode & 0o022
                   and (not hasattr(os, "getuid") or info.st_uid == uid))
    except OSError:
        private = False
    folder = root / "calibration" if private else Path(tempfile.mkdtemp(prefix="compliance-teleop-"))
    _CACHE.append(folder)
    return folder


def calibration_copy(data: bytes, name: str) -> Path:
    """A file holding ``data`` in :func:`calibration_cache`, ``<sha256>/<name>`` (written once); raises OSError."""
    digest = hashlib.sha256(data).hexdigest()[:32]
    dest = calibration_cache() / digest / (re.sub(r"[^A-Za-z0-9._-]+", "_", name) or "calibration.npz")
    try:
        if dest.read_bytes() == data:
            return dest
    except OSError:
        pass
    dest.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=dest.parent, prefix=f".{name}.", suffix=".partial")
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
        os.replace(tmp, dest)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return dest


# --------------------------------------------------------------------------- reading


# Sizes a member may inflate to, checked before it is read and again while it is read (a ZIP header
# may lie): a few kilobytes of a hostile archive may inflate to gigabytes. Each is far above what a
# record legitimately holds, so no real record is refused.
_MIB = 1024 * 1024
# record.json: the sensors', gripper's and label's settings, events and per-finger counts, a few KB
# whatever the grasp's length; 16 MiB is over a thousand times that.
_MAX_HEADER_BYTES = 16 * _MIB
# A frame: the largest raw frame the sensor settings allow (raw_width_px, raw_height_px <= 4096) is
# 48 MiB of BGR pixels, and its PNG or JPEG at most a little more; four times that.
_MAX_FRAME_BYTES = 4 * 4096 * 4096 * 3
# .npy arrays: a timestamp or sample array of an hour-long grasp at the fastest rates the settings
# allow (camera 240 Hz, width 1000 Hz) is under 30 MB of float64, a calibration array (a no-contact
# frame of the largest sensor, even as float32) under 200 MiB; a sensor's calibration file (default
# table 8 MiB unpacked, under 1 MB as stored) likewise.
_MAX_ARRAY_BYTES = 256 * _MIB
# The whole archive: frames and calibration files are stored, not compressed, so a record inflates to
# about its own size on disk plus what its deflated header and arrays add, a few MB (tens for the
# longest grasps); 1 GiB more than the file's size is tens of times that.
_MAX_INFLATION_BYTES = 1024 * _MIB


def _member_limit(name: str) -> int:
    """The most bytes member ``name`` may hold (notes above)."""
    if name == "record.json":
        return _MAX_HEADER_BYTES
    if name.startswith("frames/") and not name.endswith(".npy"):
        return _MAX_FRAME_BYTES
    return _MAX_ARRAY_BYTES


class _Reader:
    """Reads members of one archive, turning every failure into a RecordError naming it."""

    def __init__(self, path: Path, zf: zipfile.ZipFile):
        self.path = path
        self.zf = zf
        self.names = set(zf.namelist())
        try:
            size = path.stat().st_size
        except OSError:
            size = 0
        self.budget = size + _MAX_INFLATION_BYTES  # bytes all members together may still inflate to
        declared = sum(info.file_size for info in zf.infolist())
        if declared > self.budget:
            big = max(zf.infolist(), key=lambda info: info.file_size)
            raise self.fail(f"the archive's members declare {declared} bytes in all (member {big.filename!r} "
                            f"{big.file_size}), more than the limit of {self.budget} bytes (its {size} bytes "
                            f"plus {_MAX_INFLATION_BYTES}): refused before reading (a damaged or hostile record)")

    def fail(self, what: str) -> RecordError:
        return RecordError(f"{self.path}: {what}")

    def member(self, name: str) -> bytes:
        if name not in self.names:
            raise self.fail(f"member {name!r} is missing; the record is incomplete")
        limit = min(_member_limit(name), self.budget)
        declared = self.zf.getinfo(name).file_size
        if declared > limit:
            raise self.fail(f"member {name!r} declares {declared} bytes, more than the limit of {limit} bytes: "
                            "refused before reading (a damaged or hostile record)")
        try:
            with self.zf.open(name) as file:  # at most one byte past the limit: the size declared may lie
                data = file.read(limit + 1)
        except (zipfile.BadZipFile, zlib.error, OSError, EOFError, ValueError) as exc:
            raise self.fail(f"member {name!r} is damaged ({exc})") from exc
        if len(data) > limit:
            raise self.fail(f"member {name!r} holds more than the limit of {limit} bytes (it declares "
                            f"{declared}): refused (a damaged or hostile record)")
        self.budget -= len(data)
        return data

    def array(self, name: str, *, dtype: Any, ndim: int) -> np.ndarray:
        try:
            array = np.load(io.BytesIO(self.member(name)), allow_pickle=False)
        except RecordError:
            raise
        except Exception as exc:
            raise self.fail(f"member {name!r} is not a readable .npy array ({exc})") from exc
        if array.dtype != np.dtype(dtype) or array.ndim != ndim:
            raise self.fail(f"member {name!r}: expected {ndim}-D {np.dtype(dtype)}, got {array.ndim}-D {array.dtype}")
        return array

    def samples(self, name: str, unit: str) -> Samples:
        t = self.array(f"{name}/t_s.npy", dtype=np.float64, ndim=1)
        v = self.array(f"{name}/value_{unit}.npy", dtype=np.float64, ndim=1)
        if t.shape != v.shape:
            raise self.fail(f"{name}: {t.shape[0]} timestamps but {v.shape[0]} values")
        return Samples(t, v)


def safe_name(name: str) -> str:
    """``name`` fit for a record's file name on any file system: runs of anything but letters,
    digits, '.', '_' and '-' become one '_'."""
    return re.sub(r"[^A-Za-z0-9._-]+", "_", name)


def find_records(root: str | Path, *, name: str = "") -> list[Path]:
    """Every ``.grasp`` file under the directory ``root`` (recursively), sorted.

    Raises
    ------
    RecordError
        ``root`` is not a directory or holds no record; the message starts with ``name`` (the
        option that gave the directory, e.g. ``--records``) when given.
    """
    root = Path(root)
    where = f"{name} {root}" if name else str(root)
    if not root.is_dir():
        raise RecordError(f"{where}: not a directory")
    paths = sorted(root.rglob("*.grasp"))
    if not paths:
        raise RecordError(f"{where}: no .grasp records found")
    return paths


def read_record(path: str | Path) -> GraspRecord:
    """Read a grasp record written by :func:`write_record`.

    Raises
    ------
    RecordError
        The file is missing, not a ZIP, a training sample (.npz) rather than a
        record, of another format or version, or a member or field is missing,
        damaged or of the wrong type or shape. The message names the file and the
        member or field.
    """
    path = Path(path)
    try:
        zf = zipfile.ZipFile(path)
    except FileNotFoundError as exc:
        raise RecordError(f"{path}: no such grasp record") from exc
    except (zipfile.BadZipFile, OSError, EOFError) as exc:
        raise RecordError(f"{path}: not a grasp record (not a readable ZIP archive: {exc})") from exc
    with zf:
        # A record is written from its first byte. A file cut short loses its end-of-archive record,
        # and zipfile then opens the last one it finds: that of an archive stored inside (the
        # calibration .npz), which starts further in.
        if min((info.header_offset for info in zf.infolist()), default=0) != 0:
            raise RecordError(f"{path}: not a readable grasp record: the file is truncated or damaged (its "
                              "end-of-archive record is missing; the one found belongs to an archive stored in it)")
        r = _Reader(path, zf)
        # A training sample is an .npz, a ZIP too: name it rather than call it an incomplete record.
        sample = _SAMPLE_MEMBERS.issubset(r.names)
        if "record.json" not in r.names and (sample or path.suffix.lower() == ".npz"):
            what = ("a training sample (.npz, written by `teleop import-dataset --layout preprocessed` or "
                    "`estimator build-dataset`)" if sample else "an .npz archive")
            raise r.fail(f"this is {what}, not a grasp record: expected a .grasp record "
                         "(`teleop import-dataset --layout raw` writes them from the published dataset)")
        try:
            header = json.loads(r.member("record.json").decode("utf-8"))
        except (UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise r.fail(f"record.json is not valid JSON ({exc})") from exc
        if not isinstance(header, dict):
            raise r.fail("record.json: expected a JSON object at the top")
        fmt = record_header.field(path, header, "format", str, "header")
        if fmt != FORMAT_NAME:
            raise r.fail(f"record.json: format is {fmt!r}, expected {FORMAT_NAME!r}")
        version = record_header.field(path, header, "version", int, "header")
        if version not in READABLE_VERSIONS:
            raise r.fail(f"record.json: version {version} is not supported (this software reads versions "
                         f"{' and '.join(map(str, READABLE_VERSIONS))})")

        sensors = record_header.sensors(path, header)
        calibration_files = _calibration_files(r, header, version)
        for i, sensor in enumerate(sensors):
            if sensor.finger in calibration_files:
                member, data = calibration_files[sensor.finger]
                try:
                    copy = calibration_copy(data, Path(member).name)
                except OSError as exc:
                    raise r.fail(f"cannot copy member {member!r} (the calibration of finger "
                                 f"{sensor.finger!r}) to {calibration_cache()}: {exc.strerror or exc}") from exc
                sensors[i] = dataclasses.replace(sensor, calibration=str(copy))

        frames = []
        for finger, info in record_header.field(path, header, "fingers", dict, "header").items():
            encoding, count, quality, shape = record_header.frame_info(path, finger, info)
            t = r.array(f"frames/{finger}/t_s.npy", dtype=np.float64, ndim=1)
            if t.shape[0] != count:
                raise r.fail(f"frames/{finger}/t_s.npy has {t.shape[0]} timestamps, header says {count} frames")
            encoded = tuple(r.member(f"frames/{finger}/{i:06d}{ENCODINGS[encoding]}") for i in range(count))
            # frame_info and the count check above make every check FrameStream makes: it refuses none.
            frames.append(FrameStream(finger=finger, t_s=t, encoded=encoded, encoding=encoding,
                                      jpeg_quality=quality, shape=shape))
        gripper = record_header.gripper(path, header)
        label = record_header.label(path, header)
        provenance = record_header.provenance(path, header, version)
        events = record_header.events(path, header)
        calibration = {}
        for name in record_header.calibration(path, header):
            member = f"calibration/{name}.npy"
            try:
                calibration[name] = np.load(io.BytesIO(r.member(member)), allow_pickle=False)
            except RecordError:
                raise
            except Exception as exc:
                raise r.fail(f"member {member!r} is not a readable .npy array ({exc})") from exc
        # Read outside the try below: their RecordErrors (ValueErrors) already name the file.
        force_n = r.samples("force", "n")
        width_m = r.samples("width", "m")
        try:
            return GraspRecord(
                sensors=tuple(sensors),
                frames=tuple(frames),
                force_n=force_n,
                width_m=width_m,
                provenance=provenance,
                label=label,
                events=events,
                calibration=calibration,
                gripper=gripper,
                calibration_files={finger: data for finger, (_, data) in calibration_files.items()},
            )
        except ValueError as exc:
            raise r.fail(str(exc)) from exc


def _calibration_files(r: _Reader, header: Mapping[str, Any], version: int) -> dict[str, tuple[str, bytes]]:
    """finger -> (member, bytes) of the calibration files the record carries (version 3)."""
    if "calibration_files" not in header:
        return {}
    if version < 3:
        raise r.fail(f"record.json: calibration_files is a version-3 field, but the record says version {version}")
    files = record_header.field(r.path, header, "calibration_files", dict, "header")
    fingers = {table.get("finger") for table in header["sensors"] if isinstance(table, Mapping)}
    out = {}
    for finger, member in files.items():
        if not isinstance(member, str) or not member.startswith(f"sensors/{finger}/"):
            raise r.fail(f"record.json: calibration_files.{finger} must name a member sensors/{finger}/<file>, "
                         f"got {member!r}")
        if finger not in fingers:
            raise r.fail(f"record.json: calibration_files.{finger}: the record has no sensor on finger {finger!r}")
        out[finger] = (member, r.member(member))
    return out
