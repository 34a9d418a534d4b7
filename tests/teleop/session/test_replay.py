"""Replay: the recorded messages back, in process and on the bus, paced and validated."""

from __future__ import annotations

import dataclasses
import shutil

import msgpack
import pytest
from mcap.reader import make_reader
from mcap.writer import Writer
from support.session_logs import register_bus_channel, write_log

from teleop.bus import Publisher, Subscriber
from teleop.bus.wire import encode, make_message
from teleop.errors import SessionLogError
from teleop.session import LogReader, replay, replay_messages
from teleop.session.foxglove import IMAGE_SCHEMA
from teleop.session.label import label_session
from teleop.session.logfile import MESSAGE_ENCODING, PROFILE
from teleop.session.logframes import pack_frames


def _same(a, b, helpers) -> bool:
    return (a.type, a.topic, a.t_capture_s) == (
        b.type,
        b.topic,
        b.t_capture_s,
    ) and helpers.body_equal(a, b)


def test_replay_messages_gives_back_every_message_with_its_original_header(recorded, helpers):
    got = list(replay_messages(recorded.path))
    assert len(got) == len(recorded.sent)
    for message, sent in zip(got, recorded.sent, strict=True):
        assert _same(message, sent, helpers)
        assert (message.source, message.seq, message.t_send_ns) == (
            sent.source,
            sent.seq,
            sent.t_send_ns,
        )


def test_replay_messages_filters_by_topic_prefix(recorded):
    got = list(replay_messages(recorded.path, topics=["frame"]))
    assert {m.topic for m in got} == {"frame/left", "frame/right"}
    assert len(got) == sum(m.type == "frame" for m in recorded.sent)


def test_replay_republishes_the_same_messages_on_the_bus_at_ten_times_speed(recorded, helpers):
    expected = [m for m in recorded.sent if m.type != "heartbeat"]
    with (
        Publisher("tcp://127.0.0.1:*", lossless=True, source="replay") as pub,
        Subscriber(pub.endpoint) as sub,
    ):
        pub.wait_for_subscriber("")
        stats = replay(recorded.path, pub, speed=10.0)
        got = []
        while len(got) < len(expected) and (message := sub.recv(timeout_s=2.0)) is not None:
            got.append(message)
    assert stats.sent == len(expected) and stats.heartbeats_skipped == 1 and not stats.refused
    assert len(got) == len(expected)
    for message, sent in zip(got, expected, strict=True):
        assert _same(message, sent, helpers)
        assert message.source == "replay"
    assert sub.stats.gaps == 0
    # The session was spread over ~0.4 s; at x10 the replay takes a tenth of it, no less.
    assert stats.log_span_s > 0.3
    assert stats.log_span_s / 10 * 0.95 <= stats.wall_s < stats.log_span_s / 10 + 0.5


class _FakeClock:
    def __init__(self):
        self.now = 1000.0

    def __call__(self) -> float:
        return self.now

    def sleep(self, seconds: float) -> None:
        assert seconds > 0
        self.now += seconds


class _RecordingPublisher:
    """Stands in for a Publisher: notes when each message would have been sent."""

    max_bytes = 8 * 1024 * 1024
    heartbeat_s = 0.05

    def __init__(self, clock: _FakeClock):
        self.clock = clock
        self.sent: list[tuple[float, object]] = []
        self.heartbeats = 0

    def publish(self, message):
        self.sent.append((self.clock(), message))
        return message

    def heartbeat_if_due(self, now_s=None):
        self.heartbeats += 1
        return False


@pytest.mark.parametrize("speed", [1.0, 10.0, None])
def test_replay_paces_by_the_receive_times(recorded, speed):
    clock = _FakeClock()
    pub = _RecordingPublisher(clock)
    replay(recorded.path, pub, speed=speed, clock=clock, sleep=clock.sleep)
    log_ns = [
        m.log_time_ns for m in LogReader(recorded.path).messages() if m.message.type != "heartbeat"
    ]
    sent_s = [t for t, _ in pub.sent]
    assert len(sent_s) == len(log_ns)
    for t, ns in zip(sent_s, log_ns, strict=True):
        expected = 0.0 if speed is None else (ns - log_ns[0]) / 1e9 / speed
        assert t - 1000.0 == pytest.approx(expected, abs=1e-6)
    assert pub.heartbeats >= len(sent_s)  # heartbeats kept going, also while waiting


