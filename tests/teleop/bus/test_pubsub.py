"""Publisher and Subscriber over real ZeroMQ sockets on loopback (tcp and inproc)."""

from __future__ import annotations

import dataclasses
import itertools
import logging
import socket
import time

import msgpack
import numpy as np
import pytest
import zmq
from support.bus import HEARD_WITHIN_S, delivered, raw_publisher, wait_subscribed

from teleop.bus import Heartbeat, Publisher, Subscriber
from teleop.bus.peers import MAX_TRACKED, Recent
from teleop.bus.wire import encode, make_message
from teleop.errors import BusError, BusTimeoutError, MessageRejected
from teleop.settings import BusSettings

_names = itertools.count()


@pytest.fixture(params=["tcp", "inproc"])
def endpoint(request) -> str:
    return "tcp://127.0.0.1:*" if request.param == "tcp" else f"inproc://bus-test-{next(_names)}"


def _drain(sub: Subscriber, timeout_s: float = 0.3) -> list:
    got = []
    while (message := sub.recv(timeout_s=timeout_s)) is not None:
        got.append(message)
    return got


def test_lossless_burst_arrives_complete_and_in_order(endpoint):
    with Publisher(endpoint, lossless=True, source="robot") as pub, Subscriber(pub.endpoint, ["force"]) as sub:
        pub.wait_for_subscriber("force", timeout_s=2.0)
        for i in range(2000):
            pub.send("force", t_capture_s=float(i), t_s=[float(i)], value_n=[i * 0.5])
        got = _drain(sub)
    assert [m.seq for m in got] == list(range(2000))
    assert np.array_equal([m.body["value_n"][0] for m in got], np.arange(2000) * 0.5)
    assert sub.stats.gaps == 0 and sub.stats.missed == 0 and not sub.stats.refused


def _ipv6_loopback() -> bool:
    try:
        with socket.create_server(("::1", 0), family=socket.AF_INET6):
            return True
    except OSError:
        return False


@pytest.mark.skipif(not _ipv6_loopback(), reason="no IPv6 loopback here")
def test_an_ipv6_address_carries_the_bus():
    with Publisher("tcp://[::1]:*", lossless=True, source="robot") as pub, Subscriber(pub.endpoint, ["force"]) as sub:
        assert pub.endpoint.startswith("tcp://[::1]:")
        pub.wait_for_subscriber("force", timeout_s=2.0)
        pub.send("force", t_capture_s=1.0, t_s=[1.0], value_n=[2.0])
        assert sub.recv(timeout_s=2.0).body["value_n"].tolist() == [2.0]


def test_a_host_name_reaches_a_publisher_bound_to_an_ipv4_address():
    # IPv6 is on only for IPv6 addresses: with it, localhost may resolve to ::1 (where the hosts file
    # says so), where nothing listens
    with Publisher("tcp://127.0.0.1:*", lossless=True, source="robot") as pub:
        port = pub.endpoint.rpartition(":")[2]
        with Subscriber(f"tcp://localhost:{port}", ["force"]) as sub:
            pub.wait_for_subscriber("force", timeout_s=2.0)
            pub.send("force", t_capture_s=1.0, t_s=[1.0], value_n=[2.0])
            assert sub.recv(timeout_s=2.0) is not None


def test_arrays_arrive_intact_through_zmq():
    image = np.random.default_rng(3).integers(0, 65535, (120, 160, 3), dtype=np.uint16)
    with Publisher("tcp://127.0.0.1:*", lossless=True, source="robot") as pub, Subscriber(pub.endpoint, ["frame"]) as sub:
        pub.wait_for_subscriber("frame/left")
        pub.send("frame", t_capture_s=1.0, finger="left", index=0, encoding="raw", data=image)
        got = sub.recv(timeout_s=2.0)
    assert got.topic == "frame/left"
    assert got.body["data"].dtype == np.uint16 and np.array_equal(got.body["data"], image)


