"""The bus wire format: every message the robot, estimator and operator nodes exchange.

Frames
------
Every message is one multipart ZeroMQ message::

    [topic, header, body, *buffers]

``topic`` (UTF-8, at most 256 bytes)
    The message type; for a type that declares a qualifier (only ``frame``: its ``finger``),
    optionally followed by ``/`` and the qualifier (``frame/left``), which must be what the
    body says. Any other ``/`` suffix is refused: a topic a sender could make up would grow
    every receiver's per-topic tables and log lines.
    Subscribers filter on it by prefix, so a subscription to ``frame`` gets both fingers.
``header`` (msgpack map, at most 4 KiB), exactly these keys:

    ``v``            schema version, int (this software speaks version 1)
    ``type``         message type, str (one of :data:`SCHEMAS`)
    ``source``       sending node, str (``"robot"``, ``"estimator"``, ...)
    ``seq``          sequence number, int >= 0, +1 per message of one topic from one
                     source; a receiver that sees a jump knows messages were lost
    ``t_capture_s``  capture time of the data, float seconds on the clock of the stream
                     (the robot host's ``time.monotonic()`` for live devices, the record's
                     clock for replays)
    ``t_send_ns``    send time, int nanoseconds of ``time.monotonic_ns()`` on the sending
                     host. CLOCK_MONOTONIC is system-wide on Linux and never steps, so
                     ``time.monotonic_ns() - t_send_ns`` is the transit latency between
                     processes of ONE host; across hosts the value is not comparable.
    ``buffers``      one ``[field, dtype, shape]`` per array frame, in frame order: the
                     body field it fills, a numpy dtype string from :data:`DTYPES`
                     (``"<f8"``, ``"|u1"``, ...), and the shape as a list of ints.

``body`` (msgpack map, at most 64 KiB)
    The type's scalar fields (:data:`BODIES`), in their declared order: str, int, float,
    bool, nil, a two-item interval or a str->float map. Every field is present (nullable
    ones as nil); no other key is allowed. Array fields never appear here.
``buffers``
    The raw bytes of each array field, C order, one frame each. They are sent
    zero-copy (``copy=False`` over a memoryview of the array) and received zero-copy
    (``np.frombuffer`` over the received frame; decoded arrays are read-only views).

Nothing is ever pickled. :func:`decode` refuses a message with
:class:`~teleop.errors.MessageRejected`, whose ``reason`` is one of
:data:`REJECT_REASONS`: sizes are checked before anything is unpacked, msgpack runs
with tight length limits, and every field is checked against its schema, numbers
against NaN and infinity. The envelope and its encoding are this module's alone.

Message types and body schemas
------------------------------
The message types, their body fields and what each means are :mod:`teleop.bus.messages`: one
dataclass per type (:data:`BODIES`), its fields written in the field checks of
:mod:`teleop.bus.field_checks`, and :data:`SCHEMAS` derived from them. This module checks every
body against them and re-exports their names. A received (or built) message's fields are read
from its typed view, :attr:`Message.fields`, an instance of its type's dataclass; the body map
(:attr:`Message.body`) is the wire's form, which :func:`encode` writes.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from functools import cached_property
from typing import Any

import msgpack
import numpy as np
from msgpack.exceptions import StackError

from teleop.bus.field_checks import MAX_TIME_S, IntegerField, NumberField, TextField, is_int
from teleop.bus.messages import (
    BODIES,
    COMMAND_ACTIONS,
    DISPLAY_PHASES,
    ESTIMATE_STATES,
    MAX_MODEL_ID_CHARS,
    MAX_PARAMS,
    MAX_STR_CHARS,
    MODEL_EVENTS,
    ROBOT_MODES,
    ROBOT_NOTICES,
    SCHEMAS,
    Body,
)
from teleop.errors import MessageRejected

__all__ = [
    "BODIES",
    "COMMAND_ACTIONS",
    "DISPLAY_PHASES",
    "DTYPES",
    "ESTIMATE_STATES",
    "MAX_BODY_BYTES",
    "MAX_BUFFERS",
    "MAX_HEADER_BYTES",
    "MAX_MODEL_ID_CHARS",
    "MAX_TOPIC_BYTES",
    "MODEL_EVENTS",
    "REJECT_REASONS",
    "ROBOT_MODES",
    "ROBOT_NOTICES",
    "SCHEMAS",
    "SCHEMA_VERSION",
    "Body",
    "Message",
    "claimed_source",
    "decode",
    "default_topic",
    "encode",
    "make_message",
    "now_ns",
]

SCHEMA_VERSION = 1
MAX_TOPIC_BYTES = 256
MAX_HEADER_BYTES = 4096
MAX_BODY_BYTES = 64 * 1024
MAX_BUFFERS = 8
MAX_NDIM = 4
MAX_SOURCE_SHOWN = 64  # characters of a refused message's claimed source that a log line shows

REJECT_REASONS = (
    "frame_count",  # fewer than 3 frames, or more buffers than MAX_BUFFERS
    "oversize",  # the whole message, the topic, the header or the body is too large
    "corrupt",  # header or body is not a msgpack map within the limits, or topic not UTF-8
    "unknown_version",
    "unknown_type",
    "bad_header",  # header keys missing, extra or mistyped; topic not of the type, a qualifier on a type that
    # declares none, or a qualifier not the body's
    "missing_field",
    "extra_field",
    "mistyped_field",  # wrong type, out of range, not an allowed choice, wrong dtype/ndim
    "not_finite",  # NaN or infinity where a finite number is required
    "bad_buffer",  # buffer list does not match the frames, size != dtype x shape, or sizes no message carries
)

# Numeric dtypes an array may travel as; anything else (objects, structured) is refused.
DTYPES = frozenset(
    np.dtype(code).newbyteorder(order).str
    for code in ("?", "u1", "i1", "u2", "i2", "u4", "i4", "u8", "i8", "f2", "f4", "f8")
    for order in ("<", ">")
)

# The header's checked fields (the sender's identity and clocks), checked alike on both ends.
_HEADER_FIELDS = {"source": TextField(max_chars=64), "seq": IntegerField(), "t_capture_s": NumberField(max_abs=MAX_TIME_S),
                  "t_send_ns": IntegerField()}
_HEADER_KEYS = frozenset({"v", "type", *_HEADER_FIELDS, "buffers"})


def _check_body(kind: str, body: Mapping[str, Any], arrays: Mapping[str, np.ndarray]) -> dict[str, Any]:
    """Check scalar fields of ``body`` and already-typed ``arrays``; the full body, normalised."""
    schema = SCHEMAS[kind]
    if not isinstance(body, Mapping):
        raise MessageRejected("corrupt", f"{kind} body is a {type(body).__name__}, expected a map")
    missing = sorted(set(schema.fields) - set(body) - schema.optional)
    if missing:
        raise MessageRejected("missing_field", f"{kind} body lacks {', '.join(missing)}")
    body = {**dict.fromkeys(schema.optional), **body}
    extra = sorted(map(str, set(body) - set(schema.fields)))
    if extra:
        raise MessageRejected("extra_field", f"{kind} body has unexpected field(s) {', '.join(extra)}")
    out = {name: check(body[name], f"{kind}.{name}") for name, check in schema.fields.items()}
    for name, spec in schema.arrays.items():
        out[name] = spec.check(arrays[name], f"{kind}.{name}")
    if schema.rule is not None:
        schema.rule(out)
    return out


# --------------------------------------------------------------------------- message


# The body field a type's topic names after a "/" (frame/left): topic and body must agree. The
# topics of every other type are their type's name alone.
_TOPIC_QUALIFIERS = {"frame": "finger"}


def default_topic(kind: str, body: Mapping[str, Any]) -> str:
    """``frame/<finger>`` for frames, the type name for everything else."""
    qualifier = _TOPIC_QUALIFIERS.get(kind)
    return kind if qualifier is None else f"{kind}/{body[qualifier]}"


@dataclass(frozen=True)
class Message:
    """One bus message as the nodes see it.

    ``body`` holds every field of the type's schema by name, arrays included (numpy arrays;
    read-only views over the received frames after :func:`decode`): the wire's form, which
    :func:`encode` writes. Code reads the fields from :attr:`fields`. ``seq`` and ``t_send_ns``
    are filled in by the publisher when it sends.
    """

    type: str
    body: Mapping[str, Any]
    t_capture_s: float
    topic: str = ""
    source: str = ""
    seq: int = 0
    t_send_ns: int = 0

    @cached_property
    def fields(self) -> Body:
        """The body as its type's dataclass (:data:`BODIES`), the same values (arrays not
        copied); built on the first read, so a message nobody reads costs nothing more.

        Raises
        ------
        MessageRejected
            Only for a message built by hand, not by :func:`make_message` or :func:`decode`:
            ``unknown_type``, ``missing_field`` or ``extra_field``.
        """
        return _typed_body(self.type, self.body)


def _typed_body(kind: str, body: Mapping[str, Any]) -> Body:
    """``body`` as the dataclass of type ``kind``; a field left out takes its default (nil)."""
    cls = BODIES.get(kind) if isinstance(kind, str) else None
    if cls is None:
        raise MessageRejected("unknown_type", f"{kind!r} is not one of {', '.join(BODIES)}")
    try:
        return cls(**body)
    except TypeError:  # a field too many or one missing: say which
        declared = {item.name: item for item in dataclasses.fields(cls)}
        extra = sorted(map(str, set(body) - set(declared)))
        if extra:
            raise MessageRejected("extra_field", f"{kind} body has unexpected field(s) {', '.join(extra)}") from None
        missing = sorted(name for name, item in declared.items()
                         if name not in body and item.default is dataclasses.MISSING)
        raise MessageRejected("missing_field", f"{kind} body lacks {', '.join(missing)}") from None


def make_message(kind: str, *, t_capture_s: float, topic: str | None = None, **body: Any) -> Message:
    """Build and check a message of type ``kind``; nullable fields left out become None.

    Array fields accept numpy arrays of an allowed dtype (kept as they are, never cast),
    ``bytes`` (frame data) and Python numbers or sequences (converted to the field's dtype,
    so a scalar force becomes a one-sample array).

    Raises
    ------
    MessageRejected
        Unknown type, or a field missing, extra, mistyped or not finite.
    """
    checked = _sender_body(kind, body)
    t = _HEADER_FIELDS["t_capture_s"](t_capture_s, "t_capture_s")
    return Message(type=kind, body=checked, t_capture_s=t, topic=topic or default_topic(kind, checked))


def _sender_body(kind: str, body: Mapping[str, Any]) -> dict[str, Any]:
    """A sender's body checked and normalised: nullable fields filled, arrays contiguous."""
    if not isinstance(kind, str) or kind not in SCHEMAS:
        raise MessageRejected("unknown_type", f"{kind!r} is not one of {', '.join(SCHEMAS)}")
    schema = SCHEMAS[kind]
    body = {**dict.fromkeys(schema.nullable), **body}
    missing = sorted(set(schema.arrays) - set(body))
    if missing:
        raise MessageRejected("missing_field", f"{kind} body lacks {', '.join(missing)}")
    arrays = {name: spec.coerce(body[name], f"{kind}.{name}") for name, spec in schema.arrays.items()}
    checked = _check_body(kind, {k: v for k, v in body.items() if k not in schema.arrays}, arrays)
    for name in arrays:  # after the checks, so a 0-d array is refused, not promoted
        checked[name] = np.ascontiguousarray(checked[name])
    return checked


