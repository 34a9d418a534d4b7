"""The wire format: round trips, zero-copy arrays, every refusal reason, fuzzing."""

from __future__ import annotations

import contextlib
import dataclasses
import math

import cv2
import msgpack
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from teleop.bus.field_checks import MAX_TIME_S
from teleop.bus.messages import MAX_PARAMS
from teleop.bus.wire import (
    MAX_BODY_BYTES,
    MAX_HEADER_BYTES,
    REJECT_REASONS,
    SCHEMAS,
    Message,
    decode,
    encode,
    make_message,
)
from teleop.errors import BusError, MessageRejected

MAX = 16 * 1024 * 1024


def _jpeg() -> bytes:
    image = np.random.default_rng(0).integers(0, 255, (24, 32, 3), dtype=np.uint8)
    return cv2.imencode(".jpg", image)[1].tobytes()


def _examples() -> dict[str, Message]:
    """One valid message of every type (arrays of several dtypes among them)."""
    rng = np.random.default_rng(1)
    return {
        "frame_jpeg": make_message("frame", t_capture_s=1.5, finger="left", grasp_id="g1", index=7, encoding="jpeg", data=_jpeg()),
        "frame_raw_u8": make_message(
            "frame", t_capture_s=1.5, finger="right", index=0, encoding="raw",
            data=rng.integers(0, 255, (30, 40, 3), dtype=np.uint8),
        ),
        "frame_raw_u16": make_message(
            "frame", t_capture_s=1.5, finger="right", index=1, encoding="raw",
            data=rng.integers(0, 65535, (30, 40, 3), dtype=np.uint16),
        ),
        "force_f8": make_message("force", t_capture_s=2.0, grasp_id="g1", t_s=np.linspace(1.9, 2.0, 9), value_n=rng.normal(size=9)),
        "force_f4": make_message(
            "force", t_capture_s=2.0, t_s=np.linspace(1.9, 2.0, 9), value_n=rng.normal(size=9).astype(np.float32)
        ),
        "force_big_endian": make_message(
            "force", t_capture_s=2.0, t_s=np.linspace(1.9, 2.0, 4).astype(">f8"), value_n=np.ones(4, dtype=">f8")
        ),
        "width": make_message("width", t_capture_s=2.0, grasp_id="g1", t_s=[1.95], value_m=[0.031]),
        "grasp_start": make_message("grasp_event", t_capture_s=0.5, event="start", grasp_id="g1", object_name="sponge"),
        "grasp_end": make_message("grasp_event", t_capture_s=3.5, event="end", grasp_id="g1"),
        "estimate_ok": make_message(
            "estimate", t_capture_s=2.1, grasp_id="g1", method="series", E_pa=2.5e5, interval_pa=[1e5, 6e5],
            state="ok", reason="", provisional=True, latency_s=0.012,
        ),
        "estimate_bound": make_message(
            "estimate", t_capture_s=2.1, grasp_id="g1", method="series", E_pa=3e9, interval_pa=[3e9, None],
            state="lower_bound", reason="depth below resolution", provisional=False, latency_s=0.02,
        ),
        "estimate_none": make_message(
            "estimate", t_capture_s=2.1, grasp_id="g1", method="hertz", E_pa=None, interval_pa=[None, None],
            state="insufficient_data", reason="no contact", provisional=False, latency_s=0.0,
        ),
        "command": make_message("command", t_capture_s=0.0, action="start_grasp", grasp_id="g2", params={"target_force_n": 20, "hold_s": 0.5}),
        "heartbeat": make_message("heartbeat", t_capture_s=10.0, interval_s=0.5),
        "display_active": make_message(
            "display", t_capture_s=2.2, grasp_id="g1", phase="active", stiffness=0.42, uncertainty_decades=0.3,
            rigid=False, unknown=False, provisional=True, E_pa=1.2e5, level=1720, level_max=4095,
        ),
        "display_idle": make_message(
            "display", t_capture_s=9.0, phase="idle", stiffness=0.0, uncertainty_decades=0.0,
            rigid=False, unknown=False, provisional=False,
        ),
        "follow": make_message("follow", t_capture_s=3.0, grasp_id="g3", target_width_m=0.042, enable=True),
        "follow_released": make_message("follow", t_capture_s=3.0, target_width_m=0.08, enable=False),
        "robot_state": make_message("robot_state", t_capture_s=3.1, mode="following", grasp_id="g3",
                                    target_width_m=0.042, enable=True),
        "robot_state_idle": make_message("robot_state", t_capture_s=3.1, mode="idle", enable=False),
        "robot_notice": make_message("robot_notice", t_capture_s=3.2, event="watchdog", action="follow",
                                     grasp_id="g3", reason="no follow command for 0.2 s"),
        "estimate_model": make_message(
            "estimate", t_capture_s=2.1, grasp_id="g1", method="auto", E_pa=2e5, interval_pa=[1e5, 4e5],
            state="ok", reason="", provisional=False, latency_s=0.003, model="default-3f2a9c1e",
        ),
        "label": make_message("label", t_capture_s=4.0, grasp_id="g3", object_name="tennis_ball",
                              modulus_pa=None, source="catalogue", detail="configs/objects.toml"),
        "label_durometer": make_message("label", t_capture_s=4.0, grasp_id="g4", object_name="pad",
                                        modulus_pa=1.2e6, source="durometer", detail="Shore A 40 (Gent)"),
        "load_model": make_message("load_model", t_capture_s=5.0, path="/models/fine-tuned", request="r1"),
        "model_event": make_message("model_event", t_capture_s=5.1, event="loaded", request="r1",
                                    model="fine-tuned-9b1d", path="/models/fine-tuned", reason=""),
        "model_event_refused": make_message("model_event", t_capture_s=5.1, event="refused", request="r2",
                                            reason="no metadata.json in /tmp/x"),
    }