def test_lossless_send_blocks_then_times_out_instead_of_dropping():
    image = np.zeros((300, 400, 3), dtype=np.uint8)  # large enough that kernel buffers fill too
    with (
        Publisher("tcp://127.0.0.1:*", lossless=True, source="robot", high_water_mark=5, send_timeout_s=0.1) as pub,
        Subscriber(pub.endpoint, ["frame"], high_water_mark=5) as sub,
    ):
        pub.wait_for_subscriber("frame/left")
        started = time.monotonic()
        with pytest.raises(BusTimeoutError, match="no room"):
            for i in range(1000):
                pub.send("frame", t_capture_s=float(i), finger="left", index=i, encoding="raw", data=image)
        assert time.monotonic() - started >= 0.1
        sent = pub.sent
        assert sent < 1000
        got = _drain(sub)
        # every message the publisher accepted arrived; the refused one was never numbered
        assert [m.seq for m in got] == list(range(sent))
        pub.send("frame", t_capture_s=0.0, finger="left", index=sent, encoding="raw", data=image)
        assert sub.recv(timeout_s=1.0).seq == sent
    assert sub.stats.gaps == 0


def test_a_stalled_subscriber_is_skipped_when_asked_and_the_others_get_everything(caplog):
    """The robot node's publisher: one subscriber that stops reading (a recorder stopped with Ctrl-Z)
    misses messages and sees the gap; the others lose nothing, and the sender never raises."""
    image = np.zeros((300, 400, 3), dtype=np.uint8)  # large enough that kernel buffers fill too
    with (
        Publisher("tcp://127.0.0.1:*", lossless=True, source="robot", high_water_mark=50, send_timeout_s=0.05,
                  skip_stalled=True) as pub,
        Subscriber(pub.endpoint, ["frame", "force"], high_water_mark=5) as stalled,
        Subscriber(pub.endpoint, ["frame", "force"]) as healthy,
    ):
        assert delivered(pub, stalled, within_s=HEARD_WITHIN_S) and delivered(pub, healthy, within_s=HEARD_WITHIN_S)
        _drain(stalled, timeout_s=0.05)  # then it stops reading
        _drain(healthy, timeout_s=0.05)
        got, n = [], 300
        with caplog.at_level(logging.WARNING, logger="teleop.bus.pubsub"):
            for i in range(n):
                pub.send("frame", t_capture_s=float(i), finger="left", index=i, encoding="raw", data=image)
                # in step with the healthy one, however loaded the machine: its queue never fills
                got.append(message := healthy.recv(timeout_s=HEARD_WITHIN_S))
                assert message is not None and message.body["index"] == i
        assert pub.stalled_skips >= 1 and "a subscriber stalled" in caplog.text
        assert [m.body["index"] for m in got if m.type == "frame"] == list(range(n))
        late = [m for m in _drain(stalled) if m.type == "frame"]  # its queue: what it had room for
        pub.send("frame", t_capture_s=float(n), finger="left", index=n, encoding="raw", data=image)
        late += [m for m in _drain(stalled) if m.type == "frame"]  # once drained, it is sent to again
        assert 0 < len(late) < n and late[-1].body["index"] == n and stalled.stats.gaps >= 1


def _stall(pub: Publisher, image: np.ndarray, start: int) -> int:
    """Send frames from index ``start`` until one finds the subscriber stalled: the next index."""
    skips = pub.stalled_skips
    for i in range(start, start + 2000):
        pub.send("frame", t_capture_s=float(i), finger="left", index=i, encoding="raw", data=image)
        if pub.stalled_skips > skips:
            return i + 1
    raise AssertionError(f"no stall seen in 2000 sends (stalled_skips {pub.stalled_skips})")


