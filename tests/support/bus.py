"""Bus helpers for tests: publish until a subscriber hears; a raw publisher that knows when it is heard."""

from __future__ import annotations

import dataclasses
import time

import zmq

from teleop.bus import Message, Publisher, Subscriber
from teleop.bus.wire import make_message

#: How long a test waits for a delivery it expects: it returns at the first message, so this is only
#: how long a loaded machine may take (a CURVE handshake beside a full test run took over 2 s).
HEARD_WITHIN_S = 15.0


def force(pub: Publisher, i: int) -> None:
    pub.send("force", t_capture_s=float(i), t_s=[float(i)], value_n=[float(i)])


def delivered(pub: Publisher, *subs: Subscriber, within_s: float) -> Message | None:
    """Publish while ``subs`` listen, until one of them gets a message: that message, or
    None after ``within_s``. The subscribers are polled throughout: libzmq hands a SUB's
    subscriptions to a new or reconnected peer only while its socket is being used."""
    deadline = time.monotonic() + within_s
    i = 0
    while time.monotonic() < deadline:
        force(pub, i)
        i += 1
        for sub in subs:
            if (message := sub.recv(timeout_s=0.01)) is not None:
                return message
    return None


def raw_publisher(endpoint: str = "tcp://127.0.0.1:*") -> tuple[zmq.Socket, str]:
    """A raw ZeroMQ publisher bound to ``endpoint`` (a rogue peer, sending whatever frames a test
    wants) and the endpoint it took. An XPUB, not a PUB: it hears the subscriptions, so a test can
    wait for them (:func:`wait_subscribed`) instead of sleeping for the slow joiner."""
    socket = zmq.Context.instance().socket(zmq.XPUB)
    socket.setsockopt(zmq.LINGER, 0)
    socket.bind(endpoint)
    return socket, socket.getsockopt_string(zmq.LAST_ENDPOINT)


def wait_subscribed(raw: zmq.Socket, *topics: str, timeout_s: float = 5.0) -> None:
    """Block until a subscription to each of ``topics`` has reached ``raw`` (from
    :func:`raw_publisher`): from then on, what it sends on them is delivered."""
    missing = {topic.encode("utf-8") for topic in topics}
    deadline = time.monotonic() + timeout_s
    while missing:
        left_ms = int((deadline - time.monotonic()) * 1000)
        assert left_ms > 0 and raw.poll(left_ms), f"no subscription to {sorted(missing)} within {timeout_s} s"
        frame = raw.recv()
        if frame[:1] == b"\x01":  # a subscription (b"\x00" starts an unsubscription)
            missing.discard(frame[1:])


def admit_a_bound_without_its_bound(monkeypatch) -> None:
    """Let through the wire what it refuses (tests/teleop/bus/test_typed_bodies.py): a bound state
    with no value and no bound in its interval, as a sender on an older wire would send it, so a
    test can show what its receiver, which has nothing to render, does with it."""
    from teleop.bus.messages import EstimateBody

    monkeypatch.setattr(EstimateBody, "cross_check", lambda self: None)


class KeptPublisher:
    """A publisher that keeps what is sent instead of sending it; setting ``beat`` makes the next
    heartbeat due (none is otherwise)."""

    heartbeat_s = 1.0

    def __init__(self):
        self.sent: list[tuple[str, dict]] = []
        self.beat = False

    def heartbeat_if_due(self, now_s=None) -> bool:
        due, self.beat = self.beat, False
        return due

    def send(self, kind: str, **body) -> None:
        self.sent.append((kind, body))

    def of(self, kind: str) -> list[dict]:
        """The bodies sent as ``kind``, in order."""
        return [body for k, body in self.sent if k == kind]


def message_from(source: str, kind: str, **body) -> Message:
    """A ``kind`` message with ``body``, as ``source`` sent it, captured at 1 s."""
    return dataclasses.replace(make_message(kind, t_capture_s=1.0, **body), source=source)


class ReplayedEvents:
    """A subscription replaying ``messages``, then silent."""

    def __init__(self, messages: list):
        self.messages = messages

    def recv(self, timeout_s: float):
        return self.messages.pop(0) if self.messages else None
