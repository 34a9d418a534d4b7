"""Bus messages in forms Foxglove decodes: the conversion the session log and the live view share.

:func:`foxglove_messages` turns one decoded bus message into zero or more
:class:`FoxgloveMessage` (topic, schema, encoding, data), nothing else: writing them into
an MCAP log is :mod:`teleop.session.foxglove_log`'s job, serving them live
:mod:`teleop.session.foxglove_live`'s.

=============  ===============================  ==========================================
bus type       Foxglove topic                   form
=============  ===============================  ==========================================
frame          ``/tactile/<finger>``            ``foxglove.CompressedImage`` (protobuf): the
                                                camera's JPEG or PNG bytes exactly as sent;
                                                ``raw`` frames have no Foxglove form
grasp_event    ``/events``                      ``foxglove.Log`` (protobuf), e.g. "grasp g1
                                                start (object: aluminium block)"
heartbeat      (none)
force, width   ``/force``, ``/width``           JSON, one message per sample (at most
                                                :data:`MAX_SAMPLE_MESSAGES` per batch)
anything else  ``/<bus topic>``                 JSON: ``estimate``, ``display``, ``command``...
=============  ===============================  ==========================================

Why JSON for the numeric types: Foxglove's Plot, State Transitions and Raw Messages panels
read JSON fields by message path (``/estimate.log10_E_pa``) with no generated code, and a
JSON Schema per type is derived at run time from the type's one definition
(:mod:`teleop.bus.messages`, through :data:`teleop.bus.wire.SCHEMAS`), so a new bus type (or
field) is plotted without a line of new code here; these messages are a small fraction of a
session's bytes, and the log's chunks are compressed. Images and log lines use the Foxglove
protobuf schemas, which the Image and Log panels need.

JSON message fields: ``timestamp`` (``{sec, nsec}``, the capture time, or the sample time
for sample messages, on the log's clock: see below), ``t_capture_s``, every scalar field of the type as sent, plus, for
quantities that must be positive (E), their ``log10_`` form (Foxglove's Plot has no log
axis and E spans decades). Intervals become ``{low, high, log10_low, log10_high}``. A nil
value (no E, an open interval side, no grasp) is left out: Foxglove's JSON Schema reader
takes no nullable types. A type with a ``t_s`` array (force, width) gives one message per
sample with ``t_s`` and the value as numbers, each placed at its own time on the receive
clock (:attr:`FoxgloveMessage.age_ns`), so the Plot panel draws the true sample spacing.
A batch of more than :data:`MAX_SAMPLE_MESSAGES` samples (real ones hold a few; the wire
takes half a million) is decimated: it gives that many messages, the samples at evenly spaced
indices, its first and last included, so one bus message costs a bounded number of Foxglove
messages; its bus channel keeps every sample. Array fields of other types are not shown (the
bus channels keep them).

Timestamps: the bus times (``t_capture_s``, ``t_s``) are ``time.monotonic()`` seconds of the
capturing host; every Foxglove ``timestamp`` (JSON, images, log lines) is that time plus
``offset_ns`` (:func:`foxglove_messages`), which the session log and the live view set so
that it is nanoseconds since the Unix epoch, like their log times (Foxglove then shows the
date and time of day). The ``t_capture_s`` and ``t_s`` fields stay as sent.

:func:`known_channels` lists the channels of every type's default topic, so the live view
can advertise them all before the first message.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from functools import cache
from typing import Any

import numpy as np
from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage
from foxglove_schemas_protobuf.Log_pb2 import Log
from google.protobuf.descriptor_pb2 import FileDescriptorSet
from google.protobuf.timestamp_pb2 import Timestamp

from teleop.bus.field_checks import (
    FlagField,
    IntegerField,
    IntervalField,
    NumberField,
    NumberMapField,
    TextField,
)
from teleop.bus.wire import SCHEMAS, Body, Message

__all__ = [
    "EVENTS_TOPIC",
    "IMAGE_SCHEMA",
    "FoxgloveChannel",
    "FoxgloveMessage",
    "MAX_SAMPLE_MESSAGES",
    "file_descriptor_set",
    "foxglove_messages",
    "image_topic",
    "in_topic_order",
    "json_schema",
    "known_channels",
]

IMAGE_SCHEMA = CompressedImage.DESCRIPTOR.full_name  # "foxglove.CompressedImage"
EVENTS_TOPIC = "/events"
JSON_SCHEMA_PREFIX = "compliance_teleop."
_SAMPLE_TIMES = "t_s"
# Most JSON messages one force or width batch gives (module notes): real batches hold a few samples,
# a stalled reader's a few seconds' worth (the load cell reads at 80 Hz); more are decimated.
MAX_SAMPLE_MESSAGES = 256


@dataclass(frozen=True)
class FoxgloveChannel:
    """Where Foxglove messages go: a topic, its schema and its message encoding."""

    topic: str
    schema_name: str
    schema_encoding: str  # "protobuf" or "jsonschema"
    schema_data: bytes
    message_encoding: str  # "protobuf" or "json"


@dataclass(frozen=True)
class FoxgloveMessage:
    """One message Foxglove can decode: where it goes, its schema, and its bytes.

    ``age_ns``: how long before the bus message's receive time this message's data was
    taken (a sample before the newest of its batch); its log time is the receive time
    minus this.
    """

    topic: str
    schema_name: str
    schema_encoding: str  # "protobuf" or "jsonschema"
    schema_data: bytes
    message_encoding: str  # "protobuf" or "json"
    data: bytes
    age_ns: int = 0

    @property
    def channel(self) -> FoxgloveChannel:
        return FoxgloveChannel(
            self.topic, self.schema_name, self.schema_encoding, self.schema_data, self.message_encoding
        )


def image_topic(finger: str) -> str:
    """The Foxglove topic of one finger's tactile images."""
    return f"/tactile/{finger}"


