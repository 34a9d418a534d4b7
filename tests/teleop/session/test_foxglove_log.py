"""Session logs Foxglove reads: every Foxglove channel decodes through its declared schema with
no project code, JPEG bytes are stored once, the bus messages still read back byte-exact, and a
log at its channel cap keeps writing on the channels it has."""

from __future__ import annotations

import dataclasses
import io
import json
import math
from collections import Counter
from dataclasses import dataclass
from pathlib import Path

import jsonschema
import numpy as np
import pytest
from google.protobuf.descriptor_pb2 import FileDescriptorSet
from google.protobuf.descriptor_pool import DescriptorPool
from google.protobuf.message_factory import GetMessageClass
from mcap.reader import make_reader
from mcap.writer import Writer
from mcap_protobuf.decoder import DecoderFactory

from teleop.bus import Publisher
from teleop.bus.wire import SCHEMAS, encode, make_message
from teleop.catalogue import default_catalogue_path
from teleop.session import LogReader, recover
from teleop.session.foxglove import json_schema
from teleop.session.foxglove_log import LogChannels
from teleop.session.logfile import (
    BUS_ENCODINGS,
    FORMAT_VERSION,
    MESSAGE_ENCODING,
    RIG_METADATA,
    SESSION_METADATA,
)
from teleop.session.logframes import elides, pack_frames
from teleop.settings import config_dir


def _wire_bytes(message) -> list[bytes]:
    return [bytes(memoryview(frame).cast("B")) for frame in encode(message)]


def _display(pub: Publisher, t: float, **body):
    base = dict(grasp_id="g0", phase="active", stiffness=0.4, uncertainty_decades=0.3,
                rigid=False, unknown=False, provisional=True, E_pa=2e5, level=40, level_max=100)
    return pub.send("display", t_capture_s=t, **{**base, **body})


@dataclass(frozen=True)
class Session:
    path: Path
    sent: list


@pytest.fixture(scope="module")
def session(tmp_path_factory, session_settings, helpers) -> Session:
    """The shared synthetic session plus display reports and a raw (uncompressed) frame."""
    path = tmp_path_factory.mktemp("foxglove") / "session.mcap"
    with (
        Publisher("tcp://127.0.0.1:*", lossless=True, source="robot") as pub,
        helpers.recording(path, [pub.endpoint], settings=session_settings, scene="quick",
                          catalogue=default_catalogue_path(), chunk_bytes=8 * 1024) as recorder,
    ):
        pub.wait_for_subscriber("", timeout_s=5.0)
        sent = helpers.publish_session(pub)
        sent += [
            _display(pub, 200.0),
            _display(pub, 200.1, phase="idle", grasp_id=None, stiffness=0.0, E_pa=None,
                     level=None, level_max=None, provisional=False),
            _display(pub, 200.2, stiffness=1.0, rigid=True, E_pa=6.8e6, level=100),
            pub.send("frame", t_capture_s=201.0, finger="left", index=9, encoding="raw",
                     data=np.arange(24, dtype=np.uint8).reshape(2, 4, 3)),
            pub.send("force", t_capture_s=300.02, t_s=[300.0, 300.01, 300.02], value_n=[1.0, 2.0, 3.0]),
        ]
        helpers.wait_for(lambda: recorder.stats.messages == len(sent), what="every message stored")
    assert recorder.stats.error is None
    return Session(path, sent)


def _records(path: Path) -> list:
    """(schema, channel, message) of every stored message, in file order."""
    with path.open("rb") as f:
        return list(make_reader(f).iter_messages(log_time_order=False))


def _protobuf_class(schema):
    """The message class built from the schema's FileDescriptorSet alone (no generated code)."""
    pool = DescriptorPool()
    for file in FileDescriptorSet.FromString(schema.data).file:  # dependencies come first
        pool.Add(file)
    return GetMessageClass(pool.FindMessageTypeByName(schema.name))