def test_a_labelled_log_replays_each_label_right_after_its_grasp_over_the_whole_span(recorded, tmp_path):
    log = tmp_path / "labelled.mcap"
    shutil.copyfile(recorded.path, log)
    labels = tmp_path / "labels.csv"
    labels.write_text("grasp_id,object\ng0,stress_ball\ng1,stress_ball\n", encoding="utf-8")
    label_session(log, labels)
    clock = _FakeClock()
    pub = _RecordingPublisher(clock)
    stats = replay(log, pub, speed=1.0, topics=("grasp_event", "label"), clock=clock, sleep=clock.sleep)
    sent = [m for _, m in pub.sent]
    assert [m.fields.grasp_id for m in sent if m.type == "label"] == ["g0", "g1"]
    for before, message in zip(sent, sent[1:], strict=False):
        if message.type == "label":  # right after its grasp's (last) end, not at the end of the replay
            assert (before.type, before.fields.event, before.fields.grasp_id) == (
                "grasp_event", "end", message.fields.grasp_id)
    log_ns = [m.log_time_ns for m in LogReader(log).messages(("grasp_event", "label"))]
    assert log_ns == sorted(log_ns)
    assert stats.log_span_s == pytest.approx((log_ns[-1] - log_ns[0]) / 1e9)
    for (t, _), ns in zip(pub.sent, log_ns, strict=True):  # each on time, the labels too
        assert t - 1000.0 == pytest.approx((ns - log_ns[0]) / 1e9, abs=1e-6)


def test_replay_keeps_only_the_publishers_asked_for(recorded):
    clock = _FakeClock()
    every = [m for m in recorded.sent if m.type != "heartbeat"]  # the synthetic session's are all the robot's
    estimator = _RecordingPublisher(clock)
    stats = replay(recorded.path, estimator, speed=None, recorded_from=["estimator"], clock=clock, sleep=clock.sleep)
    assert stats.sent == 0 and not estimator.sent and stats.other_sources == {"robot": len(every)}
    robot = _RecordingPublisher(clock)
    stats = replay(recorded.path, robot, speed=None, recorded_from=["robot", "estimator"], clock=clock,
                   sleep=clock.sleep)
    assert stats.sent == len(robot.sent) == len(every) and not stats.other_sources


def test_replay_refuses_a_bad_speed(recorded):
    with pytest.raises(SessionLogError, match="speed"):
        replay(recorded.path, _RecordingPublisher(_FakeClock()), speed=0.0)


def test_stored_messages_are_validated_before_anyone_sees_them(tmp_path):
    good = encode(make_message("force", t_capture_s=1.0, t_s=[1.0], value_n=[2.0]))
    bad_header = [b"force", msgpack.packb({"v": 1, "type": "force"}), msgpack.packb({})]
    oversize_count = b"\x20\x00\x00\x00"  # claims 32 frames
    path = tmp_path / "tampered.mcap"
    with path.open("wb") as f:
        writer = Writer(f)
        writer.start()
        force = writer.register_channel("force", MESSAGE_ENCODING, 0)
        width = writer.register_channel("width", MESSAGE_ENCODING, 0)
        for channel, data in (
            (force, pack_frames(bad_header)),
            (force, oversize_count),
            (width, pack_frames(good)),
            (force, pack_frames(good)),
        ):
            writer.add_message(channel, log_time=1, data=data, publish_time=0)
        writer.finish()
    reader = LogReader(path)
    got = list(reader.messages())
    assert [m.message.topic for m in got] == ["force"]
    assert dict(reader.refused) == {
        "bad_header": 2,
        "frame_count": 1,
    }  # a force message on the width channel too
    clock = _FakeClock()
    pub = _RecordingPublisher(clock)
    stats = replay(path, pub, speed=None, clock=clock, sleep=clock.sleep)
    assert stats.sent == 1 and sum(stats.refused.values()) == 3


def test_a_file_that_is_not_a_log_is_refused(tmp_path):
    path = tmp_path / "not.mcap"
    path.write_bytes(b"PK\x03\x04 not an mcap file")
    with pytest.raises(SessionLogError, match="not an MCAP"):
        list(replay_messages(path))
    with pytest.raises(SessionLogError, match="cannot read"):
        list(replay_messages(tmp_path / "absent.mcap"))


T0 = 1_700_000_000_000_000_000  # a log time (ns): 2023-11-14


def _event(event, seq):
    message = make_message("grasp_event", t_capture_s=1.0, event=event, grasp_id="g0", object_name=None)
    return dataclasses.replace(message, source="robot", seq=seq)