def file_descriptor_set(message_class: Any) -> bytes:
    """A protobuf class's schema as MCAP wants it: its file and every dependency, serialized."""
    files = FileDescriptorSet()
    seen: set[str] = set()

    def add(descriptor: Any) -> None:
        if descriptor.name in seen:
            return
        seen.add(descriptor.name)
        for dependency in descriptor.dependencies:
            add(dependency)
        descriptor.CopyToProto(files.file.add())

    add(message_class.DESCRIPTOR.file)
    return files.SerializeToString()


@cache
def _protobuf_schema(message_class: Any) -> bytes:
    return file_descriptor_set(message_class)


def _timestamp(t_s: float, offset_ns: int) -> Timestamp:
    # In integer ns: epoch seconds as a float would keep only about a microsecond.
    seconds, nanos = divmod(round(t_s * 1e9) + offset_ns, 1_000_000_000)
    return Timestamp(seconds=seconds, nanos=nanos)


def _time_json(t_s: float, offset_ns: int) -> dict[str, int]:
    stamp = _timestamp(t_s, offset_ns)
    return {"sec": stamp.seconds, "nsec": stamp.nanos}


def _protobuf(topic: str, proto: Any) -> FoxgloveMessage:
    cls = type(proto)
    return FoxgloveMessage(
        topic,
        cls.DESCRIPTOR.full_name,
        "protobuf",
        _protobuf_schema(cls),
        "protobuf",
        proto.SerializeToString(),
    )


# --------------------------------------------------------------------------- protobuf types


def _image(message: Message, offset_ns: int) -> list[FoxgloveMessage]:
    frame = message.fields
    if frame.encoding == "raw":  # no compressed bytes to show as they are
        return []
    image = CompressedImage(
        timestamp=_timestamp(message.t_capture_s, offset_ns),
        frame_id=frame.finger,
        data=frame.data.tobytes(),
        format=frame.encoding,
    )
    return [_protobuf(image_topic(frame.finger), image)]


