"""Publishers and subscribers over ZeroMQ, speaking only the wire format of :mod:`teleop.bus.wire`.

Two delivery modes
------------------
*Lossless* (grasp data: frames, forces, widths, grasp events). The publisher is an XPUB
socket with ``XPUB_NODROP``: when a subscriber's queue is full a send blocks for up to
``send_timeout_s`` and then raises :class:`~teleop.errors.BusTimeoutError`; nothing is
dropped silently. Both ends queue :data:`LOSSLESS_HWM` messages (about a minute of a
two-camera grasp stream), so a subscriber that falls briefly behind loses nothing. A process
that must not stop for one observer (the robot node: a recorder stopped with Ctrl-Z killed it
after three minutes) publishes with ``skip_stalled``: a send that finds no room in time goes to
every other subscriber instead of raising, and the stalled one misses it (libzmq leaves its queue
out of later sends until it drains, then delivers to it losslessly again: the send waits only once
per stall); the stalled one counts the gap when it reads again, and the publisher counts the
skips (:attr:`Publisher.stalled_skips`) and logs them as refusals are logged.
Every message carries a per-topic sequence number; a subscriber that sees a jump counts
a gap and logs how many messages it missed, and one that sees the number fall (the sender
restarted; what it had in flight cannot be counted) counts a restart and logs it. Both are
logged as refusals are (below), by message type, so a replayed or duplicated stream cannot
flood the log. A PUB socket has nowhere to deliver before a subscriber has subscribed: call
:meth:`Publisher.wait_for_subscriber` first.

*Latest value* (display topics: estimates, status). The publisher never blocks (a full
queue drops, as plain PUB does) and the subscriber keeps only the newest message per topic:
:meth:`Subscriber.recv` drains everything pending and hands out, per topic, the latest.
(``ZMQ_CONFLATE`` cannot be used: it keeps one frame, not one multipart message.)

Liveness
--------
A publisher sends a ``heartbeat`` message whenever :meth:`Publisher.heartbeat_if_due` finds
``heartbeat_s`` passed since the last one, whatever else it sends, so a subscriber of any
topic hears it (every Subscriber also subscribes to ``heartbeat``). Every accepted
message refreshes its source in :class:`~teleop.bus.peers.Heartbeat`, on the receiver's own
monotonic clock; :meth:`~teleop.bus.peers.Heartbeat.is_alive` says whether a peer was heard
from recently.

Refusals
--------
A subscriber that meets a message :func:`~teleop.bus.wire.decode` refuses counts it in
``stats.refused`` by reason and carries on. It logs the first refusal of each reason (the
sender its header names, the rule broken, what to do) and then a count at the 10th, 100th,
1000th ... of that reason, so a peer on another wire version cannot flood the log. A single frame larger than ``max_bytes``
never reaches decode: ZeroMQ (``ZMQ_MAXMSGSIZE``) drops that connection first, before
allocating it, and the publisher reconnects. A publisher likewise accepts from its
subscribers only frames up to :data:`CONTROL_FRAME_BYTES` (subscriptions, handshakes).

Security
--------
Pass ``security`` (:class:`~teleop.bus.security.BusSecurity`, e.g. from
:func:`~teleop.bus.security.security_from_settings`) to run ZeroMQ CURVE: the binding end
is the server and admits only authorised client keys, the connecting end authenticates
the server. An endpoint reachable from other hosts refuses to start without it
(:class:`~teleop.errors.BusSecurityError`). A failed handshake is logged once per endpoint and
outcome, and an endpoint a connecting socket gave up is reconnected (:mod:`teleop.bus.handshakes`).
:meth:`Publisher.from_settings` and :meth:`Subscriber.from_settings` take the size limit,
heartbeat period and keys from :class:`~teleop.settings.BusSettings`.

Memory
------
A subscriber remembers per source (its heartbeat), per source and topic (its sequence) and per
topic (the latest message, when conflating) at most :data:`~teleop.bus.peers.MAX_TRACKED` entries
each, forgetting the longest unheard beyond that (:class:`~teleop.bus.peers.Recent`), so a sender
that makes up a name per message cannot fill the memory.

Sockets are not thread-safe: use each Publisher and Subscriber from one thread.
"""