EXAMPLES = _examples()


def _stamp(message: Message) -> Message:
    return Message(
        type=message.type, body=message.body, t_capture_s=message.t_capture_s, topic=message.topic,
        source="robot", seq=41, t_send_ns=123_456_789,
    )


def _same(a, b) -> bool:
    if isinstance(a, np.ndarray):
        return isinstance(b, np.ndarray) and a.dtype == b.dtype and a.shape == b.shape and np.array_equal(a, b)
    return a == b and type(a) is type(b)


@pytest.mark.parametrize("name", sorted(EXAMPLES))
def test_round_trip_keeps_every_field(name):
    sent = _stamp(EXAMPLES[name])
    frames = encode(sent)
    got = decode([bytes(f) for f in frames], max_bytes=MAX)
    assert (got.type, got.topic, got.source, got.seq, got.t_send_ns) == (sent.type, sent.topic, "robot", 41, 123_456_789)
    assert got.t_capture_s == sent.t_capture_s
    assert set(got.body) == set(sent.body)
    for key, value in sent.body.items():
        assert _same(value, got.body[key]), key


def test_every_type_has_an_example():
    assert {m.type for m in EXAMPLES.values()} == set(SCHEMAS)


@pytest.mark.parametrize("name", ["frame_raw_u8", "frame_raw_u16", "force_f4", "force_f8", "force_big_endian"])
def test_arrays_are_neither_copied_on_encode_nor_on_decode(name):
    message = EXAMPLES[name]
    arrays = {k: v for k, v in message.body.items() if isinstance(v, np.ndarray)}
    frames = encode(message)
    buffers = frames[3:]
    assert len(buffers) == len(arrays)
    for buffer, array in zip(buffers, arrays.values(), strict=True):
        assert isinstance(buffer, memoryview)
        assert np.shares_memory(np.frombuffer(buffer, dtype=np.uint8), array)
    received = [bytearray(f) for f in frames]  # one receive buffer per frame, as zmq hands them out
    got = decode(received, max_bytes=MAX)
    for index, key in enumerate(arrays):
        view = got.body[key]
        assert np.shares_memory(view, np.frombuffer(received[3 + index], dtype=np.uint8))
        assert not view.flags.writeable  # a receiver cannot scribble on a shared buffer


def test_topics_name_the_type_and_the_finger():
    assert EXAMPLES["frame_jpeg"].topic == "frame/left"
    assert EXAMPLES["estimate_ok"].topic == "estimate"


def test_scalars_become_one_sample_arrays_and_bytes_uint8():
    m = make_message("force", t_capture_s=1.0, t_s=1.0, value_n=2.5)
    assert m.body["t_s"].dtype == np.float64 and m.body["t_s"].shape == (1,)
    frame = EXAMPLES["frame_jpeg"].body["data"]
    assert frame.dtype == np.uint8 and frame.ndim == 1


# --------------------------------------------------------------------------- refusals