def test_every_foxglove_message_decodes_with_its_declared_schema(session):
    seen: Counter[str] = Counter()
    for schema, channel, record in _records(session.path):
        if channel.message_encoding in BUS_ENCODINGS:
            continue
        seen[channel.topic] += 1
        if channel.message_encoding == "protobuf":
            assert schema.encoding == "protobuf"
            decoded = _protobuf_class(schema).FromString(record.data)
            assert decoded.SerializeToString() == record.data  # nothing unknown to the schema
        else:
            assert (channel.message_encoding, schema.encoding) == ("json", "jsonschema")
            jsonschema.validate(json.loads(record.data), json.loads(schema.data))
    # mcap-protobuf-support's decoder agrees on every protobuf channel.
    with session.path.open("rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        protobuf = [c.topic for c in reader.get_summary().channels.values()
                    if c.message_encoding == "protobuf"]
        decoded = list(reader.iter_decoded_messages(topics=protobuf, log_time_order=False))
    assert len(decoded) == sum(seen[t] for t in protobuf)
    sent = session.sent
    frames = Counter(m.body["finger"] for m in sent if m.type == "frame" and m.body["encoding"] != "raw")
    assert seen == {
        "/tactile/left": frames["left"],
        "/tactile/right": frames["right"],
        "/events": sum(m.type == "grasp_event" for m in sent),
        "/force": sum(m.body["t_s"].size for m in sent if m.type == "force"),
        "/width": sum(m.body["t_s"].size for m in sent if m.type == "width"),
        "/estimate": sum(m.type == "estimate" for m in sent),
        "/command": sum(m.type == "command" for m in sent),
        "/display": sum(m.type == "display" for m in sent),
    }


def test_tactile_channels_are_compressed_images_holding_the_camera_bytes(session):
    images = [(c.topic, s.name, d) for s, c, _, d in _decoded(session.path, "/tactile/")]
    sent = [m for m in session.sent if m.type == "frame" and m.body["encoding"] != "raw"]
    offset = LogReader(session.path).info().offset_ns
    assert len(images) == len(sent)
    for (topic, schema_name, image), message in zip(images, sent, strict=True):
        assert schema_name == "foxglove.CompressedImage"
        assert topic == f"/tactile/{message.body['finger']}" == f"/tactile/{image.frame_id}"
        assert image.format == message.body["encoding"]  # "jpeg" left, "png" right
        assert image.data == message.body["data"].tobytes()  # as the camera sent it
        stamp_ns = image.timestamp.seconds * 10**9 + image.timestamp.nanos  # on the log's clock
        assert stamp_ns == round(message.t_capture_s * 1e9) + offset
    assert {i.format for _, _, i in images} == {"jpeg", "png"}


