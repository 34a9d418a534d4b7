"""The live view: Foxglove's WebSocket protocol, the channels it advertises, and ``record --foxglove``.

The client is ``websockets`` (installed with franky-control); it speaks only what a Foxglove
client would: the subprotocol handshake, ``serverInfo``, ``advertise``, ``subscribe`` and the
binary message-data frames.
"""

from __future__ import annotations

import json
import re
import struct
import subprocess
import sys
from pathlib import Path

import pytest
from websockets.sync.client import connect

from teleop.bus import Publisher
from teleop.bus.wire import make_message
from teleop.errors import BusError
from teleop.session.foxglove import foxglove_messages
from teleop.session.foxglove_live import LiveServer, parse_address

TELEOP = Path(sys.executable).parent / "teleop"
SUBPROTOCOL = "foxglove.sdk.v1"  # what foxglove-sdk 0.30 accepts (it refuses foxglove.websocket.v1)
JPEG = b"\xff\xd8" + bytes(range(200))


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
        data = None
        for _ in range(50):  # the subscription takes effect asynchronously: log until data comes
            server.log(image, 12)
            try:
                data = ws.recv(timeout=0.1)
            except TimeoutError:
                continue
            if isinstance(data, bytes):
                break
        assert isinstance(data, bytes), "no message data after subscribing"
        opcode, subscription, log_time = struct.unpack_from("<BIQ", data)
        assert (opcode, subscription, log_time) == (1, 7, 12)
        assert data[13:] == image[0].data


def test_bad_addresses_and_taken_ports_are_refused_clearly():
    assert parse_address("9000") == ("127.0.0.1", 9000)
    assert parse_address("0.0.0.0:0") == ("0.0.0.0", 0)
    with pytest.raises(BusError, match="expected \\[HOST:\\]PORT"):
        parse_address("localhost:http")
    with LiveServer("127.0.0.1", 0) as server, pytest.raises(BusError, match="cannot serve"):
        LiveServer("127.0.0.1", server.port)


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
                pub.send("estimate", t_capture_s=1.0, grasp_id="g1", method="split", E_pa=1e5,
                         interval_pa=[5e4, 2e5], state="ok", reason="", provisional=True,
                         latency_s=0.01)
                pub.send("frame", t_capture_s=1.0, finger="right", index=0, encoding="jpeg", data=JPEG)
                channels = _advertised(ws, {"/estimate", "/tactile/right"})
            assert channels["/estimate"]["schemaName"] == "compliance_teleop.estimate"
        finally:
            proc.terminate()
            proc.wait(timeout=20)
    assert proc.returncode == 0
