"""The live view: Foxglove's WebSocket protocol, the channels it advertises, ``record --foxglove``,
and the tap beside each live service (``teleop node``, ``estimator serve``, ``haptics serve``).

The client is ``websockets`` (installed with franky-control); it speaks only what a Foxglove
client would: the subprotocol handshake, ``serverInfo``, ``advertise``, ``subscribe`` and the
binary message-data frames.
"""

from __future__ import annotations

import argparse
import importlib
import json
import logging
import re
import socket
import struct
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import pytest
from websockets.sync.client import connect

from teleop.bus import Publisher
from teleop.bus.wire import make_message, now_ns
from teleop.errors import BusError
from teleop.session.foxglove import foxglove_messages, image_topic, known_channels
from teleop.session.foxglove_live import LiveServer, LiveTap, parse_address
from teleop.settings import Settings

TELEOP = Path(sys.executable).parent / "teleop"
SUBPROTOCOL = "foxglove.sdk.v1"  # what foxglove-sdk 0.30 accepts (it refuses foxglove.websocket.v1)
JPEG = b"\xff\xd8" + bytes(range(200))
BIG_JPEG = b"\xff\xd8" + bytes(100_000)


def _ops(ws, wanted: str, *, timeout_s: float = 5.0) -> dict:
    """The next JSON operation ``wanted``, skipping others."""
    while True:
        message = ws.recv(timeout=timeout_s)
        if isinstance(message, str) and (op := json.loads(message))["op"] == wanted:
            return op


def _advertised(ws, topics: set[str]) -> dict[str, dict]:
    channels: dict[str, dict] = {}
    while not topics <= set(channels):
        channels |= {c["topic"]: c for c in _ops(ws, "advertise")["channels"]}
    return channels


def _first_data(ws, log: Callable[[], None]) -> bytes:
    """The first message data after a subscribe, which takes effect asynchronously: ``log()`` until some comes."""
    for _ in range(50):
        log()
        try:
            data = ws.recv(timeout=0.1)
        except TimeoutError:
            continue
        if isinstance(data, bytes):
            return data
    raise AssertionError("no message data after subscribing")


def test_the_server_speaks_the_protocol_and_serves_what_it_is_given():
    frame = make_message("frame", t_capture_s=1.0, finger="left", index=0, encoding="jpeg", data=JPEG)
    force = make_message("force", t_capture_s=1.0, t_s=[1.0], value_n=[2.0])
    with (
        LiveServer("127.0.0.1", 0) as server,
        connect(server.url, subprotocols=[SUBPROTOCOL], open_timeout=5) as ws,
    ):
        assert ws.subprotocol == SUBPROTOCOL
        assert _ops(ws, "serverInfo")["name"] == "compliance-teleop"
        server.log(foxglove_messages(force), 10)
        image = foxglove_messages(frame)
        server.log(image, 11)
        channels = _advertised(ws, {"/force", "/tactile/left"})
        assert channels["/tactile/left"]["schemaName"] == "foxglove.CompressedImage"
        assert channels["/tactile/left"]["encoding"] == "protobuf"
        assert (channels["/force"]["encoding"], channels["/force"]["schemaEncoding"]) == (
            "json", "jsonschema")
        ws.send(json.dumps({"op": "subscribe",
                            "subscriptions": [{"id": 7, "channelId": channels["/tactile/left"]["id"]}]}))
        data = _first_data(ws, lambda: server.log(image, 12))
        opcode, subscription, log_time = struct.unpack_from("<BIQ", data)
        assert (opcode, subscription, log_time) == (1, 7, 12)
        assert data[13:] == image[0].data


def test_every_known_channel_is_advertised_before_the_first_message():
    """A channel made while a client is connected can be refused to its subscribe (foxglove-sdk
    0.30: "Unknown channel ID"): the server makes them all first, so they come in one advertise."""
    with (
        LiveServer("127.0.0.1", 0, fingers=["left", "middle"]) as server,
        connect(server.url, subprotocols=[SUBPROTOCOL], open_timeout=5) as ws,
    ):
        channels = {c["topic"]: c for c in _ops(ws, "advertise")["channels"]}
        expected = {c.topic: c for c in known_channels(["left", "middle"])}
        assert set(channels) == set(expected)
        assert {"/tactile/left", "/tactile/middle", "/events", "/force", "/estimate", "/label"} <= set(channels)
        for topic, channel in channels.items():
            assert (channel["schemaName"], channel["encoding"]) == (
                expected[topic].schema_name, expected[topic].message_encoding)
        # the conversion puts each type's messages on those very channels
        force = make_message("force", t_capture_s=1.0, t_s=[1.0], value_n=[2.0])
        assert foxglove_messages(force)[0].channel == expected["/force"]
        ws.send(json.dumps({"op": "subscribe", "subscriptions": [
            {"id": i, "channelId": c["id"]} for i, c in enumerate(channels.values())]}))
        server.log(foxglove_messages(force), 10)
        with pytest.raises(TimeoutError):  # no status ("Unknown channel ID") nor new advertise
            _ops(ws, "status", timeout_s=0.2)


