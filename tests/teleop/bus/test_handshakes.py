"""A CURVE handshake refused is said once on each end (teleop.bus.handshakes, teleop.bus.security)."""

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
        assert "gives the endpoint up: restart it" in client[0].getMessage()  # libzmq gives a refused endpoint up
        caplog.clear()
        # a client trusting another server key retries without end: still one warning
        with Subscriber(pub.endpoint, ["force"], security=wrong_server):
            _handshake_records(caplog, 5.0, "the server dropped the connection")  # however slowly this machine runs
            time.sleep(0.5)  # the client retries meanwhile: no further warning
        dropped = [r for r in _handshake_records(caplog, 0.0) if r.levelno == logging.WARNING]
        assert len(dropped) == 1 and "the server dropped the connection" in dropped[0].getMessage()
        assert "or it runs no CURVE (set bus.keys_dir on its host)" in dropped[0].getMessage()
        assert dropped[0].getMessage().endswith("retrying")


def test_only_curve_clients_watch_their_handshakes_until_they_close(keys):
    def watchers() -> int:
        return sum(t.name == "curve-handshakes" for t in threading.enumerate())

    before = watchers()
    with Publisher(LOOPBACK, lossless=False, source="robot", security=keys) as pub:
        with Subscriber(pub.endpoint, ["force"]), Publisher(LOOPBACK, lossless=False):
            assert watchers() == before  # plain sockets and servers: no monitor, no thread
        with Subscriber(pub.endpoint, ["force"], security=keys) as sub:
            assert watchers() == before + 1
            assert delivered(pub, sub, within_s=HEARD_WITHIN_S) is not None
    deadline = time.monotonic() + 2.0
    while watchers() > before and time.monotonic() < deadline:
        time.sleep(0.02)
    assert watchers() == before