from __future__ import annotations

import dataclasses
import logging
import time
from collections import Counter
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import Any

import zmq

from teleop.bus.handshakes import HandshakeWatch, watch_handshakes
from teleop.bus.peers import Heartbeat, Recent
from teleop.bus.security import (
    CURVE_FRAME_OVERHEAD_BYTES,
    BusSecurity,
    apply_security,
    check_endpoints,
    security_from_settings,
)
from teleop.bus.wire import Message, claimed_source, decode, encode, make_message, now_ns
from teleop.endpoints import parse_endpoint
from teleop.errors import BusAddressInUseError, BusError, BusTimeoutError, MessageRejected
from teleop.settings import BusSettings

__all__ = [
    "CONTROL_FRAME_BYTES",
    "DEFAULT_MAX_BYTES",
    "LATEST_HWM",
    "LOSSLESS_HWM",
    "is_decade",
    "Publisher",
    "Subscriber",
    "SubscriberStats",
]

log = logging.getLogger(__name__)

DEFAULT_MAX_BYTES = 8 * 1024 * 1024
LOSSLESS_HWM = 10_000  # messages queued per peer before a lossless send blocks
LATEST_HWM = 100  # display topics: a short queue, the subscriber keeps the newest anyway
HEARTBEAT_TOPIC = "heartbeat"
# Largest frame a publisher reads from its subscribers: subscriptions (a topic prefix,
# at most wire.MAX_TOPIC_BYTES long) and handshake commands (a CURVE INITIATE is ~300 B).
CONTROL_FRAME_BYTES = 4096
# What to do about a refused message, by reason (the rest: a sender that breaks the wire format).
_REFUSAL_FIXES = {
    "unknown_version": "run the same software version on every host of the bus",
    "unknown_type": "the sender may run a newer software version: run the same one on every host of the bus",
    "oversize": "raise bus.max_message_bytes to the sender's, on every host, or send less",
}
_REFUSAL_FIX = "the sender breaks the bus wire format: a bug in it, or a program that is no bus node on this endpoint"


def _ms(seconds: float | None) -> int:
    return -1 if seconds is None else max(0, round(seconds * 1000))


def is_decade(count: int) -> bool:
    """Whether the ``count``-th of a repeated event is logged: the 1st, 10th, 100th, ..."""
    return count == 10 ** (len(str(count)) - 1)


class _Socket:
    """Lifecycle shared by both ends: context manager, idempotent close, use-after-close check."""

    _socket: zmq.Socket | None
    _release_security: Callable[[], None] = staticmethod(lambda: None)  # set by _secure
    _handshakes: HandshakeWatch | None = None  # set by _secure

    def _live(self) -> zmq.Socket:
        if self._socket is None:
            raise BusError(f"{type(self).__name__} on {self.endpoint_text} is closed")
        if self._handshakes is not None:  # here, on the socket's own thread: sockets are not thread-safe
            self._handshakes.reconnect_due(self._socket)
        return self._socket

    @property
    def endpoint_text(self) -> str:
        raise NotImplementedError

    def close(self) -> None:
        """Close the socket (pending messages are discarded); calling twice is fine."""
        if self._socket is not None:
            self._socket.close(linger=0)
            self._socket = None
            self._release_security()  # after close: the ZAP handler outlives the socket

    def _secure(self, socket: zmq.Socket, security: BusSecurity | None, *, server: bool) -> None:
        """CURVE on ``socket`` before it binds or connects (see :mod:`teleop.bus.security`), and its
        handshakes watched (:mod:`teleop.bus.handshakes`): a failure is logged, and an endpoint libzmq
        gave up is reconnected when the socket is next used."""
        self._release_security = apply_security(socket, security, server=server)
        self._handshakes = watch_handshakes(socket, None if security is None else security.keys_dir, server=server)

    def _abandon(self, socket: zmq.Socket, exc: Exception, what: str, setting: str = "") -> BusError:
        """Close a socket whose setup failed; the error to raise for ``exc`` (``setting``: the
        settings key naming the endpoint, for the fix of one in use)."""
        socket.close(linger=0)
        self._release_security()
        if isinstance(exc, BusError):
            return exc
        if isinstance(exc, zmq.ZMQError) and exc.errno == zmq.EADDRINUSE:
            return BusAddressInUseError(f"{what}: {exc}: another process (a session still running?) holds it: "
                                        f"stop it or choose another port" + (f" in {setting}" if setting else ""))
        return BusError(f"{what}: {exc}")

    def __enter__(self):
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()