# --------------------------------------------------------------------------- encode


def encode(message: Message, *, max_bytes: int | None = None) -> list[bytes | memoryview]:
    """Frames of ``message``: ``[topic, header, body, *buffers]``; arrays are not copied.

    The body is checked against its schema first, so a sender cannot emit what a
    receiver would refuse. Non-contiguous arrays are made contiguous (one copy).

    Raises
    ------
    MessageRejected
        The message breaks its schema, or its frames exceed ``max_bytes``.
    """
    body = _sender_body(message.type, message.body)
    schema = SCHEMAS[message.type]
    arrays = {name: body[name] for name in schema.arrays}
    topic = message.topic or default_topic(message.type, body)
    _check_topic(topic, message.type)
    _check_qualifier(topic, message.type, body)
    header = {
        "v": SCHEMA_VERSION,
        "type": message.type,
        **{name: check(getattr(message, name), name) for name, check in _HEADER_FIELDS.items()},
        "buffers": [[name, a.dtype.str, list(a.shape)] for name, a in arrays.items()],
    }
    frames: list[bytes | memoryview] = [
        topic.encode("utf-8"),
        msgpack.packb(header, use_bin_type=True),
        msgpack.packb({k: body[k] for k in schema.fields}, use_bin_type=True),
    ]
    # memoryview over the array's own memory: zmq sends it with copy=False.
    frames += [memoryview(a).cast("B") for a in arrays.values()]
    _check_sizes(frames, max_bytes)
    return frames


