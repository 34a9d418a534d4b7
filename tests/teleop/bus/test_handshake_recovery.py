"""One end without keys: both ends say the mechanisms differ, and a keyed subscriber whose endpoint an
unkeyed publisher held hears the keyed one bound there afterwards; which endpoints a socket's watch
lists as never connected and when it reconnects one (teleop.bus.handshakes)."""

from __future__ import annotations

import itertools
import logging
import struct
import threading
import time
import types

import pytest
import zmq
from support.bus import HEARD_WITHIN_S, delivered

from teleop.bus import Publisher, Subscriber
from teleop.errors import BusError

LOOPBACK = "tcp://127.0.0.1:*"
RECONNECT_S = 3.0  # teleop.bus.handshakes.RECONNECT_S
CLIENT_SAYS = "runs no CURVE and this process does"
UNKEYED_SAYS = "runs CURVE and this process runs none"
FED_ENDPOINT = "tcp://127.0.0.1:1"  # the endpoint _fed reports every event on
MISMATCH = (zmq.EVENT_HANDSHAKE_FAILED_PROTOCOL, zmq.PROTOCOL_ERROR_ZMTP_MECHANISM_MISMATCH)
_feeds = itertools.count()


@pytest.fixture
def handshake_log(caplog):
    caplog.set_level(logging.INFO, logger="teleop.bus.handshakes")
    return caplog


def _warnings(caplog, *wanted: str, within_s: float = HEARD_WITHIN_S) -> list[str]:
    """The handshake warnings once each ``wanted`` text is in one (or ``within_s`` passed)."""
    deadline = time.monotonic() + within_s
    while True:
        texts = [r.getMessage() for r in caplog.records
                 if r.name == "teleop.bus.handshakes" and r.levelno == logging.WARNING]
        if all(any(w in t for t in texts) for w in wanted) or time.monotonic() > deadline:
            return texts
        time.sleep(0.02)


def _bind_again(endpoint: str, keys) -> Publisher:
    """A keyed publisher on ``endpoint`` once the closed one's listener is gone (libzmq closes it
    on its I/O thread)."""
    deadline = time.monotonic() + HEARD_WITHIN_S
    while True:
        try:
            return Publisher(endpoint, lossless=False, source="console", security=keys)
        except Exception:
            if time.monotonic() > deadline:
                raise
            time.sleep(0.05)


@pytest.mark.slow
def test_a_keyed_subscriber_hears_a_keyed_publisher_bound_after_an_unkeyed_one_left(keys, handshake_log):
    unkeyed = Publisher(LOOPBACK, lossless=False, source="console")  # a console started without keys
    endpoint = unkeyed.endpoint
    with Subscriber(endpoint, ["force"], security=keys) as sub:
        _warnings(handshake_log, endpoint)  # the keyed subscriber met it (libzmq gives the endpoint up)
        sub.recv(timeout_s=RECONNECT_S + 0.5)  # it reconnects meanwhile, and meets the mismatch again
        unkeyed.close()
        with _bind_again(endpoint, keys) as keyed:
            assert delivered(keyed, sub, within_s=HEARD_WITHIN_S + RECONNECT_S) is not None
    texts = _warnings(handshake_log, CLIENT_SAYS, UNKEYED_SAYS)
    client = [t for t in texts if CLIENT_SAYS in t]
    assert len(client) == 1, texts  # said once, however often it reconnected
    assert f"the peer at {endpoint}" in client[0] and "bus.keys_dir" in client[0]
    assert client[0].endswith(f"reconnecting every {RECONNECT_S:g} s")
    server = [t for t in texts if UNKEYED_SAYS in t]
    assert server and f"a peer on {endpoint}" in server[0] and "teleop keys init" in server[0], texts


@pytest.mark.slow
def test_an_unkeyed_subscriber_and_a_keyed_publisher_both_say_the_mechanisms_differ(keys, handshake_log):
    with (
        Publisher(LOOPBACK, lossless=False, source="robot", security=keys) as pub,
        Subscriber(pub.endpoint, ["force"]) as sub,  # e.g. `teleop record` without --settings
    ):
        assert delivered(pub, sub, within_s=1.0) is None
        texts = _warnings(handshake_log, CLIENT_SAYS, UNKEYED_SAYS)
    keyed = [t for t in texts if CLIENT_SAYS in t]
    assert keyed and f"a peer on {pub.endpoint}" in keyed[0] and str(keys.keys_dir) in keyed[0], texts
    unkeyed = [t for t in texts if UNKEYED_SAYS in t]
    assert unkeyed and f"the peer at {pub.endpoint}" in unkeyed[0] and "set bus.keys_dir" in unkeyed[0], texts
    assert len(keyed) == 1 and len(unkeyed) == 1  # once per endpoint and outcome, however often it retries