def test_a_subscriber_that_stalls_again_after_catching_up_is_waited_for_and_counted_again():
    # after a skip the publisher is lossless again: a second stall is waited for (send_timeout_s) and
    # counted, not dropped without a word
    image = np.zeros((300, 400, 3), dtype=np.uint8)
    with (
        Publisher("tcp://127.0.0.1:*", lossless=True, source="robot", high_water_mark=20, send_timeout_s=0.05,
                  skip_stalled=True) as pub,
        Subscriber(pub.endpoint, ["frame", "force"], high_water_mark=5) as sub,
    ):
        assert delivered(pub, sub, within_s=HEARD_WITHIN_S)
        _drain(sub, timeout_s=0.05)
        after = _stall(pub, image, 0)
        assert pub.stalled_skips == 1
        _drain(sub)  # it reads again, all it had room for
        pub.send("frame", t_capture_s=float(after), finger="left", index=after, encoding="raw", data=image)
        assert [m.body["index"] for m in _drain(sub) if m.type == "frame"][-1] == after  # caught up
        _stall(pub, image, after + 1)  # then stops reading again
        assert pub.stalled_skips == 2


def test_subscriber_detects_and_reports_gaps():
    # A latest-value publisher drops silently when queues are full; the sequence shows it.
    with (
        Publisher("tcp://127.0.0.1:*", lossless=False, source="robot", high_water_mark=4) as pub,
        Subscriber(pub.endpoint, ["force"], high_water_mark=4) as sub,
    ):
        pub.wait_for_subscriber("force")
        for i in range(500):
            pub.send("force", t_capture_s=float(i), t_s=[float(i)], value_n=[1.0])
        got = _drain(sub, 0.2)
        pub.send("force", t_capture_s=500.0, t_s=[500.0], value_n=[1.0])
        got += _drain(sub, 0.5)
    assert 0 < len(got) < 501
    assert got[-1].seq == 500
    assert sub.stats.gaps >= 1
    assert sub.stats.missed == 501 - len(got)


def test_conflated_subscriber_yields_the_latest_per_topic(endpoint):
    with (
        Publisher(endpoint, lossless=False, source="estimator") as pub,
        Subscriber(pub.endpoint, ["estimate", "grasp_event"], conflate=True) as sub,
    ):
        # Both subscriptions must reach the publisher: it drops what nobody has asked for.
        pub.wait_for_subscriber("estimate", "grasp_event")
        for i in range(50):
            pub.send(
                "estimate", t_capture_s=float(i), grasp_id="g", method="series", E_pa=1e5 + i,
                interval_pa=[None, None], state="ok", reason="", provisional=True, latency_s=0.0,
            )
        pub.send("grasp_event", t_capture_s=50.0, event="end", grasp_id="g")
        # Look, unhurried, until the grasp event (sent last) is handed out: everything has arrived then.
        # How much has arrived at the first look depends on this machine's speed (all of it when idle:
        # then one estimate, seq 49); at every look the subscriber hands out the newest of each topic.
        got = []
        deadline = time.monotonic() + 5.0
        while not got or got[-1].type != "grasp_event":
            assert time.monotonic() < deadline, f"no grasp event within 5 s: {[m.seq for m in got]}"
            time.sleep(0.05)
            if (message := sub.recv(timeout_s=0.1)) is not None:
                got.append(message)
        assert sub.recv(timeout_s=0.1) is None
    *estimates, last = got
    seqs = [m.seq for m in estimates]
    assert all(m.type == "estimate" for m in estimates) and last.type == "grasp_event"
    assert seqs == sorted(set(seqs)) and len(seqs) < 50  # never an older one after a newer: some dropped
    assert estimates[-1].body["E_pa"] == 1e5 + 49 and seqs[-1] == 49  # the latest, handed out before the end
    assert sub.stats.received == 51  # all were read off the socket, few handed out