class Publisher(_Socket):
    """Sends bus messages on one endpoint.

    Parameters
    ----------
    endpoint : str
        ZeroMQ endpoint, e.g. ``tcp://127.0.0.1:5550`` (``tcp://127.0.0.1:*`` picks a free
        port; :attr:`endpoint` then holds the one bound) or ``inproc://name``.
    lossless : bool
        True for grasp data (block with timeout instead of dropping), False for display
        topics (never block). See the module docstring.
    bind : bool
        Bind (the usual publisher) or connect (to a proxy that binds).
    source : str
        Node name written into every header (``"robot"``, ``"estimator"``).
    max_bytes : int
        Largest message this publisher will send (receivers apply their own limit).
    send_timeout_s : float
        How long a lossless send may wait for room before raising BusTimeoutError.
    skip_stalled : bool
        Lossless only: a send that found no room in time goes to the other subscribers instead of
        raising (see the module docstring).
    heartbeat_s : float
        Heartbeat period for :meth:`heartbeat_if_due`.
    high_water_mark : int, optional
        Messages queued per subscriber; :data:`LOSSLESS_HWM` or :data:`LATEST_HWM` by default.
    context : zmq.Context, optional
        The process-wide context by default (``inproc://`` needs both ends on one context).
    security : BusSecurity, optional
        CURVE keys: the publisher is the CURVE server when it binds, a client when it
        connects. Required when ``endpoint`` is not loopback.
    setting : str
        The settings key that names ``endpoint`` (``bus.robot_pub``), for the fix an endpoint
        in use is told with; :meth:`from_settings` fills it in.

    Raises
    ------
    BusSecurityError
        ``endpoint`` is not loopback and ``security`` is None, or the keys are unusable.
    BusError
        ZeroMQ cannot bind or connect ``endpoint``.
    """

    def __init__(
        self,
        endpoint: str,
        *,
        lossless: bool,
        bind: bool = True,
        source: str = "",
        max_bytes: int = DEFAULT_MAX_BYTES,
        send_timeout_s: float = 1.0,
        skip_stalled: bool = False,
        heartbeat_s: float = 0.5,
        high_water_mark: int | None = None,
        context: zmq.Context | None = None,
        security: BusSecurity | None = None,
        setting: str = "",
    ):
        if not isinstance(lossless, bool):
            raise BusError(f"lossless = {lossless!r}: expected True or False")
        self.lossless = lossless
        self.skip_stalled = skip_stalled
        self.stalled_skips = 0  # sends that found a subscriber stalled and went to the others (skip_stalled)
        self.source = source
        self.max_bytes = max_bytes
        self.heartbeat_s = heartbeat_s
        self.send_timeout_s = send_timeout_s
        self.sent = 0
        self._seq: Counter[str] = Counter()
        self._subscriptions: Counter[bytes] = Counter()
        self._last_heartbeat_s: float | None = None
        self._socket = None
        check_endpoints([endpoint], security)
        socket = (context or zmq.Context.instance()).socket(zmq.XPUB)
        try:
            socket.setsockopt(zmq.IPV6, parse_endpoint(endpoint).ipv6)
            hwm = high_water_mark or (LOSSLESS_HWM if lossless else LATEST_HWM)
            socket.setsockopt(zmq.SNDHWM, hwm)
            socket.setsockopt(zmq.XPUB_NODROP, int(lossless))
            socket.setsockopt(zmq.XPUB_VERBOSER, 1)  # every (un)subscription reaches us
            socket.setsockopt(zmq.SNDTIMEO, _ms(send_timeout_s))
            socket.setsockopt(zmq.LINGER, 0)
            socket.setsockopt(zmq.MAXMSGSIZE, CONTROL_FRAME_BYTES)
            self._secure(socket, security, server=bind)
            (socket.bind if bind else socket.connect)(endpoint)
            self.endpoint = socket.getsockopt_string(zmq.LAST_ENDPOINT) if bind else endpoint
        except (zmq.ZMQError, BusError) as exc:
            what = f"cannot {'bind' if bind else 'connect'} publisher on {endpoint!r}"
            raise self._abandon(socket, exc, what, setting) from exc
        self._socket = socket

    @classmethod
    def from_settings(cls, bus: BusSettings, endpoint: str, *, lossless: bool, **options: Any) -> Publisher:
        """A publisher on ``endpoint`` with ``bus``'s size limit, heartbeat period and keys.

        ``options`` are the remaining constructor arguments (``source``, ``bind``, ...).
        Raises BusSecurityError when any bus endpoint needs keys that are not configured.
        """
        names = [f"bus.{name}" for name in bus.ENDPOINTS if getattr(bus, name) == endpoint]
        return cls(
            endpoint,
            lossless=lossless,
            max_bytes=bus.max_message_bytes,
            heartbeat_s=bus.heartbeat_s,
            security=security_from_settings(bus),
            setting=names[0] if names else "",
            **options,
        )

    @property
    def endpoint_text(self) -> str:
        return self.endpoint

    def send(self, kind: str, *, t_capture_s: float, topic: str | None = None, **body: Any) -> Message:
        """Build a ``kind`` message from ``body`` (see :func:`~teleop.bus.wire.make_message`) and publish it."""
        return self.publish(make_message(kind, t_capture_s=t_capture_s, topic=topic, **body))

    def publish(self, message: Message) -> Message:
        """Send ``message`` with this publisher's source, the topic's next seq and the send time.

        Returns the message as sent. Raises MessageRejected for a malformed or oversized
        message and BusTimeoutError when a lossless send found no room in time.
        """
        socket = self._live()
        topic = message.topic or message.type
        sent = dataclasses.replace(
            message, topic=topic, source=self.source, seq=self._seq[topic], t_send_ns=now_ns()
        )
        try:
            frames = encode(sent, max_bytes=self.max_bytes)
        except MessageRejected as exc:
            if exc.reason != "oversize":
                raise
            # the sender's own limit: say which setting it is, not the receivers' fix
            raise MessageRejected("oversize", f"{self.endpoint}: {topic!r} {exc.detail} (bus.max_message_bytes): "
                                              "raise bus.max_message_bytes on every host, or send less") from None
        try:
            socket.send_multipart(frames, copy=False, flags=0 if self.lossless else zmq.NOBLOCK)
        except zmq.Again as exc:
            if not self.lossless:  # a full latest-value queue: dropping is the contract
                return sent
            if not self.skip_stalled:
                raise BusTimeoutError(
                    f"{self.endpoint}: no room for {topic!r} seq {sent.seq} within {self.send_timeout_s} s "
                    "(a subscriber is not keeping up)"
                ) from exc
            self._send_past_stalled(socket, frames, topic, sent.seq)
        self._seq[topic] += 1
        self.sent += 1
        return sent

    def _send_past_stalled(self, socket: zmq.Socket, frames: list, topic: str, seq: int) -> None:
        """Send ``frames`` to every subscriber with room: the full one misses it (module docstring)."""
        socket.setsockopt(zmq.XPUB_NODROP, 0)
        try:
            socket.send_multipart(frames, copy=False, flags=zmq.NOBLOCK)  # dropping, it never waits
        finally:
            socket.setsockopt(zmq.XPUB_NODROP, 1)
        self.stalled_skips += 1
        if is_decade(self.stalled_skips):
            log.warning("%s: a subscriber stalled (no room for %r seq %d within %s s): sent to the others, that "
                        "one misses it and sees the gap; %d such sends so far (logged at the 1st, 10th, 100th ...)",
                        self.endpoint, topic, seq, self.send_timeout_s, self.stalled_skips)

    def heartbeat_if_due(self, now_s: float | None = None) -> bool:
        """Send a heartbeat if ``heartbeat_s`` passed since the last one; True if sent."""
        now = time.monotonic() if now_s is None else now_s
        if self._last_heartbeat_s is not None and now - self._last_heartbeat_s < self.heartbeat_s:
            return False
        self.send("heartbeat", t_capture_s=now, interval_s=self.heartbeat_s)
        self._last_heartbeat_s = now
        return True

    def wait_for_subscriber(self, *topics: str, timeout_s: float = 5.0) -> None:
        """Block until every one of ``topics`` has a subscriber (to a prefix of it).

        No topic waits for any subscription at all. Wait for each topic a test or a
        sender needs: subscriptions arrive one by one, and until one has arrived this
        publisher drops that topic's messages. Raises BusTimeoutError if some topic has
        none within ``timeout_s``.
        """
        socket = self._live()
        wanted = [t.encode("utf-8") for t in topics or ("",)]
        deadline = time.monotonic() + timeout_s
        while missing := [w for w in wanted if not any(n > 0 and w.startswith(p) for p, n in self._subscriptions.items())]:
            remaining = deadline - time.monotonic()
            if remaining <= 0 or not socket.poll(_ms(remaining)):
                names = ", ".join(repr(m.decode()) for m in missing)
                raise BusTimeoutError(f"{self.endpoint}: no subscriber for {names} within {timeout_s} s")
            self._take_subscription(socket.recv())

    def subscriptions(self, prefix: str) -> int:
        """How many subscriptions to exactly ``prefix`` are open now (a subscriber to a shorter
        prefix is not counted); reads those that arrived, without waiting."""
        socket = self._live()
        while socket.poll(0):
            self._take_subscription(socket.recv())
        return max(0, self._subscriptions[prefix.encode("utf-8")])

    def _take_subscription(self, event: bytes) -> None:
        # XPUB delivers b"\x01<prefix>" for a subscription and b"\x00<prefix>" for its end (a
        # subscriber that closes or goes away ends each of its own).
        if event[:1] in (b"\x00", b"\x01"):
            self._subscriptions[event[1:]] += 1 if event[:1] == b"\x01" else -1