def _event(monitor: zmq.Socket, kind: int, value: int, endpoint: str) -> None:
    monitor.send_multipart([struct.pack("=HI", kind, value), endpoint.encode()])


def test_a_give_up_after_a_retried_failure_is_said_too_and_the_endpoint_is_due_for_reconnecting(handshake_log):
    from teleop.bus import handshakes

    assert handshakes.RECONNECT_S == RECONNECT_S  # what the live tests wait for
    context = zmq.Context.instance()
    feed, monitor = context.socket(zmq.PAIR), context.socket(zmq.PAIR)
    feed.bind("inproc://test-handshake-events")
    monitor.connect("inproc://test-handshake-events")
    watch = _fed(feed, monitor, [
        (zmq.EVENT_HANDSHAKE_FAILED_NO_DETAIL, 0),  # libzmq retries this one
        (zmq.EVENT_HANDSHAKE_FAILED_NO_DETAIL, 0),  # again: a CURVE server drops every retry
        (zmq.EVENT_HANDSHAKE_FAILED_PROTOCOL, zmq.PROTOCOL_ERROR_ZMTP_MECHANISM_MISMATCH),
        (zmq.EVENT_HANDSHAKE_FAILED_PROTOCOL, zmq.PROTOCOL_ERROR_ZMTP_MECHANISM_MISMATCH),
    ])
    texts = _warnings(handshake_log, within_s=0)
    assert len(texts) == 2 and "dropped the connection" in texts[0] and UNKEYED_SAYS in texts[1], texts
    assert 0 < watch.next_due_s() <= RECONNECT_S  # given up: the socket's thread reconnects it


def test_an_unkeyed_socket_whose_peer_drops_one_greeting_says_nothing_of_keys(handshake_log):
    # a peer exiting mid-greeting, or the one connection of a port scanner: no CURVE to speak of
    context = zmq.Context.instance()
    feed, monitor = context.socket(zmq.PAIR), context.socket(zmq.PAIR)
    feed.bind("inproc://test-handshake-one-drop")
    monitor.connect("inproc://test-handshake-one-drop")
    _fed(feed, monitor, [(zmq.EVENT_HANDSHAKE_FAILED_NO_DETAIL, 0), (zmq.EVENT_HANDSHAKE_SUCCEEDED, 0),
                         (zmq.EVENT_HANDSHAKE_FAILED_NO_DETAIL, 0)])
    assert _warnings(handshake_log, within_s=0) == []


def test_a_binding_socket_lists_no_never_connected_endpoint_as_its_own_address_is_no_peer():
    context = zmq.Context.instance()
    mismatch = [(zmq.EVENT_HANDSHAKE_FAILED_PROTOCOL, zmq.PROTOCOL_ERROR_ZMTP_MECHANISM_MISMATCH)]
    never_connected = {}
    for server in (True, False):
        feed, monitor = context.socket(zmq.PAIR), context.socket(zmq.PAIR)
        feed.bind(f"inproc://test-handshake-never-connected-{server}")
        monitor.connect(f"inproc://test-handshake-never-connected-{server}")
        never_connected[server] = list(_fed(feed, monitor, mismatch, server=server).never_connected())
    assert never_connected == {True: [], False: [FED_ENDPOINT]}


class _ReconnectingSocket:
    """What HandshakeWatch.reconnect_due calls on a socket, recorded."""

    def __init__(self):
        self.calls = []

    def disconnect(self, endpoint: str) -> None:
        self.calls.append(("disconnect", endpoint))

    def connect(self, endpoint: str) -> None:
        self.calls.append(("connect", endpoint))


def test_a_given_up_endpoint_is_reconnected_only_once_its_time_comes(monkeypatch):
    from teleop.bus import handshakes

    now = [100.0]
    monkeypatch.setattr(handshakes, "time", types.SimpleNamespace(monotonic=lambda: now[0]))
    watch, socket = handshakes.HandshakeWatch(), _ReconnectingSocket()
    watch.gave_up("tcp://127.0.0.1:5550")
    watch.reconnect_due(socket)
    assert socket.calls == [] and watch.next_due_s() == RECONNECT_S  # not yet: libzmq is not hammered
    now[0] += RECONNECT_S - 0.1
    watch.reconnect_due(socket)
    assert socket.calls == []
    now[0] += 0.1
    watch.reconnect_due(socket)
    assert socket.calls == [("disconnect", "tcp://127.0.0.1:5550"), ("connect", "tcp://127.0.0.1:5550")]
    assert watch.next_due_s() is None