def test_receiver_logs_refusals_and_carries_on(caplog):
    raw, raw_endpoint = raw_publisher()
    good = [bytes(f) for f in encode(make_message("heartbeat", t_capture_s=0.0, interval_s=0.5))]
    force = [bytes(f) for f in encode(make_message("force", t_capture_s=0.0, t_s=[0.0, 1.0], value_n=[1.0, 2.0]))]
    header = msgpack.unpackb(force[1])
    bad = {
        "unknown_version": [force[0], msgpack.packb({**header, "v": 9}), *force[2:]],
        "unknown_type": [b"force", msgpack.packb({**header, "type": "sneeze"}), *force[2:]],
        "corrupt": [force[0], b"\xc1\xc1", *force[2:]],
        "bad_buffer": [*force[:4], force[4][:5]],
        "not_finite": [*force[:4], np.array([1.0, np.nan]).tobytes()],
        # each frame under max_bytes (ZeroMQ would drop the connection otherwise), together over
        "oversize": [*force[:3], force[3] + b"\x00" * 1000, force[4] + b"\x00" * 1000],
    }
    try:
        with Subscriber(raw_endpoint, ["force"], max_bytes=2048) as sub:
            wait_subscribed(raw, "force")  # slow joiner: the subscription reached the raw socket
            for frames in bad.values():
                raw.send_multipart(frames)
            raw.send_multipart(force)
            got = sub.recv(timeout_s=2.0)
            raw.send_multipart(good)
            assert sub.recv(timeout_s=0.3) is None  # heartbeats are consumed, not returned
    finally:
        raw.close()
    assert got is not None and np.array_equal(got.body["value_n"], [1.0, 2.0])
    assert dict(sub.stats.refused) == dict.fromkeys(bad, 1)
    assert sum("refused a message" in r.message for r in caplog.records) == len(bad)


def test_a_peer_on_another_wire_version_is_named_once_with_the_fix_then_counted(caplog):
    raw = zmq.Context.instance().socket(zmq.PUB)
    raw.setsockopt(zmq.LINGER, 0)
    raw.bind("inproc://bus-test-v2-peer")
    force = [bytes(f) for f in encode(make_message("force", t_capture_s=0.0, t_s=[0.0], value_n=[1.0]))]
    header = {**msgpack.unpackb(force[1]), "v": 2, "source": "robot-v2"}
    newer = [force[0], msgpack.packb(header), *force[2:]]
    try:
        with Subscriber(["inproc://bus-test-v2-peer", "inproc://bus-test-elsewhere"], ["force"]) as sub:
            deadline = time.monotonic() + 2.0
            while not sub.stats.refused and time.monotonic() < deadline:  # until subscribed
                raw.send_multipart(newer)
                sub.recv(timeout_s=0.01)
            caplog.clear()
            sub.stats.refused.clear()
            for _ in range(120):
                raw.send_multipart(newer)
            while sub.recv(timeout_s=0.1) is not None or sum(sub.stats.refused.values()) < 120:
                pass
    finally:
        raw.close()
    lines = [r.getMessage() for r in caplog.records if "refused" in r.getMessage()]
    assert sub.stats.refused["unknown_version"] == 120
    first, *summaries = lines
    assert "source 'robot-v2'" in first and "header version 2" in first
    assert "run the same software version on every host" in first
    assert summaries == ["refused 10 messages for unknown_version so far, the last from source 'robot-v2' "
                         "(one of inproc://bus-test-v2-peer, inproc://bus-test-elsewhere)",
                         "refused 100 messages for unknown_version so far, the last from source 'robot-v2' "
                         "(one of inproc://bus-test-v2-peer, inproc://bus-test-elsewhere)"]


def _frames(message, *, source: str = "robot", seq: int = 0) -> list[bytes]:
    return [bytes(f) for f in encode(dataclasses.replace(message, source=source, seq=seq))]


def test_a_replayed_message_is_counted_every_time_but_logged_at_decades(caplog):
    force = _frames(make_message("force", t_capture_s=1.0, t_s=[1.0], value_n=[2.0]), seq=5)
    with Subscriber(f"inproc://bus-test-{next(_names)}", ["force"]) as sub:
        for _ in range(1000):
            sub._accept(force)
        restarts = [r.getMessage() for r in caplog.records if "restarted" in r.getMessage()]
        assert sub.stats.restarts == 999
        assert len(restarts) == 3  # the 1st, 10th and 100th
        assert "restarted topic 'force' at seq 5 (was 5)" in restarts[0] and "restart 100 of force" in restarts[-1]
        caplog.clear()
        for seq in [7, 5] * 100:  # two senders under one name: a gap, then a fall, over and over
            sub._accept(_frames(make_message("force", t_capture_s=1.0, t_s=[1.0], value_n=[2.0]), seq=seq))
        assert len([r for r in caplog.records if "missed" in r.getMessage()]) == 3  # the 1st, 10th and 100th gap
        assert len([r for r in caplog.records if "restarted" in r.getMessage()]) == 1  # the 1000th restart
        caplog.clear()
        beat = make_message("heartbeat", t_capture_s=1.0, interval_s=1.0)
        for seq in (3, 0):  # the node restarts: its heartbeat's restart is its type's first, logged
            sub._accept(_frames(beat, seq=seq))
    assert (sub.stats.gaps, sub.stats.missed, sub.stats.restarts) == (100, 100, 1100)
    assert "restarted topic 'heartbeat' at seq 0 (was 3)" in caplog.text