def _frames(name: str = "force_f8") -> list[bytes]:
    return [bytes(f) for f in encode(_stamp(EXAMPLES[name]))]


def _with_header(frames: list[bytes], **changes) -> list[bytes]:
    header = msgpack.unpackb(frames[1])
    header.update(changes)
    return [frames[0], msgpack.packb(header), *frames[2:]]


def _with_body(frames: list[bytes], drop: str | None = None, **changes) -> list[bytes]:
    body = msgpack.unpackb(frames[2])
    body.update(changes)
    if drop:
        del body[drop]
    return [frames[0], frames[1], msgpack.packb(body), *frames[3:]]


def _refused(frames, *, max_bytes: int = MAX) -> str:
    with pytest.raises(MessageRejected) as info:
        decode(frames, max_bytes=max_bytes)
    assert info.value.reason in REJECT_REASONS
    return info.value.reason


def test_unknown_version():
    assert _refused(_with_header(_frames(), v=2)) == "unknown_version"
    assert _refused(_with_header(_frames(), v=1.0)) == "unknown_version"


def test_unknown_type():
    assert _refused(_with_header(_frames(), type="teleport")) == "unknown_type"


def test_oversize_is_checked_before_unpacking():
    frames = _frames("frame_raw_u8")
    assert _refused(frames, max_bytes=sum(len(f) for f in frames) - 1) == "oversize"
    # a header or body over its own limit is refused without being unpacked, even if valid msgpack
    assert _refused([frames[0], b"\x80" + b"\x00" * MAX_HEADER_BYTES, frames[2]]) == "oversize"
    assert _refused([frames[0], frames[1], b"\x00" * (MAX_BODY_BYTES + 1)]) == "oversize"


def test_corrupt_msgpack():
    frames = _frames()
    assert _refused([frames[0], b"\xc1garbage", *frames[2:]]) == "corrupt"
    assert _refused([frames[0], frames[1], frames[2][:-3], *frames[3:]]) == "corrupt"
    assert _refused([frames[0], msgpack.packb([1, 2, 3]), *frames[2:]]) == "corrupt"
    assert _refused([b"\xff\xfe", *frames[1:]]) == "corrupt"


def test_buffer_size_must_match_dtype_times_shape():
    frames = _frames()
    assert _refused([*frames[:3], frames[3][:-8], frames[4]]) == "bad_buffer"
    assert _refused(_with_header(frames, buffers=[["t_s", "<f8", [9]], ["value_n", "<f8", [10]]])) == "bad_buffer"
    assert _refused(_with_header(frames, buffers=[["t_s", "|O", [9]], ["value_n", "<f8", [9]]])) == "bad_buffer"
    assert _refused(frames[:4]) == "bad_buffer"  # header lists two buffers, one came
    assert _refused(_with_header(frames, buffers=[["t_s", "<f8", [9]], ["t_s", "<f8", [9]]])) == "bad_buffer"
    # a third buffer naming one already given would replace it (injected values): each is given once
    header = msgpack.unpackb(frames[1])
    doubled = _with_header(frames, buffers=[*header["buffers"], ["value_n", "<f8", [9]]])
    assert _refused([*doubled, np.full(9, 999.0).tobytes()]) == "bad_buffer"


def test_nan_where_a_finite_number_is_required():
    frames = _frames("estimate_ok")
    assert _refused(_with_body(frames, E_pa=math.nan)) == "not_finite"
    assert _refused(_with_body(frames, latency_s=math.inf)) == "not_finite"
    assert _refused(_with_header(frames, t_capture_s=math.nan)) == "not_finite"
    force = _frames()
    poisoned = np.frombuffer(force[4], dtype="<f8").copy()
    poisoned[3] = np.nan
    assert _refused([*force[:4], poisoned.tobytes()]) == "not_finite"


def test_a_time_no_clock_reaches_is_refused():
    # 1e19 s overflowed the session log's nanoseconds and crashed the recorder; 1e300 as a grasp's
    # first sample made every later one "not after the previous one".
    frames = _frames("estimate_ok")
    assert _refused(_with_header(frames, t_capture_s=1e19)) == "bad_header"
    assert _refused(_with_header(frames, t_capture_s=-1.7e308)) == "bad_header"
    force = _frames()
    late = np.frombuffer(force[3], dtype="<f8").copy()
    late[0] = 1e300
    assert _refused([*force[:3], late.tobytes(), force[4]]) == "mistyped_field"
    assert decode(force, max_bytes=MAX).t_capture_s < MAX_TIME_S  # a real time passes


