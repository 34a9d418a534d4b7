"""A bus socket's failed handshakes, said once per endpoint and outcome; endpoints libzmq gave up, reconnected.

libzmq itself says nothing when a handshake fails. :func:`watch_handshakes` reads a socket's monitor
in a thread and warns once per endpoint and outcome: on a CURVE client, a server that refuses its key
or that is not the server whose key it trusts; on every socket, keyed or not, server or client, a peer
whose security mechanism differs (one end has keys, the other none), so both ends say it.

A connecting socket whose handshake was refused or broke the protocol is given up by libzmq
(4.3.5) for good, so a right peer bound later is never heard. The watch notes that endpoint, and
the socket's own thread (ZeroMQ sockets are not thread-safe) reconnects it every
:data:`RECONNECT_S` (:meth:`HandshakeWatch.reconnect_due`) until a handshake succeeds. It also keeps,
for a connecting socket, the endpoints no handshake with ever succeeded and why the last one failed
(:meth:`HandshakeWatch.never_connected`): nothing came from them, which ``teleop record`` tells at its end.
"""

from __future__ import annotations

import contextlib
import itertools
import logging
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import zmq
from zmq.utils.monitor import recv_monitor_message

from teleop.errors import BusError

__all__ = ["RECONNECT_S", "HandshakeWatch", "watch_handshakes"]

log = logging.getLogger(__name__)

RECONNECT_S = 3.0  # how often a connecting socket retries an endpoint libzmq gave up
_MONITORS = itertools.count()  # numbers the monitors' inproc addresses
_MISMATCH = zmq.PROTOCOL_ERROR_ZMTP_MECHANISM_MISMATCH  # one end runs CURVE, the other none
# What a watcher hears (MONITOR_STOPPED: the socket closed). A server says only a mechanism mismatch:
# its ZAP handler names a refused key itself (teleop.bus.security), a client a wrong server key.
_CLIENT_EVENTS = (zmq.EVENT_HANDSHAKE_FAILED_AUTH | zmq.EVENT_HANDSHAKE_FAILED_NO_DETAIL
                  | zmq.EVENT_HANDSHAKE_FAILED_PROTOCOL | zmq.EVENT_HANDSHAKE_SUCCEEDED | zmq.EVENT_MONITOR_STOPPED)
_SERVER_EVENTS = zmq.EVENT_HANDSHAKE_FAILED_PROTOCOL | zmq.EVENT_MONITOR_STOPPED
# after these a libzmq client gives the endpoint up; after a dropped connection it retries itself
_GIVES_UP = (zmq.EVENT_HANDSHAKE_FAILED_AUTH, zmq.EVENT_HANDSHAKE_FAILED_PROTOCOL)
_RECONNECTING = f"reconnecting every {RECONNECT_S:g} s"
_KEYS_HELP = "`teleop keys --help`"


@dataclass(frozen=True)
class _Side:
    """This end of the socket: whether it binds, and its keys folder (None: no CURVE)."""

    server: bool
    keys_dir: Path | None


def _fix(side: _Side) -> str:
    """How to end a mechanism mismatch, from this end."""
    if side.keys_dir is None:
        return (f"set bus.keys_dir in this process's settings (a forgotten --settings?) to the bus's keys "
                f"folder (`teleop keys init`, {_KEYS_HELP})")
    return (f"set bus.keys_dir in that peer's settings (a forgotten --settings?) to a copy of this bus's keys "
            f"({side.keys_dir}; {_KEYS_HELP})")


def _mismatch(endpoint: str, side: _Side) -> str:
    peer = f"a peer on {endpoint}" if side.server else f"the peer at {endpoint}"  # a server's is its own address
    if side.keys_dir is None:
        return f"{peer} runs CURVE and this process runs none: {_fix(side)}"
    return f"{peer} runs no CURVE and this process does (keys {side.keys_dir}): {_fix(side)}"


def _warning(kind: int, value: int, endpoint: str, side: _Side, *, reconnecting: bool = True) -> str:
    """What to say about a failed handshake on ``endpoint``, the fix included (``reconnecting``: and
    that a client retries it, while it still does)."""
    retry = f"; {_RECONNECTING}" if reconnecting and not side.server else ""
    if kind == zmq.EVENT_HANDSHAKE_FAILED_PROTOCOL:
        if value == _MISMATCH:
            return f"handshake on {endpoint} failed: {_mismatch(endpoint, side)}{retry}"
        return (f"handshake on {endpoint} failed (protocol error {value:#x}): run the same software version "
                f"and the same bus keys on both ends{retry}")
    if side.keys_dir is None:  # a CURVE server that saw the mismatch first drops the connection
        return (f"handshake on {endpoint} failed (the peer dropped the connection): it may run CURVE, and this "
                f"process runs none: {_fix(side)}")
    if kind == zmq.EVENT_HANDSHAKE_FAILED_AUTH:
        return (f"CURVE handshake with {endpoint} refused (the server does not authorise this client's key): "
                f"authorise {side.keys_dir / 'client.key'} on the server (`teleop keys add` there, then restart "
                f"the server){retry}")
    # a server drops a HELLO it cannot open, without a word: it was sealed for another server's key (read
    # once, at start); one without CURVE may drop it too, and libzmq retries either
    return (f"CURVE handshake with {endpoint} refused (the server dropped the connection: it runs no CURVE (set "
            f"bus.keys_dir in its settings), or it is not the server whose key this process trusts): check that "
            f"{side.keys_dir / 'server.key'} is that server's public certificate; fix server.key, then restart "
            "this process")