def test_made_up_sources_and_topics_are_forgotten_but_real_peers_kept(caplog):
    beat = make_message("heartbeat", t_capture_s=1.0, interval_s=60.0)
    force = make_message("force", t_capture_s=1.0, t_s=[1.0], value_n=[2.0])
    seq = itertools.count()
    with Subscriber(f"inproc://bus-test-{next(_names)}") as sub:
        for i in range(3 * MAX_TRACKED):
            # A frame's topic names its finger, whatever the sender calls it: the one topic it can make up.
            made_up = beat if i % 2 else make_message("frame", t_capture_s=1.0, finger=f"f{i}", index=0,
                                                      encoding="raw", data=np.zeros((1, 1, 3), np.uint8))
            sub._accept(_frames(made_up, source=f"made-up-{i}"))
            if i % 100 == 0:
                n = next(seq)
                sub._accept(_frames(beat, seq=n))
                sub._accept(_frames(force, seq=n))
        assert len(sub.heartbeat.peers()) == MAX_TRACKED and len(sub._last_seq) == MAX_TRACKED
        assert sub.heartbeat.is_alive("robot")  # its announced period still known
        sub._accept(_frames(force, seq=next(seq) + 1))  # a gap after its last seq: still remembered
    assert (sub.stats.gaps, sub.stats.missed, sub.stats.restarts) == (1, 1, 0)
    forgetting = [r.getMessage() for r in caplog.records if "forgetting" in r.getMessage()]
    assert len(forgetting) == 2  # once for the peers, once for the sequences
    assert any(f"more than {MAX_TRACKED} peers heard from" in line for line in forgetting)


def test_a_conflated_subscriber_keeps_a_bounded_number_of_topics():
    with Subscriber(f"inproc://bus-test-{next(_names)}", conflate=True) as sub:
        for i in range(2 * MAX_TRACKED):
            # Only a frame's topic carries a qualifier (its finger), so made-up topics are made-up fingers.
            message = make_message("frame", t_capture_s=1.0, finger=f"f{i}", index=0, encoding="raw",
                                   data=np.zeros((1, 1, 3), np.uint8))
            sub._keep_latest(sub._accept(_frames(message, source=f"made-up-{i}")))
    assert len(sub._latest) == MAX_TRACKED
    assert next(iter(sub._latest)) == f"frame/f{MAX_TRACKED}"  # the oldest forgotten first


def test_heartbeats_detect_a_dead_peer(endpoint):
    pub = Publisher(endpoint, lossless=False, source="robot", heartbeat_s=0.05)
    with Subscriber(pub.endpoint, ["estimate"]) as sub:
        deadline = time.monotonic() + 0.4
        while time.monotonic() < deadline:
            pub.heartbeat_if_due()
            sub.recv(timeout_s=0.01)
        assert sub.heartbeat.is_alive("robot")
        assert sub.heartbeat.peers() == ["robot"]
        pub.close()  # the peer dies
        deadline = time.monotonic() + 0.3
        while time.monotonic() < deadline:
            sub.recv(timeout_s=0.02)
        assert not sub.heartbeat.is_alive("robot")  # three periods passed without a word


