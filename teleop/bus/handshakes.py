"""A CURVE client's failed handshakes, said once per endpoint (libzmq itself says nothing).

A client the server refuses gives that endpoint up (libzmq 4.3.5); one that trusts another
server's key retries. :func:`watch_handshakes` reads the socket's monitor in a thread and warns
once per endpoint that refused it, naming the certificates to check; only CURVE clients pay for
it (:func:`teleop.bus.security.apply_security`).
"""

from __future__ import annotations

import itertools
import logging
import threading
from pathlib import Path

import zmq
from zmq.utils.monitor import recv_monitor_message

__all__ = ["watch_handshakes"]

log = logging.getLogger(__name__)

_MONITORS = itertools.count()  # numbers the monitors' inproc addresses
# What the watcher hears (MONITOR_STOPPED: the socket closed).
_EVENTS = (zmq.EVENT_HANDSHAKE_FAILED_AUTH | zmq.EVENT_HANDSHAKE_FAILED_NO_DETAIL
           | zmq.EVENT_HANDSHAKE_FAILED_PROTOCOL | zmq.EVENT_HANDSHAKE_SUCCEEDED | zmq.EVENT_MONITOR_STOPPED)
# Why a handshake failed, and whether libzmq tries again: after a refusal or a protocol error
# its client gives the endpoint up; after a dropped connection it reconnects.
_FAILURES = {
    zmq.EVENT_HANDSHAKE_FAILED_AUTH: ("the server does not authorise this client's key", False),
    # a server drops a HELLO it cannot open, without a word: it was sealed for another server's key;
    # a server that runs no CURVE may drop it too
    zmq.EVENT_HANDSHAKE_FAILED_NO_DETAIL: (
        "the server dropped the connection: it is not the server whose key this node trusts, or it runs "
        "no CURVE (set bus.keys_dir on its host)", True),
    zmq.EVENT_HANDSHAKE_FAILED_PROTOCOL: (
        "protocol error: the server may run no CURVE (set bus.keys_dir on its host)", False),
}
_GIVEN_UP = "this client gives the endpoint up: restart it once that is fixed"


def _report(monitor: zmq.Socket, server_cert: Path, client_cert: Path) -> None:
    """Warn once per endpoint whose handshake fails, until the watched socket closes."""
    warned: set[str] = set()
    try:
        while True:
            event = recv_monitor_message(monitor)
            kind, endpoint = event["event"], event["endpoint"].decode("utf-8", "replace")
            if kind == zmq.EVENT_MONITOR_STOPPED:
                return
            if kind == zmq.EVENT_HANDSHAKE_SUCCEEDED:
                if endpoint in warned:
                    warned.discard(endpoint)
                    log.info("CURVE handshake with %s now succeeds", endpoint)
            elif endpoint not in warned:
                warned.add(endpoint)
                reason, retried = _FAILURES.get(kind, (f"event {kind}", False))
                log.warning(
                    "CURVE handshake with %s refused (%s): check that %s is that server's public "
                    "certificate and that this client's key (%s) is authorised on the server "
                    "(`teleop keys add` there, then restart the server); %s",
                    endpoint, reason, server_cert, client_cert, "retrying" if retried else _GIVEN_UP,
                )
    except zmq.ZMQError:  # the context was terminated under it
        pass
    finally:
        monitor.close(linger=0)


def watch_handshakes(socket: zmq.Socket, *, server_cert: Path, client_cert: Path) -> None:
    """Report ``socket``'s failed handshakes from a thread reading its monitor (closing the
    socket stops it); the warning names the certificates (public ``.key`` files) to check."""
    # our own PAIR, not get_monitor_socket's (it hands its one socket to every caller): a
    # later monitor replaces this one, and this thread then hears MONITOR_STOPPED and ends
    address = f"inproc://teleop-curve-handshakes-{next(_MONITORS)}"
    socket.monitor(address, _EVENTS)
    monitor = socket.context.socket(zmq.PAIR)
    monitor.connect(address)
    threading.Thread(target=_report, args=(monitor, server_cert, client_cert), name="curve-handshakes",
                     daemon=True).start()
