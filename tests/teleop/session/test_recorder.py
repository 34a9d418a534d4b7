"""The recorder: byte-identical messages, encodings, attachments, metadata, refusals, full disks."""

from __future__ import annotations

import errno
import io
import json
import re
import threading
import time

import msgpack
import numpy as np
import pytest
import zmq
from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage
from mcap.reader import make_reader

from teleop.bus import Publisher, Subscriber
from teleop.bus.wire import encode
from teleop.errors import BusError, MessageRejected, SessionLogError, SettingsError
from teleop.session import LogReader, SessionRecorder, recover, session_source
from teleop.session.foxglove import IMAGE_SCHEMA
from teleop.session.logfile import (
    END_METADATA,
    MESSAGE_ENCODING,
    SCHEMA_ENCODING,
    SESSION_METADATA,
    SETTINGS_ATTACHMENT,
)
from teleop.session.logframes import elides, pack_frames, unpack_frames
from teleop.settings import settings_from_mapping


def _wire_bytes(message) -> list[bytes]:
    """What the publisher put on the wire for ``message`` (publish sends exactly encode(sent))."""
    return [bytes(memoryview(frame).cast("B")) for frame in encode(message)]


def test_every_message_is_stored_byte_identical_with_its_times(recorded):
    offset = LogReader(recorded.path).info().offset_ns
    with recorded.path.open("rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        everything = list(reader.iter_messages(log_time_order=False))  # file order
    # Each bus message follows its Foxglove forms; a JPEG or PNG frame's bytes are in its image.
    stored, image = [], None
    for schema, channel, record in everything:
        if channel.message_encoding == MESSAGE_ENCODING:
            stored.append((schema, channel, record, image))
        else:
            image = CompressedImage.FromString(record.data).data if schema.name == IMAGE_SCHEMA else None
    bus_channels = {c.id for c in summary.channels.values() if c.message_encoding == MESSAGE_ENCODING}
    counts = summary.statistics.channel_message_counts
    assert sum(counts[c] for c in bus_channels) == len(recorded.sent) == len(stored)
    assert {summary.channels[c].topic for c in bus_channels} == {m.topic for m in recorded.sent}
    for (schema, channel, record, image), sent in zip(stored, recorded.sent, strict=True):
        assert channel.topic == sent.topic
        assert channel.metadata == {"type": sent.type}
        assert (
            schema.name == f"compliance-teleop/{sent.type}" and schema.encoding == SCHEMA_ENCODING
        )
        assert json.loads(schema.data)["type"] == sent.type
        elided = image if sent.type == "frame" and sent.body["encoding"] != "raw" else None
        assert elides(record.data) == (elided is not None)
        assert [bytes(f) for f in unpack_frames(record.data, elided=elided)] == _wire_bytes(sent)
        assert record.publish_time == sent.t_send_ns + offset  # on the log's (epoch) clock
        assert record.sequence == sent.seq
        assert (
            record.log_time >= record.publish_time
        )  # received after it was sent, one host's clock
    log_times = [record.log_time for _, _, record, _ in stored]
    assert log_times == sorted(log_times)


def test_settings_calibration_catalogue_and_scene_are_attached(recorded):
    with recorded.path.open("rb") as f:
        reader = make_reader(f)
        attachments = {a.name: a.data for a in reader.iter_attachments()}
        metadata = {m.name: m.metadata for m in reader.iter_metadata()}
    settings = settings_from_mapping(json.loads(attachments[SETTINGS_ATTACHMENT]))
    assert settings == recorded.settings
    left = recorded.settings.sensor("left")
    with open(left.calibration, "rb") as cal:
        assert attachments["calibration/left/left_cal.npz"] == cal.read()
    assert b"stress_ball" in attachments["catalogue.toml"]
    assert b"stress_ball" in attachments["scene.toml"]
    session = metadata[SESSION_METADATA]
    assert session["scene"] == "quick" and session["source"] == "simulated"
    assert session["software_version"] and session["start_utc"]
    end = metadata[END_METADATA]
    assert json.loads(end["messages"]) == len(recorded.sent)
    assert json.loads(end["error"]) is None


def test_the_end_metadata_leaves_out_the_file_size_it_cannot_know_yet(recorded):
    """It is written before the summary and footer: a size there would be false (it said 0)."""
    end = LogReader(recorded.path).info().metadata[END_METADATA]
    assert "file_bytes" not in end and json.loads(end["messages"]) == recorded.stats.messages
    assert recorded.stats.file_bytes == recorded.path.stat().st_size  # the stats (`--json`) have it


def test_log_times_are_the_wall_clock_the_session_ran_at(recorded):
    """Log, publish and attachment times are ns since the Unix epoch, not the monotonic clock."""
    with recorded.path.open("rb") as f:
        reader = make_reader(f)
        times = [(r.log_time, r.publish_time) for _, c, r in reader.iter_messages(log_time_order=False)
                 if c.message_encoding == MESSAGE_ENCODING]  # a force sample may be older than the start
        attachments = {a.name: (a.create_time, a.log_time) for a in reader.iter_attachments()}
    info = LogReader(recorded.path).info()
    start, now = int(info.session["start_wall_ns"]), time.time_ns()
    assert info.offset_ns == start - int(info.session["start_monotonic_ns"])
    assert all(start <= t <= now for pair in times for t in pair)
    assert attachments[SETTINGS_ATTACHMENT][0] == start  # made by the recorder as it started
    assert all(start <= log_time <= now and 0 < create <= now for create, log_time in attachments.values())


def test_chunks_are_small(recorded):
    with recorded.path.open("rb") as f:
        summary = make_reader(f).get_summary()
    assert len(summary.chunk_indexes) > 3  # 8 KiB chunks: the session spans several
    assert all(c.uncompressed_size < 8 * 1024 + 4096 for c in summary.chunk_indexes)


def test_pack_and_unpack_frames_round_trip_and_reject_malformed_containers():
    frames = [b"force", b"\x81\xa1v\x01", b"", bytes(range(256))]
    packed = pack_frames(frames)
    assert [bytes(f) for f in unpack_frames(packed)] == frames
    with pytest.raises(MessageRejected) as info:
        unpack_frames(packed[:-1])
    assert info.value.reason == "corrupt"
    with pytest.raises(MessageRejected) as info:
        unpack_frames(pack_frames(frames[:2]))
    assert info.value.reason == "frame_count"
    with pytest.raises(MessageRejected) as info:
        unpack_frames(b"\x05\x00")
    assert info.value.reason == "corrupt"


def test_refused_messages_are_counted_not_stored(tmp_path):
    path = tmp_path / "refused.mcap"
    context = zmq.Context.instance()
    raw = context.socket(zmq.XPUB)
    raw.bind("tcp://127.0.0.1:*")
    endpoint = raw.getsockopt_string(zmq.LAST_ENDPOINT)
    try:
        with SessionRecorder(path, [endpoint]) as recorder:
            raw.poll(5000)
            assert raw.recv()[:1] == b"\x01"  # the recorder's subscription arrived
            header = msgpack.packb({"v": 1, "type": "force"})  # keys missing: bad_header
            raw.send_multipart([b"force", header, msgpack.packb({})])
            raw.send_multipart([b"force", b"\xc1", b"\x80"])  # not msgpack: corrupt
            with Publisher("tcp://127.0.0.1:*", lossless=True, source="robot") as pub:
                good = pub.send("force", t_capture_s=1.0, t_s=[1.0], value_n=[2.0])
                raw.send_multipart(_wire_bytes(good))
            while recorder.stats.messages < 1:
                recorder.poll(0.1)
            stats = recorder.close()
    finally:
        raw.close(linger=0)
    assert stats.messages == 1 and dict(stats.refused) == {"bad_header": 1, "corrupt": 1}
    stored = list(LogReader(path).messages())
    assert [m.frames for m in stored] and [bytes(f) for f in stored[0].frames] == _wire_bytes(good)


def test_source_follows_the_backends(session_settings):
    import dataclasses

    assert session_source(session_settings) == "simulated"
    real = dataclasses.replace(
        session_settings, gripper=dataclasses.replace(session_settings.gripper, backend="franky")
    )
    assert session_source(real) == "hardware"


def test_bad_options_are_refused_naming_them(tmp_path):
    with pytest.raises(SessionLogError, match="compression 'gzip'"):
        SessionRecorder(tmp_path / "x.mcap", "tcp://127.0.0.1:1", compression="gzip")
    with pytest.raises(SessionLogError, match="at least one endpoint"):
        SessionRecorder(tmp_path / "x.mcap", [])
    with pytest.raises(SessionLogError, match="source 'robot'"):
        SessionRecorder(tmp_path / "x.mcap", "tcp://127.0.0.1:1", source="robot")
    with pytest.raises(SessionLogError, match="cannot create session log"):
        SessionRecorder(tmp_path / "no" / "such" / "dir.mcap", "tcp://127.0.0.1:1").open()
    with pytest.raises(SettingsError, match="cannot read catalogue .*absent.toml"):
        SessionRecorder(tmp_path / "x.mcap", "tcp://127.0.0.1:1", catalogue=tmp_path / "absent.toml")


@pytest.mark.parametrize(
    ("text", "problem"),
    [("[[objects]\nname = ", "not valid TOML"), ("", "expected one or more [[objects]] tables")],
)
def test_a_catalogue_that_does_not_load_is_refused_before_recording_naming_it(tmp_path, text, problem):
    # It was attached as it was, and only `teleop export` failed on it, naming a temporary file.
    catalogue = tmp_path / "objects.toml"
    catalogue.write_text(text, encoding="utf-8")
    with pytest.raises(SettingsError, match=f"{catalogue}: {re.escape(problem)}"):
        SessionRecorder(tmp_path / "x.mcap", "tcp://127.0.0.1:1", catalogue=catalogue)
    assert not (tmp_path / "x.mcap").exists()


class DiskThatFills(io.RawIOBase):
    """A file on a disk with ``capacity`` bytes free: a write takes what fits, then ENOSPC."""

    def __init__(self, capacity: int):
        self.data = bytearray()
        self.capacity = capacity
        self.name = "<disk that fills>"

    def writable(self) -> bool:
        return True

    def write(self, b) -> int:
        b = bytes(b)
        room = self.capacity - len(self.data)
        self.data += b[: max(room, 0)]
        if len(b) > room:
            raise OSError(errno.ENOSPC, "No space left on device")
        return len(b)

    def tell(self) -> int:
        return len(self.data)

    def truncate(self, size=None) -> int:
        del self.data[size:]
        return size


def test_disk_full_stops_recording_cleanly_while_the_bus_carries_on(tmp_path, helpers):
    # tcp, as deployed (on inproc libzmq keeps a closed subscriber's full pipe; see the report).
    # Frames large enough that kernel buffers cannot hide a recorder that stopped reading.
    # Room for the attached settings and shipped calibrations (~0.9 MB), far less than is sent.
    disk = DiskThatFills(capacity=2_000_000)
    image = np.random.default_rng(1).integers(0, 256, 60_000, dtype=np.uint8)
    image[:2] = (0xFF, 0xD8)  # a JPEG's magic, enough for the wire's frame check
    with (
        Publisher(
            "tcp://127.0.0.1:*",
            lossless=True,
            source="robot",
            high_water_mark=10,
            send_timeout_s=0.5,
        ) as pub,
        Subscriber(pub.endpoint, ["frame"], high_water_mark=10) as estimator,
        helpers.recording(
            disk, [pub.endpoint], chunk_bytes=16 * 1024, high_water_mark=10
        ) as recorder,
    ):
        pub.wait_for_subscriber("frame/left")
        while not (
            recorder.stats.messages and estimator.heartbeat.last_seen_s("robot") is not None
        ):
            pub.send("heartbeat", t_capture_s=0.0, interval_s=1.0)  # until both are listening
            estimator.recv(timeout_s=0.02)
        received, stop = [], threading.Event()

        def estimate() -> (
            None
        ):  # the estimator reads on its own thread, as it would in its own node
            while not stop.is_set():
                if (message := estimator.recv(timeout_s=0.05)) is not None:
                    received.append(message)

        reader = threading.Thread(target=estimate)
        reader.start()
        # 18 MB for a 2 MB disk; queues hold 20 messages: a recorder not reading would block this.
        try:
            sent = [
                pub.send(
                    "frame",
                    t_capture_s=float(i),
                    finger="left",
                    index=i,
                    encoding="jpeg",
                    data=image,
                )
                for i in range(300)
            ]
            helpers.wait_for(lambda: len(received) == 300, what="the estimator to get every frame")
        finally:
            stop.set()
            reader.join()
        helpers.wait_for(lambda: recorder.failed, what="the recorder to notice the full disk")
    assert [m.body["index"] for m in received] == list(range(300))
    assert recorder.failed and "No space left on device" in recorder.stats.error
    assert len(disk.data) <= disk.capacity
    # Everything before the failing write is intact and readable; nothing after it was left behind.
    log = tmp_path / "full.mcap"
    log.write_bytes(disk.data)
    reader = LogReader(log)
    stored = list(reader.messages())
    assert reader.damage.startswith("the file ends after its last complete record")
    assert recorder.stats.saved_messages >= 1
    assert len(stored) >= recorder.stats.saved_messages
    frames = [logged for logged in stored if logged.message.type == "frame"]
    assert frames
    for logged, original in zip(frames, sent, strict=False):
        assert [bytes(f) for f in logged.frames] == _wire_bytes(original)
    report = recover(log, tmp_path / "fixed.mcap")
    assert report.messages == len(stored) and not report.complete and report.undecodable == 0


def test_a_subscription_that_cannot_start_leaves_no_log(tmp_path):
    path = tmp_path / "never.mcap"
    with pytest.raises(BusError, match="not-an-endpoint"):
        SessionRecorder(path, ["not-an-endpoint"]).open()
    assert not path.exists()