def test_a_data_message_alone_says_its_sender_is_alive():
    # a peer heard only through its data, before its first heartbeat, counts as heard from
    with (
        Publisher("inproc://bus-test-data-alive", lossless=True, source="robot") as pub,
        Subscriber("inproc://bus-test-data-alive", ["force"]) as sub,
    ):
        pub.wait_for_subscriber("force")
        pub.send("force", t_capture_s=1.0, t_s=[1.0], value_n=[2.0])
        assert sub.recv(timeout_s=5.0).type == "force"
        assert sub.heartbeat.peers() == ["robot"]
        assert sub.heartbeat.is_alive("robot", timeout_s=60.0)


def test_recv_with_no_wait_looks_at_one_queued_message_however_many_heartbeats_wait():
    # timeout_s=0 looks once: a peer flooding heartbeats cannot keep it reading past its deadline
    with (
        Publisher("inproc://bus-test-recv-once", lossless=True, source="robot") as pub,
        Subscriber("inproc://bus-test-recv-once") as sub,
    ):
        pub.wait_for_subscriber("heartbeat")
        for i in range(50):
            pub.send("heartbeat", t_capture_s=float(i), interval_s=0.5)
        assert sub._live().poll(1000)  # they are queued
        assert sub.recv(timeout_s=0) is None
        assert sub.stats.received == 1
        assert sub.heartbeat.peers() == ["robot"]


def test_heartbeat_bookkeeping_on_an_injected_clock():
    now = [100.0]
    beat = Heartbeat(clock=lambda: now[0])
    assert not beat.is_alive("estimator", timeout_s=1.0)
    beat.saw("estimator", interval_s=0.5)
    now[0] += 1.4
    assert beat.is_alive("estimator")
    now[0] += 0.2
    assert not beat.is_alive("estimator")
    assert beat.is_alive("estimator", timeout_s=2.0)
    beat.saw("display")
    with pytest.raises(BusError, match="timeout_s"):
        beat.is_alive("display")
    assert beat.last_seen_s("display") == now[0]


def test_heartbeat_times_given_explicitly_are_used_not_the_clock():
    beat = Heartbeat(clock=lambda: 1000.0)  # a clock far from the times given
    beat.saw("robot", interval_s=0.5, now_s=10.0)
    assert beat.last_seen_s("robot") == 10.0
    assert beat.is_alive("robot", now_s=11.4)  # within three periods of 10.0
    assert not beat.is_alive("robot", now_s=11.6)


def test_a_peer_heard_exactly_timeout_s_ago_is_still_alive():
    beat = Heartbeat(clock=lambda: 0.0)
    beat.saw("robot", interval_s=0.5, now_s=10.0)
    assert beat.is_alive("robot", timeout_s=2.0, now_s=12.0)  # "within timeout_s": the bound included
    assert not beat.is_alive("robot", timeout_s=2.0, now_s=12.001)


def test_a_peer_heard_again_is_kept_when_made_up_names_flood_the_table():
    beat = Heartbeat(clock=lambda: 0.0)
    beat.saw("robot", interval_s=0.5)  # the first peer heard from
    for i in range(MAX_TRACKED - 1):
        beat.saw(f"made-up-{i}")
    beat.saw("robot")  # heard again: now the most recent
    beat.saw("one-more")  # the table is full: the longest unheard (made-up-0) goes, not the robot
    assert beat.last_seen_s("robot") is not None and beat.is_alive("robot")
    assert beat.last_seen_s("made-up-0") is None
    recent = Recent("names")
    recent["a"] = 1
    for i in range(MAX_TRACKED - 1):
        recent[i] = i
    recent["a"] = 2  # written again: now the most recent
    recent["b"] = 3
    assert "a" in recent and 0 not in recent and len(recent) == MAX_TRACKED


def test_heartbeat_is_sent_only_when_due():
    with Publisher("inproc://heartbeat-due", lossless=False, heartbeat_s=0.5) as pub:
        assert pub.heartbeat_if_due(now_s=10.0)
        assert not pub.heartbeat_if_due(now_s=10.4)
        assert pub.heartbeat_if_due(now_s=10.5)
        assert pub.sent == 2