def test_the_span_reported_covers_a_message_stored_out_of_order(tmp_path):
    """A label an older `teleop label` appended at the end of the file, logged mid-session, does not
    shorten the receive-time span the replay reports."""
    label = dataclasses.replace(
        make_message("label", t_capture_s=1.0, grasp_id="g0", object_name="foam", modulus_pa=5e4,
                     source="datasheet", detail=""),
        source="teleop label", seq=0)
    log = write_log(tmp_path / "s.mcap", [
        (T0, _event("start", 0)),
        (T0 + 2_000_000_000, _event("end", 1)),
        (T0 + 1_000_000_000, label),
    ])
    clock = _FakeClock()
    pub = _RecordingPublisher(clock)
    stats = replay(log, pub, speed=None, clock=clock, sleep=clock.sleep)
    assert stats.sent == len(pub.sent) == 3
    assert stats.log_span_s == 2.0


class _SlowOpeningClock(_FakeClock):
    """Its first reading, as the log is opened, is 10 s before the next: opening the log took 10 s."""

    def __init__(self):
        super().__init__()
        self.readings = 0

    def __call__(self) -> float:
        self.readings += 1
        return self.now - 10.0 if self.readings == 1 else self.now


def test_pacing_starts_at_the_first_message_sent_not_when_the_log_was_opened(tmp_path):
    log = write_log(tmp_path / "s.mcap", [(T0, _event("start", 0)), (T0 + 1_000_000_000, _event("end", 1))])
    clock = _SlowOpeningClock()
    pub = _RecordingPublisher(clock)
    stats = replay(log, pub, speed=1.0, clock=clock, sleep=clock.sleep)
    assert stats.sent == 2
    (first, _), (second, _) = pub.sent
    assert second - first == pytest.approx(1.0)


def test_a_replay_of_a_cut_log_says_it_stopped(recorded, tmp_path):
    data = recorded.path.read_bytes()
    log = tmp_path / "cut.mcap"
    log.write_bytes(data[: len(data) // 2 + 3])
    clock = _FakeClock()
    stats = replay(log, _RecordingPublisher(clock), speed=None, clock=clock, sleep=clock.sleep)
    assert stats.sent > 0 and stats.stopped and stats.damage


def test_an_elided_frame_takes_its_image_only_from_the_image_of_its_own_sequence(recorded, tmp_path):
    """The image record before an elided frame must match its log time and sequence; one of another
    sequence does not hold its bytes: the frame is refused, not rebuilt from the wrong image."""
    path = tmp_path / "reseq.mcap"
    changed = False
    with recorded.path.open("rb") as src, path.open("wb") as out:
        reader = make_reader(src)
        writer = Writer(out)
        header = reader.get_header()
        writer.start(header.profile, header.library)
        schemas, channels = {}, {}
        for schema, channel, message in reader.iter_messages(log_time_order=False):
            if schema is not None and schema.id not in schemas:
                schemas[schema.id] = writer.register_schema(schema.name, schema.encoding, schema.data)
            if channel.id not in channels:
                channels[channel.id] = writer.register_channel(
                    channel.topic, channel.message_encoding, schemas.get(channel.schema_id, 0), dict(channel.metadata))
            sequence = message.sequence
            if schema is not None and schema.name == IMAGE_SCHEMA and not changed:
                sequence, changed = sequence + 1000, True
            writer.add_message(channels[channel.id], log_time=message.log_time, data=message.data,
                               publish_time=message.publish_time, sequence=sequence)
        writer.finish()
    assert changed
    reader = LogReader(path)
    frames = list(reader.messages(topics=("frame",)))
    assert len(frames) == len(list(LogReader(recorded.path).messages(topics=("frame",)))) - 1
    assert sum(reader.refused.values()) == 1


def test_a_message_on_an_unknown_channel_is_not_refused_when_its_topic_is_not_asked_for(tmp_path):
    """With a topic filter, a stored message whose channel is unknown is not among those asked for: it
    is passed over, not counted as refused (replay reports the refused)."""
    beat = dataclasses.replace(make_message("heartbeat", t_capture_s=1.0, interval_s=1.0), source="robot", seq=1)
    path = tmp_path / "s.mcap"
    with path.open("wb") as f:
        writer = Writer(f)
        writer.start(PROFILE, "test")
        channel = register_bus_channel(writer, "heartbeat", "heartbeat")
        writer.add_message(channel, log_time=1, data=pack_frames(encode(beat)), publish_time=1)
        writer.add_message(channel + 7, log_time=2, data=pack_frames(encode(beat)), publish_time=2)  # no channel
        writer.finish()
    reader = LogReader(path)
    assert [m.message.topic for m in reader.messages(topics=("heartbeat",))] == ["heartbeat"]
    assert sum(reader.refused.values()) == 0