def test_missing_extra_and_mistyped_fields():
    frames = _frames("estimate_ok")
    assert _refused(_with_body(frames, drop="state")) == "missing_field"
    assert _refused(_with_body(frames, colour="red")) == "extra_field"
    assert _refused(_with_body(frames, state="great")) == "mistyped_field"
    assert _refused(_with_body(frames, provisional=1)) == "mistyped_field"
    assert _refused(_with_body(frames, E_pa=-5.0)) == "mistyped_field"
    assert _refused(_with_body(frames, interval_pa=[5e5, 1e5])) == "mistyped_field"
    assert _refused(_with_body(frames, E_pa="1e5")) == "mistyped_field"
    assert _refused(_with_header(frames, seq=-1)) == "bad_header"
    assert _refused(_with_header(frames, extra=1)) == "bad_header"


def _made_refused(type_: str, **fields) -> MessageRejected:
    """The refusal of ``make_message(type_, **fields)``: what a sender is told."""
    with pytest.raises(MessageRejected) as refused:
        make_message(type_, **fields)
    return refused.value


def test_an_interval_whose_low_is_above_its_high_is_refused():
    estimate = dict(t_capture_s=2.1, grasp_id="g1", method="hertz", E_pa=None, state="insufficient_data",
                    reason="too short", provisional=False, latency_s=0.001)
    refused = _made_refused("estimate", interval_pa=[6e5, 1e5], **estimate)
    assert refused.reason == "mistyped_field" and "low is above high" in str(refused)
    make_message("estimate", interval_pa=[1e5, 1e5], **estimate)  # equal sides: a point interval


def test_command_params_hold_at_most_max_params_names():
    full = {f"p{i}": float(i) for i in range(MAX_PARAMS)}
    command = dict(t_capture_s=0.0, action="start_grasp", grasp_id="g2")
    message = make_message("command", params=full, **command)
    assert decode(encode(message, max_bytes=MAX), max_bytes=MAX).fields.params == full
    refused = _made_refused("command", params={**full, "one_more": 1.0}, **command)
    assert refused.reason == "mistyped_field" and f"at most {MAX_PARAMS}" in str(refused)


@pytest.mark.parametrize("t", [-1e300, -2 * MAX_TIME_S])
def test_a_sample_time_far_below_any_clock_is_refused_as_one_far_above(t):
    # magnitude, not value: -1e300 overflows the session log's nanoseconds as 1e300 does
    refused = _made_refused("force", t_capture_s=2.0, grasp_id="g1", t_s=np.array([t, 2.0]),
                            value_n=np.array([1.0, 2.0]))
    assert refused.reason == "mistyped_field" and "in magnitude" in str(refused)


@pytest.mark.parametrize("flag", [True, np.bool_(False)])
def test_a_flag_is_no_integer(flag):
    # index=True would be stored as frame 1
    refused = _made_refused("frame", t_capture_s=1.5, finger="left", grasp_id="g1", index=flag, encoding="jpeg",
                            data=b"\xff\xd8\xff\xd9")
    assert refused.reason == "mistyped_field" and "must be an integer" in str(refused)


def test_frame_count_and_topic():
    frames = _frames()
    assert _refused(frames[:2]) == "frame_count"
    assert _refused([*frames, *([b"x"] * 8)]) == "frame_count"
    assert _refused([b"width", *frames[1:]]) == "bad_header"


def test_frame_data_must_be_what_its_encoding_says():
    frames = _frames("frame_jpeg")
    png_claim = _with_body(frames, encoding="png")
    assert _refused(png_claim) == "mistyped_field"


def _refusal(frames, *, max_bytes: int = MAX) -> MessageRejected:
    with pytest.raises(MessageRejected) as info:
        decode(frames, max_bytes=max_bytes)
    return info.value


@pytest.mark.parametrize("shape", [[0, 2**64 - 1], [0, 2**63], [2**40, 0, 2**40]])
def test_an_empty_buffer_of_sizes_no_message_carries_is_refused(shape):
    # A 0 made the byte count match the empty frame; numpy's reshape then raised a bare ValueError
    # that no subscriber caught.
    frames = _with_header(_frames(), buffers=[["t_s", "<f8", shape], ["value_n", "<f8", [9]]])
    refusal = _refusal([*frames[:3], b"", frames[4]])
    assert refusal.reason == "bad_buffer"
    assert "'t_s'" in refusal.detail and str(shape) in refusal.detail