def test_each_topics_times_never_go_back():
    """A batch's oldest sample can fall before the previous batch's newest: it is held back."""
    first = make_message("force", t_capture_s=1.02, t_s=[1.0, 1.01, 1.02], value_n=[1.0, 2.0, 3.0])
    second = make_message("force", t_capture_s=1.04, t_s=[1.02, 1.03, 1.04], value_n=[4.0, 5.0, 6.0])
    with (
        LiveServer("127.0.0.1", 0) as server,
        connect(server.url, subprotocols=[SUBPROTOCOL], open_timeout=5) as ws,
    ):
        force = _advertised(ws, {"/force"})["/force"]
        ws.send(json.dumps({"op": "subscribe", "subscriptions": [{"id": 1, "channelId": force["id"]}]}))
        _first_data(ws, lambda: server.log(foxglove_messages(first), 1_000_000_000))
        server.log(foxglove_messages(second), 1_015_000_000)  # 15 ms later: its oldest is 20 ms old
        times = []
        while len(times) < 3:
            data = ws.recv(timeout=5)
            if isinstance(data, bytes) and json.loads(data[13:])["value_n"] >= 4.0:
                times.append(struct.unpack_from("<BIQ", data)[2])
    assert times == [1_000_000_000, 1_005_000_000, 1_015_000_000]


def test_bad_addresses_and_taken_ports_are_refused_clearly():
    assert parse_address("9000") == ("127.0.0.1", 9000)
    assert parse_address("0.0.0.0:0") == ("0.0.0.0", 0)
    assert parse_address("65535") == ("127.0.0.1", 65535)
    assert parse_address("[::1]:8765") == parse_address("::1:8765") == ("::1", 8765)
    for bad in ("localhost:http", "65536", "-1", "[]:8765"):  # "[]": no host, not "every interface"
        with pytest.raises(BusError, match="expected \\[HOST:\\]PORT"):
            parse_address(bad)
    with LiveServer("127.0.0.1", 0) as server, pytest.raises(BusError, match="cannot serve"):
        LiveServer("127.0.0.1", server.port)


def test_a_live_view_on_an_ipv6_host_is_reachable_at_its_url():
    try:
        with socket.socket(socket.AF_INET6) as probe:
            probe.bind(("::1", 0))
    except OSError as exc:
        pytest.skip(f"this host has no IPv6 loopback: {exc}")
    with (
        LiveServer(*parse_address("[::1]:0"), fingers=[]) as server,
        connect(server.url, subprotocols=[SUBPROTOCOL], open_timeout=5) as ws,
    ):
        assert server.url == f"ws://[::1]:{server.port}"
        assert _ops(ws, "serverInfo")["name"] == "compliance-teleop"


def test_live_log_times_are_ns_since_the_unix_epoch_like_the_session_logs():
    force = make_message("force", t_capture_s=1.0, t_s=[1.0], value_n=[2.0])
    with (
        LiveServer("127.0.0.1", 0, fingers=[]) as server,
        connect(server.url, subprotocols=[SUBPROTOCOL], open_timeout=5) as ws,
    ):
        # monotonic plus the offset is this host's clock (a generous bound: only sign and scale matter)
        assert abs(now_ns() + server.offset_ns - time.time_ns()) < 60 * 10**9
        channel = _advertised(ws, {"/force"})["/force"]
        ws.send(json.dumps({"op": "subscribe", "subscriptions": [{"id": 1, "channelId": channel["id"]}]}))
        received_ns = now_ns()
        data = _first_data(ws, lambda: server.log_message(force, received_ns))
    assert struct.unpack_from("<BIQ", data)[2] == received_ns + server.offset_ns
    assert data[13:] == foxglove_messages(force, server.offset_ns)[0].data


def test_the_default_rigs_image_channels_are_in_the_first_advertise():
    fingers = [sensor.finger for sensor in Settings().sensors]
    assert fingers
    with (
        LiveServer("127.0.0.1", 0) as server,
        connect(server.url, subprotocols=[SUBPROTOCOL], open_timeout=5) as ws,
    ):
        topics = {channel["topic"] for channel in _ops(ws, "advertise")["channels"]}
    assert {image_topic(finger) for finger in fingers} <= topics


