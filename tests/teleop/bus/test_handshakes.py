"""A failed handshake is said once per endpoint and outcome on each end, and a connecting socket recovers
an endpoint libzmq gave up (teleop.bus.handshakes, teleop.bus.security)."""

from __future__ import annotations

import dataclasses
import logging
import threading
import time

from support.bus import HEARD_WITHIN_S, delivered

from teleop.bus import Publisher, Subscriber

LOOPBACK = "tcp://127.0.0.1:*"


def _handshake_records(caplog, within_s: float, *wanted: str) -> list[logging.LogRecord]:
    """The security module's records once every ``wanted`` text is in one (or ``within_s`` passed)."""
    deadline = time.monotonic() + within_s
    while True:
        records = [r for r in caplog.records if r.name in ("teleop.bus.security", "teleop.bus.handshakes")]
        found = all(any(w in r.getMessage() for r in records) for w in wanted)
        if found or time.monotonic() > deadline:
            return records
        time.sleep(0.02)


def test_a_refused_handshake_is_logged_once_on_both_ends(keys, stranger, caplog):
    caplog.set_level(logging.INFO, logger="teleop.bus.security")
    caplog.set_level(logging.INFO, logger="teleop.bus.handshakes")
    wrong_server = dataclasses.replace(keys, server_public_key=stranger.client_public_key)
    stranger_key = stranger.client_public_key.decode()
    with (
        Publisher(LOOPBACK, lossless=False, source="robot", security=keys) as pub,
        Subscriber(pub.endpoint, ["force"], security=stranger),
    ):
        records = _handshake_records(caplog, 3.0, stranger_key, pub.endpoint)
        server = [r for r in records if stranger_key in r.getMessage()]
        client = [r for r in records if f"CURVE handshake with {pub.endpoint} refused" in r.getMessage()]
        assert [r.levelno for r in server] == [logging.WARNING], records
        assert "teleop keys add" in server[0].getMessage()
        assert [r.levelno for r in client] == [logging.WARNING], records
        assert "does not authorise this client's key" in client[0].getMessage()
        assert str(stranger.keys_dir / "client.key") in client[0].getMessage()
        assert client[0].getMessage().endswith("reconnecting every 3 s")  # libzmq gave it up: we retry it
        caplog.clear()
        # a client trusting another server key retries without end: still one warning
        with Subscriber(pub.endpoint, ["force"], security=wrong_server):
            _handshake_records(caplog, 5.0, "the server dropped the connection")  # however slowly this machine runs
            time.sleep(0.5)  # the client retries meanwhile: no further warning
        dropped = [r for r in _handshake_records(caplog, 0.0) if r.levelno == logging.WARNING]
        assert len(dropped) == 1 and "the server dropped the connection" in dropped[0].getMessage()
        # the keys are read once: fixing server.key helps only a restarted process
        assert dropped[0].getMessage().endswith("fix server.key, then restart this process")


def test_every_socket_watches_its_handshakes_until_it_closes(keys):
    def watchers(expected: int) -> int:
        """The watcher threads, once there are ``expected`` (a closed socket's ends soon after)."""
        deadline = time.monotonic() + HEARD_WITHIN_S
        while (count := sum(t.name == "bus-handshakes" for t in threading.enumerate())) != expected:
            if time.monotonic() > deadline:
                break
            time.sleep(0.02)
        return count

    before = watchers(sum(t.name == "bus-handshakes" for t in threading.enumerate()))
    with Publisher(LOOPBACK, lossless=False, source="robot", security=keys) as pub:
        with Publisher(LOOPBACK, lossless=False):
            assert watchers(before + 2) == before + 2  # plain sockets and servers too: a mismatch is said on both ends
        with Subscriber(pub.endpoint, ["force"], security=keys) as sub:
            assert watchers(before + 2) == before + 2
            assert delivered(pub, sub, within_s=HEARD_WITHIN_S) is not None
    assert watchers(before) == before


def test_the_watch_lists_only_endpoints_no_handshake_ever_succeeded_with():
    from teleop.bus.handshakes import HandshakeWatch

    watch = HandshakeWatch()
    watch.failed("tcp://h:1", "refused at first")
    watch.succeeded("tcp://h:1")  # recovered: something may have come from it
    watch.succeeded("tcp://h:2")
    watch.failed("tcp://h:2", "refused after a restart")  # connected before: not never
    watch.failed("tcp://h:3", "refused")
    watch.failed("tcp://h:3", "refused again")
    assert watch.never_connected() == {"tcp://h:3": "refused again"}