def test_an_empty_raw_image_is_refused_by_sender_and_receiver():
    empty = dict(t_capture_s=1.0, finger="left", index=0, encoding="raw")
    for shape in [(0, 4, 3), (4, 0, 3), (0, 0, 3)]:
        with pytest.raises(MessageRejected, match=r"frame\.data is empty") as info:
            make_message("frame", data=np.zeros(shape, np.uint8), **empty)
        assert info.value.reason == "mistyped_field"
    frames = _with_header(_frames("frame_raw_u8"), buffers=[["data", "|u1", [0, 0, 3]]])
    refusal = _refusal([*frames[:3], b""])
    assert refusal.reason == "mistyped_field" and "frame.data is empty" in refusal.detail


def test_the_topic_names_the_finger_the_body_names():
    frames = _frames("frame_jpeg")  # finger "left"
    refusal = _refusal([b"frame/right", *frames[1:]])
    assert refusal.reason == "bad_header"
    assert "'frame/right'" in refusal.detail and "frame.finger is 'left'" in refusal.detail
    assert _refused([b"frame/left/more", *frames[1:]]) == "bad_header"
    assert decode([b"frame", *frames[1:]], max_bytes=MAX).fields.finger == "left"  # no qualifier: nothing to disagree
    with pytest.raises(MessageRejected, match="frame.finger is 'left'"):
        encode(_stamp(dataclasses.replace(EXAMPLES["frame_jpeg"], topic="frame/right")))


@pytest.mark.parametrize("name", ["force_f8", "width", "estimate_ok", "heartbeat", "grasp_start", "command"])
def test_a_made_up_qualifier_on_a_type_that_declares_none_is_refused(name):
    """Only ``frame`` names a body field in its topic: any other ``<type>/...`` is the sender's own
    invention, and each would be one more entry in its receivers' per-topic tables and logs."""
    kind = EXAMPLES[name].type
    frames = _frames(name)
    assert decode([kind.encode(), *frames[1:]], max_bytes=MAX).topic == kind
    for topic in (f"{kind}/{7:0200d}", f"{kind}/left", f"{kind}/"):
        refusal = _refusal([topic.encode(), *frames[1:]])
        assert refusal.reason == "bad_header"
        assert f"has a qualifier, but {kind} declares none: its topic is {kind!r}" in refusal.detail
    with pytest.raises(MessageRejected, match=f"but {kind} declares none") as info:
        encode(_stamp(dataclasses.replace(EXAMPLES[name], topic=f"{kind}/extra")))
    assert info.value.reason == "bad_header"


def test_a_frame_topic_names_its_finger_or_nothing():
    frames = _frames("frame_jpeg")  # finger "left"
    assert decode([b"frame/left", *frames[1:]], max_bytes=MAX).topic == "frame/left"
    refusal = _refusal([b"frame/", *frames[1:]])  # an empty qualifier is not the finger either
    assert refusal.reason == "bad_header" and "names '', but frame.finger is 'left'" in refusal.detail


def test_a_body_nested_too_deep_is_refused_saying_so():
    frames = _frames()
    refusal = _refusal([*frames[:2], b"\x81\xa1a" * 20000 + b"\xc0", *frames[3:]])
    assert refusal.reason == "corrupt"
    assert refusal.detail == "body is not valid msgpack within the limits (nested too deep)"


def test_estimate_states_are_consistent():
    base = dict(grasp_id="g", method="series", interval_pa=[None, None], reason="", provisional=False, latency_s=0.0)
    with pytest.raises(MessageRejected, match="no E_pa"):
        make_message("estimate", t_capture_s=0.0, E_pa=None, state="ok", **base)
    with pytest.raises(MessageRejected, match="carries an E_pa"):
        make_message("estimate", t_capture_s=0.0, E_pa=1e5, state="insufficient_data", **base)