def _decoded(path: Path, prefix: str) -> list:
    with path.open("rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        topics = [c.topic for c in reader.get_summary().channels.values() if c.topic.startswith(prefix)]
        return list(reader.iter_decoded_messages(topics=topics, log_time_order=False))


def test_grasp_events_are_log_lines(session):
    lines = [d for *_, d in _decoded(session.path, "/events")]
    events = [m for m in session.sent if m.type == "grasp_event"]
    assert [line.message for line in lines][:2] == [
        "grasp g0 start (object: stress_ball)",
        "grasp g0 end (object: stress_ball)",
    ]
    assert all(line.level == 2 and line.name == "robot" for line in lines)  # INFO
    assert len(lines) == len(events)


def test_json_messages_carry_the_values_and_their_log10_forms(session):
    records = _records(session.path)
    estimates = [json.loads(r.data) for _, c, r in records if c.topic == "/estimate"]
    sent = [m for m in session.sent if m.type == "estimate"]
    for got, message in zip(estimates, sent, strict=True):
        assert got.get("E_pa") == message.body["E_pa"] and got["state"] == message.body["state"]
        low, high = message.body["interval_pa"]
        assert (got["interval_pa"].get("low"), got["interval_pa"].get("high")) == (low, high)
        if message.body["E_pa"] is None:  # nil is left out
            assert "log10_E_pa" not in got and "E_pa" not in got
        else:
            assert got["log10_E_pa"] == pytest.approx(math.log10(message.body["E_pa"]))
        assert got["interval_pa"].get("log10_low") == (None if low is None else pytest.approx(math.log10(low)))
    # One message per force sample, each at its own time (test_sample_times_are_... below).
    force = [(r.log_time, json.loads(r.data)) for _, c, r in records if c.topic == "/force"]
    values = np.concatenate([m.body["value_n"] for m in session.sent if m.type == "force"])
    assert [f["value_n"] for _, f in force] == pytest.approx(values.astype(float).tolist())
    assert [f["t_s"] for _, f in force[-3:]] == [300.0, 300.01, 300.02]
    received = [r.log_time for _, c, r in records if c.topic == "force"][-1]
    assert force[-1][0] == received  # the newest sample at the batch's receive time
    assert [t for t, _ in force] == sorted(t for t, _ in force)


class _Writer:
    """Stands in for an MCAP writer: keeps (channel, log time, publish time) per message."""

    def __init__(self):
        self.topics: list[str] = []
        self.messages: list[tuple[str, int, int]] = []

    def register_schema(self, name, encoding, data):
        return 1

    def register_channel(self, topic, encoding, schema, metadata):
        self.topics.append(topic)
        return len(self.topics) - 1

    def add_message(self, channel, *, log_time, data, publish_time, sequence):
        self.messages.append((self.topics[channel], log_time, publish_time))


def test_sample_times_are_the_batch_spacing_and_never_go_back():
    writer = _Writer()
    log = LogChannels(writer, offset_ns=10**18)
    first = make_message("force", t_capture_s=300.02, t_s=[300.0, 300.01, 300.02], value_n=[1.0, 2.0, 3.0])
    # Received 15 ms after the first: its oldest sample (20 ms before) would fall before the
    # first batch's newest, as when delivery latency varies.
    second = make_message("force", t_capture_s=300.04, t_s=[300.02, 300.03, 300.04], value_n=[4.0, 5.0, 6.0])
    log.write_foxglove(first, 1_000_000_000)
    log.write_foxglove(second, 1_015_000_000)
    times = [t - 10**18 for topic, t, _ in writer.messages if topic == "/force"]
    assert times[:3] == [980_000_000, 990_000_000, 1_000_000_000]  # the batch's spacing
    assert times[3:] == [1_000_000_000, 1_005_000_000, 1_015_000_000]  # the first held back
    log.write_bus(second, encode(second), 1_015_000_000, elide_image=False)
    assert writer.messages[-1] == ("force", 10**18 + 1_015_000_000, 10**18 + second.t_send_ns)


def _write(log: LogChannels, message) -> bool:
    """Write ``message`` as the recorder does: its Foxglove forms, then itself; False when refused."""
    converted = log.convert(message)
    if not log.admits(message, converted):
        return False
    log.write_foxglove(message, 1_000, converted)
    log.write_bus(message, encode(message), 1_000, elide_image=log.carries_image(converted))
    return True


def test_a_log_at_its_channel_cap_still_takes_messages_on_the_channels_it_has():
    writer = _Writer()
    log = LogChannels(writer, max_channels=2)
    assert _write(log, make_message("force", t_capture_s=1.0, t_s=[1.0], value_n=[2.0]))  # force, /force: full
    assert not _write(log, make_message("width", t_capture_s=1.0, t_s=[1.0], value_m=[0.03]))
    assert _write(log, make_message("force", t_capture_s=2.0, t_s=[2.0], value_n=[3.0]))  # no new channel
    assert [topic for topic, *_ in writer.messages] == ["/force", "force", "/force", "force"]


def test_a_sequence_number_past_32_bits_is_written_modulo_2_to_the_32():
    # The wire takes any seq >= 0 from a sender; MCAP's sequence is a uint32.
    buffer = io.BytesIO()
    writer = Writer(buffer)
    writer.start()
    message = dataclasses.replace(make_message("force", t_capture_s=1.0, t_s=[1.0], value_n=[2.0]), seq=2**32 + 5)
    assert _write(LogChannels(writer), message)
    writer.finish()
    buffer.seek(0)
    sequences = {channel.topic: record.sequence for _, channel, record in make_reader(buffer).iter_messages()}
    assert sequences == {"/force": 5, "force": 5}


def test_jpeg_bytes_are_stored_once_and_the_bus_messages_read_back_byte_exact(session):
    records = _records(session.path)
    bus = [r for _, c, r in records if c.message_encoding == MESSAGE_ENCODING]
    for record, message in zip(bus, session.sent, strict=True):
        compressed = message.type == "frame" and message.body["encoding"] != "raw"
        assert elides(record.data) == compressed
        if compressed:  # the image bytes are in the CompressedImage only
            assert message.body["data"].tobytes() not in record.data
            assert len(record.data) < 400
    # The reader puts them back: exactly the ZeroMQ frames the publisher sent.
    logged = list(LogReader(session.path).messages())
    assert len(logged) == len(session.sent)
    for got, message in zip(logged, session.sent, strict=True):
        assert [bytes(f) for f in got.frames] == _wire_bytes(message)
    frames = list(LogReader(session.path).messages(["frame/left"]))  # filtered reads too
    assert [bytes(m.frames[3]) for m in frames] == [
        m.body["data"].tobytes() for m in session.sent if m.topic == "frame/left"]


def test_recovery_keeps_the_foxglove_channels_and_the_elided_frames(session, tmp_path):
    report = recover(session.path, tmp_path / "copy.mcap")
    assert report.messages == len(session.sent) and report.undecodable == 0
    assert len(_records(tmp_path / "copy.mcap")) == len(_records(session.path))
    got = [[bytes(f) for f in m.frames] for m in LogReader(tmp_path / "copy.mcap").messages()]
    assert got == [_wire_bytes(m) for m in session.sent]


def test_settings_stay_attachments_and_the_rig_is_metadata(session, session_settings):
    with session.path.open("rb") as f:
        reader = make_reader(f)
        metadata = {m.name: m.metadata for m in reader.iter_metadata()}
        attachments = {a.name for a in reader.iter_attachments()}
    assert "settings.json" in attachments and "calibration/left/left_cal.npz" in attachments
    rig = metadata[RIG_METADATA]
    assert all(isinstance(v, str) for v in rig.values())
    left, right = session_settings.sensor("left"), session_settings.sensor("right")
    assert float(rig["left.gel_modulus_pa"]) == left.gel_modulus_pa
    assert float(rig["right.gel_thickness_m"]) == right.gel_thickness_m
    assert float(rig["left.pixel_pitch_m"]) == left.pixel_pitch_m
    assert (rig["left.markers"], rig["right.markers"]) == ("false", "true")
    assert float(rig["gripper.finger_stiffness_n_per_m"]) == session_settings.gripper.finger_stiffness_n_per_m
    assert metadata[SESSION_METADATA]["log_format"] == str(FORMAT_VERSION)


def test_format_1_logs_still_read(tmp_path):
    """Before the Foxglove channels: bus channels only, encoding multipart/1, no flags."""
    messages = [
        make_message("frame", t_capture_s=1.0, finger="left", index=0, encoding="jpeg",
                     data=b"\xff\xd8" + bytes(range(50))),
        make_message("force", t_capture_s=1.0, t_s=[1.0], value_n=[2.0]),
    ]
    path = tmp_path / "format1.mcap"
    with path.open("wb") as f:
        writer = Writer(f)
        writer.start("compliance-teleop.session", "old")
        channels = {m.topic: writer.register_channel(m.topic, "compliance-teleop.multipart/1", 0)
                    for m in messages}
        for message in messages:
            writer.add_message(channels[message.topic], log_time=1, publish_time=0,
                               data=pack_frames(encode(message)))
        writer.finish()
    reader = LogReader(path)
    got = [[bytes(f) for f in m.frames] for m in reader.messages()]
    assert got == [_wire_bytes(m) for m in messages] and not reader.refused


def test_an_elided_frame_without_its_image_is_refused_not_yielded(tmp_path):
    frame = make_message("frame", t_capture_s=1.0, finger="left", index=0, encoding="jpeg",
                         data=b"\xff\xd8" + bytes(range(50)))
    force = make_message("force", t_capture_s=1.0, t_s=[1.0], value_n=[2.0])
    path = tmp_path / "orphan.mcap"
    with path.open("wb") as f:
        writer = Writer(f)
        writer.start()
        frames = writer.register_channel("frame/left", MESSAGE_ENCODING, 0)
        forces = writer.register_channel("force", MESSAGE_ENCODING, 0)
        writer.add_message(frames, log_time=1, publish_time=0,
                           data=pack_frames(encode(frame), elide_last=True))
        writer.add_message(forces, log_time=2, publish_time=0, data=pack_frames(encode(force)))
        writer.finish()
    reader = LogReader(path)
    assert [m.message.type for m in reader.messages()] == ["force"]
    assert dict(reader.refused) == {"corrupt": 1}


def _foxglove_reads(schema: dict, where: str) -> None:
    """What Foxglove's JSON Schema reader (parseJsonSchema in foxglove/studio's mcap-support)
    requires: an object with "properties", each with ONE type it knows (no lists, no nulls)."""
    assert schema["type"] == "object" and isinstance(schema["properties"], dict), where
    for name, field in schema["properties"].items():
        assert field.get("type") in ("boolean", "string", "number", "integer", "object"), (
            f"{where}.{name}: {field}")
        if field["type"] == "object":
            _foxglove_reads(field, f"{where}.{name}")


def test_every_bus_type_gets_a_json_schema_foxglove_reads_from_the_wire_table():
    for kind, schema in SCHEMAS.items():
        derived = json_schema(kind)
        jsonschema.Draft202012Validator.check_schema(derived)
        _foxglove_reads(derived, kind)
        assert set(schema.fields) <= set(derived["properties"]), f"{kind}: a field has no JSON form"


def _message_paths(layout: dict) -> set[str]:
    paths = set()
    for config in layout["configById"].values():
        paths |= {p["value"] for p in config.get("paths", [])}
    return paths


def test_the_shipped_layout_shows_channels_and_fields_the_log_has(session):
    layout = json.loads((config_dir() / "foxglove" / "layout.json").read_text())
    configs = layout["configById"]

    def leaves(node):
        return [node] if isinstance(node, str) else leaves(node["first"]) + leaves(node["second"])

    assert sorted(leaves(layout["layout"])) == sorted(configs)
    kinds = Counter(panel.split("!")[0] for panel in configs)
    assert kinds["Image"] == 2 and kinds["Plot"] >= 3 and kinds["RosOut"] == 1
    topics = {c.topic: (s, c) for s, c, _ in _records(session.path)}
    shown = {configs[p]["imageMode"]["imageTopic"] for p in configs if p.startswith("Image!")}
    assert shown == {"/tactile/left", "/tactile/right"}
    assert {configs[p]["topicToRender"] for p in configs if p.startswith("RosOut!")} <= set(topics)
    for path in _message_paths(layout):
        topic, *fields = path.split(".")
        schema, _ = topics[topic]
        node = json.loads(schema.data)
        for name in fields:
            node = node["properties"][name]
        assert "number" in node["type"] or node["type"] in ("string", "boolean"), path
    assert {"/force.value_n", "/width.value_m", "/estimate.log10_E_pa",
            "/estimate.interval_pa.log10_low", "/estimate.interval_pa.log10_high"} <= _message_paths(layout)