def _fed(feed: zmq.Socket, monitor: zmq.Socket, events: list[tuple[int, int]], *, server: bool = False,
        keys_dir=None):
    """A socket's watch (``server``: one that binds; keyed when ``keys_dir`` is given) fed ``events`` on
    FED_ENDPOINT, then stopped: the watch."""
    from teleop.bus.handshakes import HandshakeWatch, _report, _Side

    watch = HandshakeWatch()
    reader = threading.Thread(target=_report, args=(monitor, _Side(server=server, keys_dir=keys_dir), watch))
    reader.start()
    try:
        for kind, value in events:
            _event(feed, kind, value, FED_ENDPOINT)
    finally:
        _event(feed, zmq.EVENT_MONITOR_STOPPED, 0, "")
        reader.join(timeout=HEARD_WITHIN_S)
        feed.close(linger=0)
    return watch


def _keyed_watch(events: list[tuple[int, int]], keys_dir):
    """A keyed connecting socket's watch fed ``events`` (:func:`_fed` on a fresh monitor pair)."""
    context = zmq.Context.instance()
    address = f"inproc://test-handshake-keyed-{next(_feeds)}"
    feed, monitor = context.socket(zmq.PAIR), context.socket(zmq.PAIR)
    feed.bind(address)
    monitor.connect(address)
    return _fed(feed, monitor, events, keys_dir=keys_dir)


def test_an_endpoint_whose_handshake_later_succeeds_is_not_listed_as_never_connected(tmp_path):
    # `teleop record` must not say nothing came from a peer it did hear once the mismatch was mended
    assert _keyed_watch([MISMATCH, (zmq.EVENT_HANDSHAKE_SUCCEEDED, 0)], tmp_path).never_connected() == {}
    assert list(_keyed_watch([MISMATCH], tmp_path).never_connected()) == [FED_ENDPOINT]


def test_a_dropped_connection_libzmq_retries_itself_is_not_given_up_for_reconnecting(tmp_path):
    # a keyed client whose server drops its HELLO (another server key): libzmq retries; only a refused
    # key or a protocol error makes it give the endpoint up
    watch = _keyed_watch([(zmq.EVENT_HANDSHAKE_FAILED_NO_DETAIL, 0)] * 3, tmp_path)
    assert FED_ENDPOINT in watch.never_connected()  # said, and kept for `teleop record`
    assert watch.next_due_s() is None  # but not disconnected and reconnected by us
    assert _keyed_watch([(zmq.EVENT_HANDSHAKE_FAILED_AUTH, 0)], tmp_path).next_due_s() is not None


def test_a_failure_after_a_recovery_is_said_again(tmp_path, handshake_log):
    _keyed_watch([MISMATCH, MISMATCH, (zmq.EVENT_HANDSHAKE_SUCCEEDED, 0), MISMATCH], tmp_path)
    texts = _warnings(handshake_log, within_s=0)
    assert len(texts) == 2, texts  # once before the recovery, once after: not silenced for good
    assert any("now succeeds" in r.getMessage() for r in handshake_log.records)


def test_a_repeated_give_up_does_not_postpone_the_reconnect(monkeypatch):
    from teleop.bus import handshakes

    now = [100.0]
    monkeypatch.setattr(handshakes, "time", types.SimpleNamespace(monotonic=lambda: now[0]))
    watch = handshakes.HandshakeWatch()
    watch.gave_up(FED_ENDPOINT)
    now[0] += 2.0
    watch.gave_up(FED_ENDPOINT)  # a second failure reported before the retry
    assert watch.next_due_s() == RECONNECT_S - 2.0


def test_the_next_reconnect_is_the_soonest_one(monkeypatch):
    from teleop.bus import handshakes

    now = [100.0]
    monkeypatch.setattr(handshakes, "time", types.SimpleNamespace(monotonic=lambda: now[0]))
    watch = handshakes.HandshakeWatch()
    watch.gave_up("tcp://127.0.0.1:1")
    now[0] += 2.0
    watch.gave_up("tcp://127.0.0.1:2")
    assert watch.next_due_s() == RECONNECT_S - 2.0  # the first one's, not the second's


class _RefusingSocket(_ReconnectingSocket):
    """A socket libzmq will not connect again."""

    def connect(self, endpoint: str) -> None:
        raise zmq.ZMQError(zmq.EINVAL, "refused")


def test_an_endpoint_libzmq_will_not_connect_again_is_an_error_not_silently_dropped(monkeypatch):
    from teleop.bus import handshakes

    now = [100.0]
    monkeypatch.setattr(handshakes, "time", types.SimpleNamespace(monotonic=lambda: now[0]))
    watch = handshakes.HandshakeWatch()
    watch.gave_up(FED_ENDPOINT)
    now[0] += RECONNECT_S
    with pytest.raises(BusError, match=f"cannot reconnect {FED_ENDPOINT}"):
        watch.reconnect_due(_RefusingSocket())