def test_display_fields_are_checked():
    frames = _frames("display_active")
    assert decode(frames, max_bytes=MAX).body["level"] == 1720
    idle = decode(_frames("display_idle"), max_bytes=MAX).body
    assert (idle["grasp_id"], idle["E_pa"], idle["level"], idle["level_max"]) == (None, None, None, None)
    assert _refused(_with_body(frames, drop="phase")) == "missing_field"
    assert _refused(_with_body(frames, drop="E_pa")) == "missing_field"  # nullable, but always present on the wire
    assert _refused(_with_body(frames, stale=True)) == "extra_field"
    refusals = {
        "phase": ("resting", "mistyped_field"),
        "stiffness": (1.5, "mistyped_field"),
        "uncertainty_decades": (-0.1, "mistyped_field"),
        "rigid": (1, "mistyped_field"),
        "provisional": (None, "mistyped_field"),
        "E_pa": (0.0, "mistyped_field"),
        "level": (-1, "mistyped_field"),
        "level_max": (0, "mistyped_field"),
        "grasp_id": (7, "mistyped_field"),
    }
    for field, (value, reason) in refusals.items():
        assert _refused(_with_body(frames, **{field: value})) == reason, field
    assert _refused(_with_body(frames, stiffness=-0.01)) == "mistyped_field"
    assert _refused(_with_body(frames, stiffness=math.nan)) == "not_finite"
    assert _refused(_with_body(frames, E_pa=math.inf)) == "not_finite"
    assert _refused(_with_body(frames, level=2.0)) == "mistyped_field"
    assert _refused(_with_body(frames, level=4096)) == "mistyped_field"  # above level_max
    assert _refused(_with_body(frames, level_max=None)) == "mistyped_field"  # a level needs its full scale
    assert _refused(_with_body(frames, rigid=True, unknown=True)) == "mistyped_field"
    # E_pa is the modulus of a stiffness on the display: there exactly when stiffness > 0 and not unknown.
    assert _refused(_with_body(frames, E_pa=None)) == "mistyped_field"
    assert _refused(_with_body(frames, unknown=True)) == "mistyped_field"
    assert _refused(_with_body(_frames("display_idle"), E_pa=5e3)) == "mistyped_field"
    unknown = _with_body(frames, unknown=True, E_pa=None)
    assert decode(unknown, max_bytes=MAX).body["unknown"] is True
    with pytest.raises(MessageRejected, match="stiffness"):
        make_message("display", t_capture_s=0.0, phase="active", stiffness=1.0001, uncertainty_decades=0.0,
                     rigid=True, unknown=False, provisional=False, E_pa=1e6)


def test_operator_and_robot_state_fields_are_checked():
    idle = decode(_frames("robot_state_idle"), max_bytes=MAX).body
    assert (idle["grasp_id"], idle["target_width_m"]) == (None, None)
    refusals = {
        "follow": {"target_width_m": (-0.001, "mistyped_field"), "enable": (1, "mistyped_field"),
                   "grasp_id": (3, "mistyped_field")},
        "robot_state": {"mode": ("dancing", "mistyped_field"), "target_width_m": (-1.0, "mistyped_field"),
                        "enable": (None, "mistyped_field")},
        "robot_notice": {"event": ("oops", "mistyped_field"), "action": (None, "mistyped_field"),
                         "reason": ("x" * 2000, "mistyped_field")},
    }
    for kind, fields in refusals.items():
        frames = _frames(kind)
        for field, (value, reason) in fields.items():
            assert _refused(_with_body(frames, **{field: value})) == reason, (kind, field)
        assert _refused(_with_body(frames, colour="red")) == "extra_field"
    assert _refused(_with_body(_frames("follow"), drop="enable")) == "missing_field"
    assert _refused(_with_body(_frames("follow"), target_width_m=math.nan)) == "not_finite"
    assert _refused(_with_body(_frames("robot_state"), target_width_m=math.inf)) == "not_finite"


def test_an_estimate_from_before_the_model_field_reads_as_no_model():
    # Session logs and senders that predate the field: a receiver fills it with nil.
    old = _with_body(_frames("estimate_model"), drop="model")
    assert decode(old, max_bytes=MAX).body["model"] is None
    assert decode(_frames("estimate_model"), max_bytes=MAX).body["model"] == "default-3f2a9c1e"
    assert make_message("estimate", t_capture_s=0.0, grasp_id="g", method="series", E_pa=1e5,
                        interval_pa=[None, None], state="ok", reason="", provisional=True,
                        latency_s=0.0).body["model"] is None  # senders always send it