@dataclass
class SubscriberStats:
    """What a subscriber received: accepted messages, refusals by reason, sequence gaps."""

    received: int = 0
    refused: Counter[str] = field(default_factory=Counter)
    gaps: int = 0  # sequence jumps seen
    missed: int = 0  # messages those jumps skipped
    restarts: int = 0  # a source's topic started again from a lower seq (the sender restarted)


class Subscriber(_Socket):
    """Receives bus messages from one or more publishers.

    Parameters
    ----------
    endpoints : str or iterable of str
        Publisher endpoints to connect to.
    topics : iterable of str
        Topic prefixes to receive (``""``: everything). ``heartbeat`` is always added.
    conflate : bool
        False: every message, in order (lossless topics). True: per topic only the newest
        (display topics). See the module docstring.
    max_bytes : int
        Largest message accepted; larger ones are refused (reason ``oversize``).
    high_water_mark : int, optional
        Messages queued before ZeroMQ stops reading; per mode by default.
    context : zmq.Context, optional
        The process-wide context by default.
    bind : bool
        Connect to publishers (the usual subscriber) or bind (publishers connect to it).
        A binding subscriber hands its subscriptions to a publisher that connects only
        while it is in :meth:`recv` (libzmq processes the new peer on the socket's own
        thread), so keep calling :meth:`recv`.
    security : BusSecurity, optional
        CURVE keys: the subscriber is a CURVE client when it connects, the server when it
        binds. Required when an endpoint is not loopback.

    Raises
    ------
    BusSecurityError
        An endpoint is not loopback and ``security`` is None, or the keys are unusable.
    BusError
        ZeroMQ cannot connect or bind an endpoint.
    """

    def __init__(
        self,
        endpoints: str | Iterable[str],
        topics: Iterable[str] = ("",),
        *,
        conflate: bool = False,
        max_bytes: int = DEFAULT_MAX_BYTES,
        high_water_mark: int | None = None,
        context: zmq.Context | None = None,
        bind: bool = False,
        security: BusSecurity | None = None,
    ):
        if isinstance(topics, str | bytes) or not isinstance(topics, Iterable):
            what = f"the str {topics!r}" if isinstance(topics, str) else repr(topics)
            raise BusError(f"topics: expected a sequence of topic names, got {what}")
        if not isinstance(endpoints, str | Iterable):
            raise BusError(f"endpoints: expected an endpoint or a sequence of endpoints, got {endpoints!r}")
        self.endpoints = [endpoints] if isinstance(endpoints, str) else list(endpoints)
        self.topics = sorted({*topics, HEARTBEAT_TOPIC})
        self.conflate = conflate
        self.max_bytes = max_bytes
        self.stats = SubscriberStats()
        self.heartbeat = Heartbeat()
        self._last_seq: Recent = Recent("(source, topic) pairs sequence-checked")
        # Restarts and gaps by message type, for logging: a bounded set, so a node's restart is
        # logged for each of its topics, yet made-up sources or topics cannot flood the log.
        self._restarts: Counter[str] = Counter()
        self._gaps: Counter[str] = Counter()
        self._latest: Recent = Recent("topics with a message waiting to be read")
        self._socket = None
        check_endpoints(self.endpoints, security)
        socket = (context or zmq.Context.instance()).socket(zmq.SUB)
        try:
            socket.setsockopt(zmq.IPV6, any(parse_endpoint(e).ipv6 for e in self.endpoints))
            socket.setsockopt(zmq.RCVHWM, high_water_mark or (LATEST_HWM * 10 if conflate else LOSSLESS_HWM))
            # Checked on each frame's length prefix, before libzmq allocates the frame.
            overhead = CURVE_FRAME_OVERHEAD_BYTES if security is not None else 0
            socket.setsockopt(zmq.MAXMSGSIZE, max_bytes + overhead)
            socket.setsockopt(zmq.LINGER, 0)
            self._secure(socket, security, server=bind)
            resolved = []
            for endpoint in self.endpoints:
                (socket.bind if bind else socket.connect)(endpoint)
                # a bound tcp://HOST:* names the port it got, as Publisher.endpoint does
                resolved.append(socket.getsockopt_string(zmq.LAST_ENDPOINT) if bind else endpoint)
            self.endpoints = resolved
            for topic in self.topics:
                socket.setsockopt(zmq.SUBSCRIBE, topic.encode("utf-8"))
        except (zmq.ZMQError, BusError) as exc:
            what = f"cannot {'bind' if bind else 'connect'} subscriber to {self.endpoints}"
            raise self._abandon(socket, exc, what) from exc
        self._socket = socket

    @classmethod
    def from_settings(
        cls,
        bus: BusSettings,
        endpoints: str | Iterable[str],
        topics: Iterable[str] = ("",),
        **options: Any,
    ) -> Subscriber:
        """A subscriber of ``endpoints`` with ``bus``'s size limit and keys.

        ``options`` are the remaining constructor arguments (``conflate``, ``bind``, ...).
        Raises BusSecurityError when any bus endpoint needs keys that are not configured.
        """
        security = security_from_settings(bus)
        return cls(endpoints, topics, max_bytes=bus.max_message_bytes, security=security, **options)

    @property
    def endpoint_text(self) -> str:
        return ", ".join(self.endpoints)

    def recv(self, timeout_s: float | None = None) -> Message | None:
        """The next message (latest per topic when conflating), or None after ``timeout_s``.

        ``timeout_s=None`` waits indefinitely; ``timeout_s=0`` looks once, without waiting, at
        what is already queued (None if that was a heartbeat or a refused message).
        Heartbeats update :attr:`heartbeat` and are not returned; refused messages are
        logged, counted and skipped.
        """
        socket = self._live()
        deadline = None if timeout_s is None else time.monotonic() + timeout_s
        looked = False
        while True:
            if self.conflate:
                while socket.poll(0):
                    self._keep_latest(self._accept(socket.recv_multipart(copy=False)))
                if self._latest:
                    return self._latest.popitem(last=False)[1]
            remaining = None if deadline is None else deadline - time.monotonic()
            # Look at least once (timeout_s=0 takes a queued message), but never past the
            # deadline after that: a peer flooding heartbeats must not keep recv from returning.
            if looked and remaining is not None and remaining <= 0:
                return None
            looked = True
            wait = None if remaining is None else max(0.0, remaining)
            # an endpoint libzmq gave up is reconnected by _live, from this thread: wake for it
            retry_in = None if self._handshakes is None else self._handshakes.next_due_s()
            if retry_in is not None and (wait is None or retry_in < wait):
                if not socket.poll(_ms(retry_in)):
                    self._live()
                    continue
            elif not socket.poll(_ms(wait)):
                return None
            if not self.conflate:
                message = self._accept(socket.recv_multipart(copy=False))
                if message is not None:
                    return message

    def _keep_latest(self, message: Message | None) -> None:
        if message is not None:
            self._latest[message.topic] = message  # moves to the end: newest last

    def _accept(self, frames: list[zmq.Frame]) -> Message | None:
        try:
            message = decode(frames, max_bytes=self.max_bytes)
        except MessageRejected as exc:
            self._refused(exc, frames)
            return None
        self.stats.received += 1
        self._check_sequence(message)
        if message.type == "heartbeat":
            self.heartbeat.saw(message.source, interval_s=message.fields.interval_s)
            return None
        self.heartbeat.saw(message.source)
        return message

    def _refused(self, exc: MessageRejected, frames: list[zmq.Frame]) -> None:
        """Count a refusal; log the first of its reason, then a count at every power of ten."""
        self.stats.refused[exc.reason] += 1
        count = self.stats.refused[exc.reason]
        source = claimed_source(frames)
        sender = (f"source {source!r}" if source is not None else "a sender that names none") + (
            f" on {self.endpoints[0]}" if len(self.endpoints) == 1 else f" (one of {self.endpoint_text})")
        if count == 1:
            log.warning("refused a message from %s: %s: %s; further %s refusals are counted, not each logged",
                        sender, exc, _REFUSAL_FIXES.get(exc.reason, _REFUSAL_FIX), exc.reason)
        elif is_decade(count):
            log.warning("refused %d messages for %s so far, the last from %s", count, exc.reason, sender)

    def _check_sequence(self, message: Message) -> None:
        key = (message.source, message.topic)
        last = self._last_seq.get(key)
        self._last_seq[key] = message.seq
        if last is None or message.seq == last + 1:
            return
        if message.seq <= last:
            # What the old sender had in flight when it died cannot be counted: say so.
            self.stats.restarts += 1
            self._restarts[message.type] += 1
            if is_decade(self._restarts[message.type]):
                log.warning("%s restarted topic %r at seq %d (was %d): messages in flight then may be lost "
                            "(restart %d of %s seen; logged at the 1st, 10th, 100th ...)", message.source,
                            message.topic, message.seq, last, self._restarts[message.type], message.type)
            return
        missed = message.seq - last - 1
        self.stats.gaps += 1
        self.stats.missed += missed
        self._gaps[message.type] += 1
        if is_decade(self._gaps[message.type]):
            log.warning("missed %d message(s) of %r from %s before seq %d (gap %d of %s seen; logged at the 1st, "
                        "10th, 100th ...)", missed, message.topic, message.source, message.seq,
                        self._gaps[message.type], message.type)