def test_waiting_for_several_topics_names_the_one_nobody_asked_for():
    with (
        Publisher("tcp://127.0.0.1:*", lossless=False, source="estimator") as pub,
        Subscriber(pub.endpoint, ["estimate"]),
    ):
        pub.wait_for_subscriber("estimate", timeout_s=2.0)
        with pytest.raises(BusTimeoutError, match="'grasp_event'") as caught:
            pub.wait_for_subscriber("estimate", "grasp_event", timeout_s=0.1)
    assert "'estimate'" not in str(caught.value)


def test_errors_name_the_endpoint():
    with pytest.raises(BusError, match="nowhere"):
        Publisher("nowhere://x", lossless=True)
    with Publisher("tcp://127.0.0.1:*", lossless=True) as pub, pytest.raises(BusTimeoutError, match="no subscriber"):
        pub.wait_for_subscriber("force", timeout_s=0.05)
    with pytest.raises(BusError, match="closed"):
        pub.send("heartbeat", t_capture_s=0.0, interval_s=1.0)
    sub = Subscriber("tcp://127.0.0.1:1", ["force"])
    sub.close()
    with pytest.raises(BusError, match="closed"):
        sub.recv(timeout_s=0.0)


def test_a_malformed_message_is_refused_for_what_it_breaks_not_called_oversize():
    with Publisher("inproc://bus-test-publish-refused", lossless=False, source="robot") as pub:
        force = make_message("force", t_capture_s=1.0, t_s=[1.0], value_n=[2.0])
        with pytest.raises(MessageRejected) as refused:
            pub.publish(dataclasses.replace(force, topic="estimate"))
        assert refused.value.reason == "bad_header"
        assert "bus.max_message_bytes" not in str(refused.value)
        assert pub.sent == 0


def test_an_endpoint_in_use_says_how_to_free_it_and_which_setting_names_it():
    with Publisher("tcp://127.0.0.1:*", lossless=True) as holder:
        with pytest.raises(BusError, match=r"holds it: stop it or choose another port$"):
            Publisher(holder.endpoint, lossless=True)
        bus = BusSettings(robot_pub=holder.endpoint)
        with pytest.raises(BusError, match=r"a session still running\?.* choose another port in bus.robot_pub$"):
            Publisher.from_settings(bus, bus.robot_pub, lossless=True)


@pytest.mark.parametrize("topics", ["estimate", None])
def test_subscriber_refuses_topics_that_are_not_a_sequence_of_names(topics):
    # A str would be split into one-letter prefixes ('e', 's', ...) and subscribe to the wrong topics.
    with pytest.raises(BusError, match="topics: expected a sequence of topic names, got " + (
            "the str 'estimate'" if topics else "None")):
        Subscriber("inproc://bus-test-topics", topics)


def test_subscriber_refuses_no_endpoint():
    with pytest.raises(BusError, match="endpoints: expected an endpoint or a sequence of endpoints, got None"):
        Subscriber(None)


@pytest.mark.parametrize("lossless", ["no", "0", 0, 1, None])
def test_publisher_lossless_must_be_a_bool(lossless):
    with pytest.raises(BusError, match=r"lossless = .*: expected True or False"):
        Publisher(f"inproc://bus-test-{next(_names)}", lossless=lossless)


def test_subscriptions_count_exact_prefixes_and_end_with_their_subscriber(endpoint):
    def until(count: int, prefix: str, pub: Publisher) -> int:
        deadline = time.monotonic() + 5.0
        while (n := pub.subscriptions(prefix)) != count and time.monotonic() < deadline:
            time.sleep(0.01)
        return n

    with Publisher(endpoint, lossless=True) as pub:
        assert pub.subscriptions("follow") == 0
        with Subscriber(pub.endpoint, ["command", "follow"]):
            with Subscriber(pub.endpoint, [""]):
                assert until(1, "", pub) == 1 and until(1, "follow", pub) == 1
                assert pub.subscriptions("follow") == 1  # the empty prefix is its own
            assert until(0, "", pub) == 0 and pub.subscriptions("follow") == 1
        assert until(0, "follow", pub) == 0 and pub.subscriptions("command") == 0
        with pytest.raises(BusTimeoutError, match="no subscriber for 'follow'"):  # the one that left is none
            pub.wait_for_subscriber("follow", timeout_s=0.2)