def test_record_serves_the_bus_live(tmp_path):
    with Publisher("tcp://127.0.0.1:*", lossless=True, source="robot") as pub:
        proc = subprocess.Popen(
            [str(TELEOP), "record", "--out", str(tmp_path / "live.mcap"), "--endpoint", pub.endpoint,
             "--duration-s", "20", "--foxglove", "127.0.0.1:0"],
            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
        )
        try:
            url = None
            while url is None and (line := proc.stderr.readline()):
                url = (match := re.search(r"Foxglove live view: (ws://\S+)", line)) and match[1]
            assert url, "record printed no ws:// address"
            with connect(url, subprotocols=[SUBPROTOCOL], open_timeout=10) as ws:
                _ops(ws, "serverInfo")
                pub.wait_for_subscriber("", timeout_s=30.0)
                pub.send("estimate", t_capture_s=1.0, grasp_id="g1", method="series", E_pa=1e5,
                         interval_pa=[5e4, 2e5], state="ok", reason="", provisional=True,
                         latency_s=0.01)
                pub.send("frame", t_capture_s=1.0, finger="right", index=0, encoding="jpeg", data=JPEG)
                channels = _advertised(ws, {"/estimate", "/tactile/right"})
            assert channels["/estimate"]["schemaName"] == "compliance_teleop.estimate"
        finally:
            proc.terminate()
            proc.wait(timeout=20)
    assert proc.returncode == 0


def _estimate(pub: Publisher, grasp_id: str = "g1") -> None:
    pub.send("estimate", t_capture_s=1.0, grasp_id=grasp_id, method="series", E_pa=1e5,
             interval_pa=[5e4, 2e5], state="ok", reason="", provisional=True, latency_s=0.01)


def _frames(pub: Publisher, n: int) -> None:
    """``n`` frames of 100 kB: far past small queues and the sockets' buffers."""
    for i in range(n):  # a lossless send with no room raises BusTimeoutError after send_timeout_s
        pub.send("frame", t_capture_s=1.0, finger="left", index=i, encoding="jpeg", data=BIG_JPEG)