def test_label_and_model_messages_are_checked():
    refusals = {
        "label": {"source": ("guess", "mistyped_field"), "modulus_pa": (0.0, "mistyped_field"),
                  "object_name": (None, "mistyped_field")},
        "load_model": {"path": (None, "mistyped_field"), "request": (7, "mistyped_field")},
        "model_event": {"event": ("maybe", "mistyped_field"), "model": ("x" * 65, "mistyped_field")},
    }
    for kind, fields in refusals.items():
        frames = _frames(kind)
        for field, (value, reason) in fields.items():
            assert _refused(_with_body(frames, **{field: value})) == reason, (kind, field)
        assert _refused(_with_body(frames, colour="red")) == "extra_field"
    assert _refused(_with_body(_frames("label"), drop="source")) == "missing_field"
    assert _refused(_with_body(_frames("label_durometer"), modulus_pa=math.inf)) == "not_finite"


def test_senders_cannot_emit_what_receivers_refuse():
    with pytest.raises(MessageRejected) as info:
        make_message("force", t_capture_s=0.0, t_s=[0.0, 1.0], value_n=[1.0, np.nan])
    assert info.value.reason == "not_finite"
    with pytest.raises(MessageRejected) as info:
        make_message("force", t_capture_s=0.0, t_s=np.zeros(3, np.float32), value_n=np.zeros(3))
    assert info.value.reason == "mistyped_field"  # float32 timestamps are refused, never cast
    with pytest.raises(MessageRejected) as info:
        make_message("width", t_capture_s=0.0, t_s=[0.0, 1.0], value_m=[1.0])
    assert info.value.reason == "mistyped_field"
    with pytest.raises(MessageRejected) as info:
        encode(EXAMPLES["frame_raw_u8"], max_bytes=1000)
    assert info.value.reason == "oversize"
    with pytest.raises(MessageRejected):
        make_message("nonsense", t_capture_s=0.0)
    assert isinstance(info.value, BusError)


# --------------------------------------------------------------------------- fuzzing

FUZZ = settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])


@FUZZ
@given(st.lists(st.binary(max_size=200), min_size=0, max_size=12))
def test_decode_of_random_bytes_raises_only_bus_errors(frames):
    with contextlib.suppress(BusError):
        decode(frames, max_bytes=4096)


_sizes = st.integers(0, 3) | st.integers(2**20, 2**64 - 1)


@FUZZ
@given(st.lists(_sizes, max_size=4), st.lists(_sizes, max_size=4), st.binary(max_size=64))
def test_decode_of_hostile_buffer_shapes_raises_only_refusals(t_shape, value_shape, data):
    frames = _with_header(_frames(), buffers=[["t_s", "<f8", t_shape], ["value_n", "<f8", value_shape]])
    with contextlib.suppress(MessageRejected):
        decode([*frames[:3], data, data], max_bytes=MAX)


_msgpack_values = st.recursive(
    st.none() | st.booleans() | st.integers(-(2**63), 2**64 - 1) | st.floats() | st.text(max_size=20) | st.binary(max_size=20),
    lambda inner: st.lists(inner, max_size=5) | st.dictionaries(st.text(max_size=12), inner, max_size=5),
    max_leaves=20,
)


@pytest.mark.slow
@settings(max_examples=120, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    st.sampled_from(sorted(EXAMPLES)),
    st.dictionaries(st.sampled_from(["v", "type", "source", "seq", "t_capture_s", "t_send_ns", "buffers", "x"]), _msgpack_values),
    st.dictionaries(st.text(max_size=12), _msgpack_values, max_size=10),
    st.booleans(),
)
def test_decode_of_random_msgpack_fields_raises_only_bus_errors(name, header_changes, body, replace_body):
    frames = _with_header(_frames(name), **header_changes)
    if replace_body:
        frames = [frames[0], frames[1], msgpack.packb(body), *frames[3:]]
    with contextlib.suppress(BusError):
        decode(frames, max_bytes=MAX)


@FUZZ
@given(st.sampled_from(sorted(EXAMPLES)), st.data())
def test_decode_of_damaged_valid_messages_raises_only_bus_errors(name, data):
    frames = [bytearray(f) for f in _frames(name)]
    which = data.draw(st.integers(0, len(frames) - 1))
    if frames[which]:
        position = data.draw(st.integers(0, len(frames[which]) - 1))
        frames[which][position] = data.draw(st.integers(0, 255))
    cut = data.draw(st.integers(0, len(frames[which])))
    frames[which] = frames[which][:cut] if data.draw(st.booleans()) else frames[which]
    with contextlib.suppress(BusError):
        decode(frames, max_bytes=MAX)