# --------------------------------------------------------------------------- decode


def _frame_bytes(frame: Any) -> memoryview:
    # zmq.Frame exposes .buffer; bytes, bytearray and memoryview are buffers already.
    try:
        view = memoryview(getattr(frame, "buffer", frame))
    except TypeError as exc:
        raise MessageRejected("corrupt", f"a frame is a {type(frame).__name__}, not a byte buffer") from exc
    return view if view.format == "B" and view.ndim == 1 else view.cast("B")


def _check_sizes(frames: Sequence[Any], max_bytes: int | None) -> None:
    if len(frames) < 3:
        raise MessageRejected("frame_count", f"{len(frames)} frame(s): expected [topic, header, body, *buffers]")
    if len(frames) > 3 + MAX_BUFFERS:
        raise MessageRejected("frame_count", f"{len(frames) - 3} buffers: at most {MAX_BUFFERS}")
    sizes = [_frame_bytes(f).nbytes for f in frames]
    for name, size, limit in zip(
        ("topic", "header", "body"), sizes, (MAX_TOPIC_BYTES, MAX_HEADER_BYTES, MAX_BODY_BYTES), strict=False
    ):
        if size > limit:
            raise MessageRejected("oversize", f"{name} frame has {size} bytes, at most {limit}")
    if max_bytes is not None and sum(sizes) > max_bytes:
        raise MessageRejected("oversize", f"message has {sum(sizes)} bytes, at most {max_bytes}")