def _until(condition, timeout_s: float = 10.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not condition():
        assert time.monotonic() < deadline, "timed out"
        time.sleep(0.01)


def test_a_tap_serves_what_the_publisher_sends(capsys):
    with Publisher("tcp://127.0.0.1:*", lossless=True, source="robot") as pub:
        with LiveTap(pub.endpoint, ("127.0.0.1", 0)) as tap:
            assert tap.running
            assert f"Foxglove live view: {tap.server.url}" in capsys.readouterr().err
            with connect(tap.server.url, subprotocols=[SUBPROTOCOL], open_timeout=5) as ws:
                _ops(ws, "serverInfo")
                pub.wait_for_subscriber("", timeout_s=5.0)
                _estimate(pub)
                pub.send("frame", t_capture_s=1.0, finger="left", index=0, encoding="jpeg", data=JPEG)
                pub.heartbeat_if_due()
                channels = _advertised(ws, {"/estimate", "/tactile/left"})
                _until(lambda: tap.stats.served == 2)  # advertised as it serves: the count follows on a loaded machine
            assert channels["/estimate"]["schemaName"] == "compliance_teleop.estimate"
        assert not tap.running and tap.server is None
        assert tap.stats.as_dict() == {"received": 2, "served": 2, "dropped": 0, "error": None}


def test_a_tap_that_falls_behind_drops_the_oldest_and_never_holds_a_lossless_publisher_up():
    served = []

    def slow(message, received_ns):
        time.sleep(0.02)
        served.append(message.body["index"])

    with (
        Publisher("tcp://127.0.0.1:*", lossless=True, source="robot", send_timeout_s=0.5,
                  high_water_mark=5) as pub,
        LiveTap(pub.endpoint, ("127.0.0.1", 0), max_pending=3, high_water_mark=5) as tap,
    ):
        tap.server.log_message = slow
        pub.wait_for_subscriber("", timeout_s=5.0)
        _frames(pub, 200)
        _until(lambda: tap.stats.served + tap.stats.dropped == 200)
    assert tap.stats.received == 200 and tap.stats.dropped > 0 and tap.stats.error is None
    assert served[-1] == 199  # the newest is always served


class _QueuedSocket:
    """Stands in for the tap's subscriber, with ``messages`` already queued on it."""

    def __init__(self, messages):
        self.messages = list(messages)

    def recv(self, timeout_s):
        return self.messages.pop(0) if self.messages else None


@pytest.mark.parametrize(("max_pending", "kept"), [(3, [7, 8, 9]), (1, [9]), (0, [9])])
def test_a_tap_keeps_the_newest_max_pending_messages_and_counts_the_rest_dropped(max_pending, kept):
    # Deterministic only off the bus: how much ZeroMQ has delivered when the tap reads varies.
    frames = [make_message("frame", t_capture_s=1.0, finger="left", index=i, encoding="jpeg", data=JPEG)
              for i in range(10)]
    tap = LiveTap("tcp://127.0.0.1:9", None, max_pending=max_pending)
    tap._take(_QueuedSocket(frames), timeout_s=0)
    assert [message.body["index"] for message, _ in tap._pending] == kept
    assert (tap.stats.received, tap.stats.dropped) == (10, 10 - len(kept))


def test_a_tap_that_fails_logs_one_error_and_lets_the_service_carry_on(caplog):
    caplog.set_level(logging.ERROR)
    assert not LiveTap("tcp://127.0.0.1:9", None).start().running  # no --foxglove: nothing
    with LiveServer("127.0.0.1", 0) as taken, LiveTap("tcp://127.0.0.1:9", ("127.0.0.1", taken.port)) as tap:
        assert not tap.running and "cannot serve" in tap.stats.error
        tap.start()  # a retrying caller: a failed tap stays stopped, and logs no second error
        assert not tap.running and tap.server is None
    def broken(message, received_ns):
        raise RuntimeError("no more")

    with (
        Publisher("tcp://127.0.0.1:*", lossless=True, source="robot", send_timeout_s=0.5,
                  high_water_mark=5) as pub,
        LiveTap(pub.endpoint, ("127.0.0.1", 0), high_water_mark=5) as tap,
    ):
        tap.server.log_message = broken
        pub.wait_for_subscriber("", timeout_s=5.0)
        _estimate(pub)
        _until(lambda: not tap.running)
        assert tap.stats.error == "RuntimeError: no more"
        _frames(pub, 200)  # the tap's subscription is gone: nothing waits for it
    errors = [r.getMessage() for r in caplog.records if r.levelno == logging.ERROR]
    assert len(errors) == 2 and all("the service carries on without it" in e for e in errors)


SERVICES = ["teleop.node_cli", "estimator.service_cli", "haptics.service_cli"]


@pytest.mark.parametrize("module", SERVICES)
def test_every_live_service_takes_the_foxglove_option(module):
    parser = argparse.ArgumentParser()
    importlib.import_module(module).add_arguments(parser)
    assert "--foxglove [[HOST:]PORT]" in parser.format_help()
    assert parser.parse_args(["--foxglove", "127.0.0.1:0"]).foxglove == ("127.0.0.1", 0)
    assert parser.parse_args(["--foxglove"]).foxglove == ("127.0.0.1", 8765)
    assert parser.parse_args([]).foxglove is None


@pytest.mark.slow
def test_the_node_serves_what_it_publishes_live(tmp_path):
    stderr = tmp_path / "node.log"
    with Publisher("tcp://127.0.0.1:*", lossless=True, source="operator") as operator, stderr.open("w") as err:
        proc = subprocess.Popen(
            [str(TELEOP), "node", "--scene", "quick", "--robot-pub", "tcp://127.0.0.1:*",
             "--command", operator.endpoint, "--duration-s", "60", "--foxglove", "127.0.0.1:0"],
            stdout=subprocess.DEVNULL, stderr=err,
        )
        try:
            url = []
            _until(lambda: url.extend(re.findall(r"Foxglove live view: (ws://\S+)", stderr.read_text()))
                   or url or proc.poll() is not None, timeout_s=60.0)
            assert url, f"the node printed no ws:// address: {stderr.read_text()}"
            with connect(url[0], subprotocols=[SUBPROTOCOL], open_timeout=10) as ws:
                _ops(ws, "serverInfo")
                operator.wait_for_subscriber("command", timeout_s=30.0)
                operator.send("command", t_capture_s=time.monotonic(), action="start_grasp", grasp_id="g1",
                              params={"object_index": 0.0})
                channels = _advertised(ws, {"/events", "/force", "/width"})
            assert channels["/events"]["schemaName"] == "foxglove.Log"
        finally:
            proc.terminate()
            proc.wait(timeout=30)
    assert proc.returncode == 0, stderr.read_text()
    assert "robot node:" in stderr.read_text().splitlines()[-1]
