"""What one sender can make the recorder do is bounded: a huge sample batch, made-up topics."""

from __future__ import annotations

import json
import logging
import time

import numpy as np
from mcap.reader import make_reader

from teleop.bus import Publisher
from teleop.bus.wire import make_message
from teleop.session import LogReader
from teleop.session.foxglove import foxglove_messages
from teleop.session.logfile import END_METADATA, MESSAGE_ENCODING

LIMIT = 256  # the documented most Foxglove messages per batch, and channels per log
BIG = (8 * 1024 * 1024 - 2000) // 16  # samples of a force batch just under the wire's 8 MiB


def test_a_huge_force_batch_gives_a_bounded_number_of_foxglove_messages():
    t_s = 1.0 + np.arange(BIG) * 1e-4
    message = make_message("force", t_capture_s=float(t_s[-1]), t_s=t_s, value_n=np.arange(BIG) * 0.5)
    started = time.monotonic()
    converted = foxglove_messages(message)
    assert time.monotonic() - started < 2.0
    assert 2 <= len(converted) <= LIMIT
    samples = [json.loads(item.data) for item in converted]
    assert samples[0]["t_s"] == t_s[0] and samples[-1]["t_s"] == t_s[-1]  # first and last kept
    assert [s["t_s"] for s in samples] == sorted({s["t_s"] for s in samples})  # real samples, in order
    assert all(s["value_n"] == (s["t_s"] - 1.0) / 1e-4 * 0.5 for s in samples[:3])
    assert [item.age_ns for item in converted][-1] == 0
    small = make_message("width", t_capture_s=2.0, t_s=[1.9, 2.0], value_m=[0.03, 0.031])
    assert [json.loads(item.data)["value_m"] for item in foxglove_messages(small)] == [0.03, 0.031]


def test_a_huge_force_batch_is_recorded_promptly_keeping_every_sample_on_its_bus_channel(
    tmp_path, helpers, session_settings
):
    path = tmp_path / "big.mcap"
    with (
        Publisher("tcp://127.0.0.1:*", lossless=True, source="robot") as pub,
        helpers.recording(path, [pub.endpoint], settings=session_settings) as recorder,
    ):
        pub.wait_for_subscriber("", timeout_s=5.0)
        big = np.full(BIG, 1.0)
        pub.send("force", t_capture_s=1.0, grasp_id="big", t_s=big, value_n=big * 2)
        pub.send("force", t_capture_s=2.0, grasp_id="g1", t_s=[2.0], value_n=[3.0])
        helpers.wait_for(lambda: recorder.stats.messages == 2, timeout_s=15.0, what="both batches stored")
    with path.open("rb") as f:
        records = [(c.topic, c.message_encoding, r) for _, c, r in make_reader(f).iter_messages()]
    assert 2 <= sum(topic == "/force" for topic, _, _ in records) <= LIMIT + 1
    stored = [m.message for m in LogReader(path).messages()]
    assert [len(m.fields.t_s) for m in stored] == [BIG, 1]  # the bus channel: verbatim
    assert sum(encoding == MESSAGE_ENCODING for _, encoding, _ in records) == 2


def test_made_up_frame_topics_give_at_most_the_cap_of_channels_and_a_count(
    tmp_path, helpers, session_settings, caplog
):
    path = tmp_path / "topics.mcap"
    made_up = 300
    data = np.frombuffer(b"\xff\xd8\xff" + bytes(13), np.uint8)
    caplog.set_level(logging.WARNING, logger="teleop.session.recorder")
    with (
        Publisher("tcp://127.0.0.1:*", lossless=True, source="robot") as pub,
        helpers.recording(path, [pub.endpoint], settings=session_settings) as recorder,
    ):
        pub.wait_for_subscriber("", timeout_s=5.0)
        for i in range(made_up):
            pub.send("frame", t_capture_s=1.0, finger=f"f{i:03d}", grasp_id=None, index=0, encoding="jpeg", data=data)
        # The settings' finger and a type's own topic still fit, though the cap was reached.
        pub.send("frame", t_capture_s=2.0, finger="left", grasp_id=None, index=0, encoding="jpeg", data=data)
        pub.send("force", t_capture_s=2.0, grasp_id=None, t_s=[2.0], value_n=[3.0])
        total = made_up + 2
        helpers.wait_for(
            lambda: recorder.stats.messages + recorder.stats.refused["too_many_topics"] == total,
            timeout_s=20.0, what="every message stored or refused",
        )
    stats = recorder.stats
    admitted = LIMIT // 2  # a JPEG frame's topic needs two channels: the bus one and /tactile/<finger>
    assert stats.refused["too_many_topics"] == made_up - admitted
    assert stats.messages == admitted + 2 and stats.error is None
    with path.open("rb") as f:
        summary = make_reader(f).get_summary()
    topics = {c.topic for c in summary.channels.values()}
    assert len(topics) <= LIMIT + 4
    assert {"frame/left", "/tactile/left", "force", "/force"} <= topics
    assert "frame/f299" not in topics
    with path.open("rb") as f:
        end = {m.name: m.metadata for m in make_reader(f).iter_metadata()}[END_METADATA]
    assert json.loads(end["refused"]) == {"too_many_topics": made_up - admitted}  # in the log's summary
    warnings = [r.getMessage() for r in caplog.records if "new topics" in r.getMessage()]
    assert len(warnings) == 3  # the 1st, 10th and 100th refusal