class HandshakeWatch:
    """What a socket's monitor thread saw: the endpoints libzmq gave up, for the socket's own thread to
    reconnect, and those a handshake failed with and none ever succeeded."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._due: dict[str, float] = {}  # endpoint given up -> when to reconnect it (monotonic)
        self._failed: dict[str, str] = {}  # endpoint -> why its last failed handshake failed
        self._connected: set[str] = set()  # endpoints a handshake succeeded with

    def gave_up(self, endpoint: str) -> None:
        with self._lock:
            self._due.setdefault(endpoint, time.monotonic() + RECONNECT_S)

    def failed(self, endpoint: str, why: str) -> None:
        """A handshake with ``endpoint`` failed, ``why`` (the fix included)."""
        with self._lock:
            self._failed[endpoint] = why

    def succeeded(self, endpoint: str) -> None:
        with self._lock:
            self._connected.add(endpoint)

    def never_connected(self) -> dict[str, str]:
        """Each endpoint a handshake failed with and none ever succeeded, with why the last one failed:
        nothing was received from it."""
        with self._lock:
            return {endpoint: why for endpoint, why in sorted(self._failed.items()) if endpoint not in self._connected}

    def next_due_s(self) -> float | None:
        """Seconds until the next reconnect is due; None when no endpoint is given up."""
        if not self._due:  # the usual case, without taking the lock
            return None
        with self._lock:
            return max(0.0, min(self._due.values()) - time.monotonic()) if self._due else None

    def reconnect_due(self, socket: zmq.Socket) -> None:
        """Reconnect each given-up endpoint whose time has come: call from ``socket``'s own thread.

        Raises BusError when libzmq refuses to connect the endpoint again."""
        if not self._due:
            return
        now = time.monotonic()
        with self._lock:
            due = [endpoint for endpoint, at in self._due.items() if at <= now]
            for endpoint in due:
                del self._due[endpoint]
        for endpoint in due:
            with contextlib.suppress(zmq.ZMQError):  # libzmq forgot it already: connecting is all it takes
                socket.disconnect(endpoint)
            try:
                socket.connect(endpoint)
            except zmq.ZMQError as exc:
                raise BusError(f"cannot reconnect {endpoint} after a failed handshake: {exc}") from exc


def _report(monitor: zmq.Socket, side: _Side, watch: HandshakeWatch) -> None:
    """Warn once per endpoint and outcome, note what libzmq gave up, until the watched socket closes."""
    warned: set[tuple[str, int, int]] = set()  # (endpoint, event, value): a few per endpoint at most
    dropped: dict[str, int] = {}  # endpoint -> connections dropped mid-greeting since its last handshake
    try:
        while True:
            event = recv_monitor_message(monitor)
            kind, value = event["event"], event["value"]
            endpoint = event["endpoint"].decode("utf-8", "replace")
            if kind == zmq.EVENT_MONITOR_STOPPED:
                return
            if kind == zmq.EVENT_HANDSHAKE_SUCCEEDED:
                dropped.pop(endpoint, None)
                watch.succeeded(endpoint)
                if any(seen[0] == endpoint for seen in warned):
                    warned = {seen for seen in warned if seen[0] != endpoint}
                    log.info("handshake with %s now succeeds", endpoint)
                continue
            if kind == zmq.EVENT_HANDSHAKE_FAILED_NO_DETAIL and side.keys_dir is None:
                # A peer exiting mid-greeting drops one connection; a CURVE server drops every retry.
                dropped[endpoint] = dropped.get(endpoint, 0) + 1
                if dropped[endpoint] < 2:
                    log.debug("handshake on %s: the peer dropped the connection", endpoint)
                    continue
            if side.server and value != _MISMATCH:
                continue  # a client with another server's key: it says so itself
            if not side.server:
                watch.failed(endpoint, _warning(kind, value, endpoint, side, reconnecting=False))
                if kind in _GIVES_UP:
                    watch.gave_up(endpoint)
            outcome = (endpoint, kind, value if kind == zmq.EVENT_HANDSHAKE_FAILED_PROTOCOL else 0)
            if outcome not in warned:
                warned.add(outcome)
                log.warning("%s", _warning(kind, value, endpoint, side))
    except zmq.ZMQError:  # the context was terminated under it
        pass
    finally:
        monitor.close(linger=0)


def watch_handshakes(socket: zmq.Socket, keys_dir: Path | None, *, server: bool) -> HandshakeWatch:
    """Report ``socket``'s failed handshakes from a thread reading its monitor (closing the socket
    stops it); call before it binds or connects. ``keys_dir``: its CURVE keys folder (None: no CURVE).
    A connecting socket's user calls :meth:`HandshakeWatch.reconnect_due` from its own thread."""
    # our own PAIR, not get_monitor_socket's (it hands its one socket to every caller): a
    # later monitor replaces this one, and this thread then hears MONITOR_STOPPED and ends
    address = f"inproc://teleop-handshakes-{next(_MONITORS)}"
    socket.monitor(address, _SERVER_EVENTS if server else _CLIENT_EVENTS)
    monitor = socket.context.socket(zmq.PAIR)
    monitor.connect(address)
    watch = HandshakeWatch()
    threading.Thread(target=_report, args=(monitor, _Side(server, keys_dir), watch), name="bus-handshakes",
                     daemon=True).start()
    return watch