def _check_topic(topic: str, kind: str) -> None:
    """Refuse a topic not of type ``kind``, or qualified (``force/x``) though the type declares no
    qualifier: before the body is read, so a made-up topic costs its receiver nothing more."""
    if topic == kind:
        return
    if not topic.startswith(kind + "/"):
        raise MessageRejected("bad_header", f"topic {topic!r} does not belong to type {kind!r}")
    if kind not in _TOPIC_QUALIFIERS:
        raise MessageRejected("bad_header", f"topic {topic!r} has a qualifier, but {kind} declares none: "
                                            f"its topic is {kind!r}")


def _check_qualifier(topic: str, kind: str, body: Mapping[str, Any]) -> None:
    """Refuse a topic whose qualifier (``frame/left``) is not what the body says (``finger``):
    subscribers filter on the topic, readers go by the body. ``frame`` alone names no finger."""
    field = _TOPIC_QUALIFIERS.get(kind)
    qualifier = topic[len(kind) + 1:]
    if field is not None and topic != kind and qualifier != body[field]:
        raise MessageRejected("bad_header", f"topic {topic!r} names {qualifier!r}, but {kind}.{field} is {body[field]!r}")


def _unpack(data: memoryview, what: str) -> dict[str, Any]:
    try:
        value = msgpack.unpackb(
            data,
            raw=False,
            strict_map_key=True,
            max_str_len=4 * MAX_STR_CHARS,
            max_bin_len=0,  # bytes travel as buffers, never inside msgpack
            max_array_len=MAX_BUFFERS * 2 + MAX_NDIM,
            max_map_len=MAX_PARAMS + 16,
            max_ext_len=0,
        )
    except Exception as exc:  # msgpack raises a zoo of types on bad input; all mean "corrupt"
        # StackError says nothing of itself; others name the problem, some only by their type.
        problem = "nested too deep" if isinstance(exc, StackError) else (str(exc) or type(exc).__name__)
        raise MessageRejected("corrupt", f"{what} is not valid msgpack within the limits ({problem})") from exc
    if not isinstance(value, dict):
        raise MessageRejected("corrupt", f"{what} is a {type(value).__name__}, expected a map")
    return value


def _check_header(header: dict[str, Any], n_buffers: int) -> dict[str, Any]:
    version = header.get("v")
    if not is_int(version) or version != SCHEMA_VERSION:
        raise MessageRejected("unknown_version", f"header version {version!r}: this software speaks {SCHEMA_VERSION}")
    kind = header.get("type")
    if not isinstance(kind, str) or kind not in SCHEMAS:
        raise MessageRejected("unknown_type", f"type {kind!r} is not one of {', '.join(SCHEMAS)}")
    if set(header) != _HEADER_KEYS:
        raise MessageRejected("bad_header", f"header keys {sorted(map(str, header))}, expected {sorted(_HEADER_KEYS)}")
    try:
        for name, check in _HEADER_FIELDS.items():
            check(header[name], f"header.{name}")
    except MessageRejected as exc:
        reason = "not_finite" if exc.reason == "not_finite" else "bad_header"
        raise MessageRejected(reason, exc.detail) from None
    buffers = header["buffers"]
    if not isinstance(buffers, list) or len(buffers) != n_buffers:
        raise MessageRejected("bad_buffer", f"header lists {buffers!r} buffers, message has {n_buffers}")
    return header