def _event(message: Message, offset_ns: int) -> list[FoxgloveMessage]:
    event = message.fields
    text = f"grasp {event.grasp_id} {event.event}"
    if event.object_name:
        text += f" (object: {event.object_name})"
    line = Log(
        timestamp=_timestamp(message.t_capture_s, offset_ns),
        level=Log.Level.INFO,
        message=text,
        name=message.source or "teleop",
    )
    return [_protobuf(EVENTS_TOPIC, line)]


# --------------------------------------------------------------------------- JSON types

# Foxglove's JSON Schema reader (``parseJsonSchema`` of its mcap-support package) takes one
# "type" per property (boolean, string, number, integer, object with "properties", array)
# and refuses type lists and typeless properties: a nil value is therefore left out of the
# message, and its property is simply not required.


def _text_schema(check: TextField) -> dict[str, Any]:
    schema: dict[str, Any] = {"type": "string"}
    if check.choices:
        schema["enum"] = list(check.choices)
    return schema


def _number_schema(check: NumberField) -> dict[str, Any]:
    schema: dict[str, Any] = {"type": "number"}
    if check.lo is not None:
        schema["exclusiveMinimum" if check.lo_open else "minimum"] = check.lo
    return schema


_BOUNDS = ("low", "high", "log10_low", "log10_high")  # an interval's JSON form; nil sides left out

# The JSON Schema of each kind of field check's value (teleop.bus.field_checks), from its options.
_FIELD_SCHEMAS: dict[type, Callable[[Any], dict[str, Any]]] = {
    TextField: _text_schema,
    IntegerField: lambda check: {"type": "integer", "minimum": check.lo},
    NumberField: _number_schema,
    FlagField: lambda check: {"type": "boolean"},
    IntervalField: lambda check: {
        "type": "object",
        "properties": {k: {"type": "number"} for k in _BOUNDS},
        "additionalProperties": False,
    },
    NumberMapField: lambda check: {
        "type": "object",
        "properties": {},
        "additionalProperties": {"type": "number"},
    },
}


@dataclass(frozen=True)
class _Field:
    name: str
    schema: dict[str, Any]
    nullable: bool
    interval: bool
    positive: bool  # must be > 0 (a modulus): also given as log10


@cache
def _fields(kind: str) -> tuple[_Field, ...]:
    """The scalar fields of ``kind``, each with the JSON Schema of its value."""
    return tuple(
        _Field(name, _FIELD_SCHEMAS[type(check)](check), check.nullable, isinstance(check, IntervalField),
               isinstance(check, NumberField) and check.positive)
        for name, check in SCHEMAS[kind].fields.items()
    )


@cache
def json_schema(kind: str) -> dict[str, Any]:
    """The JSON Schema of bus type ``kind``'s JSON messages (see the module docstring)."""
    properties: dict[str, Any] = {
        "timestamp": {
            "type": "object",
            "properties": {
                "sec": {"type": "integer"},
                "nsec": {"type": "integer", "minimum": 0, "maximum": 999_999_999},
            },
            "required": ["sec", "nsec"],
        },
        "t_capture_s": {"type": "number"},
    }
    required = list(properties)
    for field in _fields(kind):
        names = [field.name, *([f"log10_{field.name}"] if field.positive else [])]
        properties |= {name: field.schema if name == field.name else {"type": "number"} for name in names}
        required += [] if field.nullable else names
    arrays = SCHEMAS[kind].arrays
    if _SAMPLE_TIMES in arrays:
        properties |= {name: {"type": "number"} for name in arrays}
        required += list(arrays)
    return {
        "$schema": "https://json-schema.org/draft/2020-12/schema",
        "title": f"{JSON_SCHEMA_PREFIX}{kind}",
        "type": "object",
        "properties": properties,
        "required": sorted(required),
        "additionalProperties": False,
    }


@cache
def _json_schema_bytes(kind: str) -> bytes:
    return json.dumps(json_schema(kind), sort_keys=True).encode("utf-8")


def _json_fields(kind: str, body: Body) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for field in _fields(kind):
        value = getattr(body, field.name)
        if value is None:
            continue
        if field.interval:
            low, high = value
            logs = (None if v is None else math.log10(v) for v in (low, high))
            value = {k: v for k, v in zip(_BOUNDS, (low, high, *logs), strict=True) if v is not None}
        out[field.name] = value
        if field.positive:
            out[f"log10_{field.name}"] = math.log10(value)
    return out


