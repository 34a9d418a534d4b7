"""A grasp record's header (``record.json``), checked value by value as :func:`teleop.record.read_record`
reads it.

Each function takes the record's path (for the message) and a part of the parsed header, and returns
what the reader builds from it, or raises :class:`~teleop.errors.RecordError` naming the file, the
field and what was expected. The format itself is described in :mod:`teleop.record`'s notes.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from teleop.errors import RecordError, SettingsError
from teleop.grasp_data import ENCODINGS, Label, Provenance
from teleop.settings import GripperSettings, SensorSettings
from teleop.settings_fields import build_settings

__all__ = ["calibration", "events", "field", "frame_info", "gripper", "header_error", "label", "provenance", "sensors"]


def header_error(path: Path, what: str) -> RecordError:
    """The error for a bad value ``what`` in the header of the record at ``path``."""
    return RecordError(f"{path}: record.json: {what}")


def _is_int(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)  # a JSON true is no number


def _is_number(value: Any) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool)


def _finite(value: int | float) -> bool:
    try:
        return math.isfinite(value)
    except OverflowError:  # an integer too large for a float
        return False


def field(path: Path, mapping: Any, key: str, kind: type | tuple[type, ...], where: str) -> Any:
    """``mapping[key]``, which must be of type ``kind`` (a bool only when ``kind`` says so); ``where``
    names ``mapping`` in the message (e.g. ``"header"``, ``"fingers.left"``)."""
    if not isinstance(mapping, Mapping) or key not in mapping:
        raise header_error(path, f"{where}.{key} is missing")
    value = mapping[key]
    kinds = kind if isinstance(kind, tuple) else (kind,)
    if not isinstance(value, kinds) or (isinstance(value, bool) and bool not in kinds):
        names = " or ".join(k.__name__ for k in kinds)
        raise header_error(path, f"{where}.{key} must be {names}, got {value!r}")
    return value


def sensors(path: Path, header: Mapping[str, Any]) -> list[SensorSettings]:
    """The ``sensors`` list: full sensor settings, one sensor per finger."""
    out: list[SensorSettings] = []
    for i, table in enumerate(field(path, header, "sensors", list, "header")):
        try:
            if not isinstance(table, Mapping):
                raise TypeError(f"expected a table of sensor settings, got {table!r}")
            # The settings loader's checks apply to the sensors stored in records too.
            sensor = build_settings(SensorSettings, table, "record.json", "sensors")
        except (SettingsError, TypeError, ValueError) as exc:
            raise header_error(path, f"sensors[{i}] is invalid ({exc})") from exc
        # A finger's frames and calibration are looked up by finger: two sensors on one would be ambiguous.
        for j, other in enumerate(out):
            if other.finger == sensor.finger:
                raise header_error(path, f"sensors[{i}].finger {sensor.finger!r} is also sensors[{j}]'s: "
                                         "expected one sensor per finger")
        out.append(sensor)
    return out


def gripper(path: Path, header: Mapping[str, Any]) -> GripperSettings | None:
    """The optional ``gripper`` table: full gripper settings, or None when absent or null."""
    table = header.get("gripper")
    if table is None:
        return None
    try:
        if not isinstance(table, Mapping):
            raise TypeError(f"expected a table of gripper settings, got {table!r}")
        return build_settings(GripperSettings, table, "record.json", "gripper")
    except (SettingsError, TypeError, ValueError) as exc:
        raise header_error(path, f"gripper is invalid ({exc})") from exc


def frame_info(path: Path, finger: str, info: Any) -> tuple[str, int, int | None, tuple[int, int, int] | None]:
    """``fingers.<finger>``: its (encoding, count, jpeg_quality, shape).

    ``jpeg_quality`` is an integer from 1 to 100 or null (unknown, or PNG frames); ``shape`` is
    ``[rows, columns, 3]`` (frames decode to H x W x 3 BGR) or null (no frames, or not stated).
    """
    where = f"fingers.{finger}"
    encoding = field(path, info, "encoding", str, where)
    if encoding not in ENCODINGS:
        raise header_error(path, f"{where}.encoding {encoding!r} is not one of {sorted(ENCODINGS)}")
    count = field(path, info, "count", int, where)
    quality = info.get("jpeg_quality")
    if quality is not None and not (_is_int(quality) and 1 <= quality <= 100):
        raise header_error(path, f"{where}.jpeg_quality must be an integer from 1 to 100 or null, got {quality!r}")
    shape = info.get("shape")
    if shape is not None and not (isinstance(shape, list) and len(shape) == 3 and shape[2] == 3
                                  and all(_is_int(n) and n > 0 for n in shape)):
        raise header_error(path, f"{where}.shape must be [rows, columns, 3] (positive integers: frames decode "
                                 f"to H x W x 3 BGR) or null, got {shape!r}")
    return encoding, count, quality, None if shape is None else (shape[0], shape[1], shape[2])


def label(path: Path, header: Mapping[str, Any]) -> Label | None:
    """The optional ``label``, or None when null or absent."""
    table = header.get("label")
    if table is None:
        return None
    name = field(path, table, "object_name", str, "label")
    modulus = table.get("modulus_pa")
    if modulus is not None and not _is_number(modulus):
        raise header_error(path, f"label.modulus_pa must be a number (Pa) or null, got {modulus!r}")
    try:
        return Label(
            object_name=name,
            modulus_pa=modulus,
            material=table.get("material", ""),
            shape=table.get("shape", ""),
            extra=table.get("extra", {}),
            source=table.get("source", "catalogue"),
            detail=table.get("detail", ""),
        )
    except (TypeError, ValueError) as exc:
        raise header_error(path, f"label is invalid ({exc})") from exc


def provenance(path: Path, header: Mapping[str, Any], version: int) -> Provenance:
    """The ``provenance`` table; ``style`` only from version 2 on."""
    table = field(path, header, "provenance", dict, "header")
    if version == 1 and "style" in table:
        raise header_error(path, "provenance.style is a version-2 field, but the record says version 1")
    try:
        return Provenance(**table)
    except (TypeError, ValueError) as exc:
        raise header_error(path, f"provenance is invalid ({exc})") from exc


def calibration(path: Path, header: Mapping[str, Any]) -> list[str]:
    """The ``calibration`` list: the names of the record's calibration arrays (none when absent)."""
    names = header.get("calibration", [])
    if not isinstance(names, list) or not all(isinstance(name, str) for name in names):
        raise header_error(path, f"header.calibration must be a list of array names, got {names!r}")
    return names


def events(path: Path, header: Mapping[str, Any]) -> dict[str, float]:
    """The ``events`` table: name -> time (s), each a finite number."""
    table = field(path, header, "events", dict, "header")
    for key, value in table.items():
        # The writer refuses NaN and infinities (allow_nan=False): one here was not written by it.
        if not (_is_number(value) and _finite(value)):
            raise header_error(path, f"events.{key} must be a time in seconds (a finite number), got {value!r}")
    return {key: float(value) for key, value in table.items()}