def _buffer_array(entry: Any, frame: memoryview, kind: str, seen: set[str], max_bytes: int) -> tuple[str, np.ndarray]:
    """One header buffer entry ``[field, dtype, shape]`` over its frame, sizes checked first."""
    if not (isinstance(entry, list) and len(entry) == 3):
        raise MessageRejected("bad_buffer", f"buffer entry {entry!r}: expected [field, dtype, shape]")
    name, dtype, shape = entry
    arrays = SCHEMAS[kind].arrays
    if not isinstance(name, str) or name not in arrays or name in seen:
        raise MessageRejected("bad_buffer", f"buffer for {name!r}: {kind} has array fields {sorted(arrays)}, each once")
    if not isinstance(dtype, str) or dtype not in DTYPES:
        raise MessageRejected("bad_buffer", f"buffer {name!r} has dtype {dtype!r}, not a plain numeric dtype")
    if not (isinstance(shape, list) and len(shape) <= MAX_NDIM and all(is_int(s) and s >= 0 for s in shape)):
        raise MessageRejected("bad_buffer", f"buffer {name!r} has shape {shape!r}: expected up to {MAX_NDIM} sizes >= 0")
    # A size 0 makes the byte count 0 whatever the other sizes, yet numpy refuses to shape even an
    # empty array past its address space: bound them as if each 0 were 1.
    span = math.prod(max(s, 1) for s in shape) * np.dtype(dtype).itemsize
    if span > max_bytes:
        raise MessageRejected("bad_buffer", f"buffer {name!r} has shape {shape}: {dtype} sizes that span {span} bytes "
                                            f"(a 0 taken as 1), more than a message carries ({max_bytes})")
    expected = math.prod(shape) * np.dtype(dtype).itemsize
    if expected != frame.nbytes:
        raise MessageRejected("bad_buffer", f"buffer {name!r}: {dtype} x {shape} needs {expected} bytes, frame has {frame.nbytes}")
    array = np.frombuffer(frame, dtype=np.dtype(dtype)).reshape(shape)
    array.flags.writeable = False
    seen.add(name)
    return name, array


def decode(frames: Sequence[Any], *, max_bytes: int) -> Message:
    """Check and decode ``[topic, header, body, *buffers]`` into a :class:`Message`.

    ``frames`` may be ``bytes``, memoryviews or ``zmq.Frame`` objects (from
    ``recv_multipart(copy=False)``); array fields become read-only numpy views over
    them, without copying. Sizes are checked before anything is unpacked.

    Raises
    ------
    MessageRejected
        With ``reason`` from :data:`REJECT_REASONS` and a detail naming the rule broken.
        No other exception escapes, whatever the bytes.
    """
    _check_sizes(frames, max_bytes)
    views = [_frame_bytes(f) for f in frames]
    try:
        topic = views[0].tobytes().decode("utf-8")
    except UnicodeDecodeError as exc:
        raise MessageRejected("corrupt", "topic is not UTF-8") from exc
    header = _check_header(_unpack(views[1], "header"), len(views) - 3)
    kind = header["type"]
    _check_topic(topic, kind)
    seen: set[str] = set()
    arrays = dict(_buffer_array(e, v, kind, seen, max_bytes) for e, v in zip(header["buffers"], views[3:], strict=True))
    missing = sorted(set(SCHEMAS[kind].arrays) - seen)
    if missing:
        raise MessageRejected("bad_buffer", f"{kind} lacks buffer(s) {', '.join(missing)}")
    body = _check_body(kind, _unpack(views[2], "body"), arrays)
    _check_qualifier(topic, kind, body)
    return Message(
        type=kind,
        body=body,
        t_capture_s=float(header["t_capture_s"]),
        topic=topic,
        source=header["source"],
        seq=int(header["seq"]),
        t_send_ns=int(header["t_send_ns"]),
    )


def claimed_source(frames: Sequence[Any]) -> str | None:
    """The ``source`` a refused message's header names, for saying who sent it; None when the
    header cannot be read within the limits or names no source. Never raises.

    Only what the sender claims: on a CURVE bus, a sender the server admitted.
    """
    try:
        if len(frames) < 2 or _frame_bytes(frames[1]).nbytes > MAX_HEADER_BYTES:
            return None
        source = _unpack(_frame_bytes(frames[1]), "header").get("source")
    except MessageRejected:
        return None
    return source[:MAX_SOURCE_SHOWN] if isinstance(source, str) and source else None


def now_ns() -> int:
    """The send clock: ``time.monotonic_ns()`` (see the module docstring)."""
    return time.monotonic_ns()