def _json(topic: str, kind: str, fields: dict[str, Any], age_ns: int = 0) -> FoxgloveMessage:
    data = json.dumps(fields, separators=(",", ":"), allow_nan=False).encode("utf-8")
    return FoxgloveMessage(
        topic,
        f"{JSON_SCHEMA_PREFIX}{kind}",
        "jsonschema",
        _json_schema_bytes(kind),
        "json",
        data,
        age_ns,
    )


def _plain(message: Message, offset_ns: int) -> list[FoxgloveMessage]:
    kind, body = message.type, message.fields
    common = {"t_capture_s": message.t_capture_s, **_json_fields(kind, body)}
    topic = "/" + message.topic
    arrays = SCHEMAS[kind].arrays
    if _SAMPLE_TIMES not in arrays:
        return [_json(topic, kind, {"timestamp": _time_json(message.t_capture_s, offset_ns), **common})]
    columns = {name: np.asarray(getattr(body, name)) for name in arrays}
    times = columns[_SAMPLE_TIMES]
    newest = float(times.max()) if times.size else 0.0
    if times.size > MAX_SAMPLE_MESSAGES:  # evenly spaced indices, the first and last included
        picked = np.unique(np.linspace(0, times.size - 1, MAX_SAMPLE_MESSAGES).round().astype(np.intp))
        columns = {name: values[picked] for name, values in columns.items()}
    rows = {name: values.tolist() for name, values in columns.items()}
    out = []
    for i, t_s in enumerate(rows[_SAMPLE_TIMES]):
        sample = {name: values[i] for name, values in rows.items()}
        age_ns = round((newest - t_s) * 1e9)
        out.append(_json(topic, kind, {"timestamp": _time_json(t_s, offset_ns), **common, **sample}, age_ns))
    return out


_SPECIAL: dict[str, Callable[[Message, int], list[FoxgloveMessage]]] = {
    "frame": _image,
    "grasp_event": _event,
    "heartbeat": lambda message, offset_ns: [],
}


def foxglove_messages(message: Message, offset_ns: int = 0) -> list[FoxgloveMessage]:
    """The Foxglove forms of one decoded bus message (none for heartbeats and raw frames).

    ``offset_ns`` is added to the bus times to make each ``timestamp`` (module notes).
    """
    return _SPECIAL.get(message.type, _plain)(message, offset_ns)


def known_channels(fingers: Iterable[str] = ()) -> list[FoxgloveChannel]:
    """The channels :func:`foxglove_messages` puts each bus type's default topic on.

    Tactile images for each of ``fingers``, grasp events, and one JSON channel per other type
    (``/estimate``, ``/force``, ...); a topic with a suffix (``estimate/extra``) is not listed.
    """
    out = [FoxgloveChannel(image_topic(finger), IMAGE_SCHEMA, "protobuf",
                           _protobuf_schema(CompressedImage), "protobuf") for finger in fingers]
    out.append(FoxgloveChannel(EVENTS_TOPIC, Log.DESCRIPTOR.full_name, "protobuf", _protobuf_schema(Log),
                               "protobuf"))
    out += [FoxgloveChannel(f"/{kind}", f"{JSON_SCHEMA_PREFIX}{kind}", "jsonschema", _json_schema_bytes(kind),
                            "json") for kind in SCHEMAS if kind not in _SPECIAL]
    return out


def in_topic_order(last_ns: dict[str, int], topic: str, at_ns: int) -> int:
    """``at_ns``, or ``topic``'s previous time in ``last_ns`` when later (which it updates).

    A sample is placed at its batch's receive time less its age; when delivery latency varies that
    can fall before the previous batch's last sample, and Foxglove's plots want each topic in order.
    """
    at_ns = last_ns[topic] = max(at_ns, last_ns.get(topic, 0))
    return at_ns
