"""Live view: the bus served over Foxglove's WebSocket protocol, as the session log shows it.

:class:`LiveServer` starts a ``foxglove-sdk`` WebSocket server (subprotocol
``foxglove.sdk.v1``) in its own SDK context and logs the Foxglove forms of each bus message
(:mod:`teleop.session.foxglove`, the same conversion the log uses, so the shipped layout
works on both). Every channel of a bus type's default topic
(:func:`~teleop.session.foxglove.known_channels`) is created as the server starts, so a
client sees them all in its first ``advertise``: a channel created while a client is
connected can be refused to that client's ``subscribe`` ("Unknown channel ID", a race in
foxglove-sdk 0.30), and it would then never see that topic. Other topics (a suffixed bus
topic, an unexpected finger) get their channel on their first message. Message times are
log times, nanoseconds since the Unix epoch as in the session log (this host's
``time.monotonic_ns()`` plus an offset read once at the start), each topic's kept in order.
``teleop record --foxglove`` serves what it records; ``teleop demo --foxglove`` passes the
option to its recorder. Clients that fall behind lose the oldest messages (the SDK's
per-client backlog), never the recording.

:class:`LiveTap` serves what one live service publishes: ``teleop node``, ``estimator
serve`` and ``haptics serve`` take the same ``--foxglove`` option and tap their own
publisher endpoint. The tap is a subscriber of its own (every topic, non-conflating) read
in a background thread, which takes each message off the socket at once and keeps at most
``max_pending`` waiting for conversion, dropping (and counting) the oldest beyond that, so
a lossless publisher never waits for it. A tap that cannot start or fails later logs one
error and stops; the service carries on without it.
"""

from __future__ import annotations

import argparse
import errno
import logging
import os
import sys
import threading
import time
from collections import deque
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Any

import foxglove

from teleop.bus.pubsub import Subscriber
from teleop.bus.security import host_is_loopback
from teleop.bus.wire import Message, now_ns
from teleop.clikit import help_literal
from teleop.errors import BusError
from teleop.session.foxglove import (
    FoxgloveChannel,
    FoxgloveMessage,
    foxglove_messages,
    in_topic_order,
    known_channels,
)
from teleop.settings import BusSettings, Settings, config_dir

__all__ = [
    "DEFAULT_ADDRESS",
    "LiveServer",
    "LiveTap",
    "LiveTapStats",
    "add_foxglove_argument",
    "parse_address",
]

log = logging.getLogger(__name__)

DEFAULT_HOST, DEFAULT_PORT = "127.0.0.1", 8765
DEFAULT_ADDRESS = f"{DEFAULT_HOST}:{DEFAULT_PORT}"


def parse_address(text: str) -> tuple[str, int]:
    """``[HOST:]PORT`` as ``(host, port)``; the host defaults to 127.0.0.1, port 0: any free one.

    Raises
    ------
    BusError
        The port is not an integer in 0..65535, or the host is empty.
    """
    host, _, port = text.rpartition(":")
    host = host.strip("[]") if host else DEFAULT_HOST  # [::1]:8765
    try:
        number = int(port)
    except ValueError:
        number = -1
    if not 0 <= number <= 65535 or not host:
        raise BusError(f"Foxglove address {text!r}: expected [HOST:]PORT with PORT in 0..65535")
    return host, number


def add_foxglove_argument(parser: argparse.ArgumentParser, *, what: str) -> None:
    """The ``--foxglove [[HOST:]PORT]`` option (``args.foxglove``: ``(host, port)`` or None)."""

    def address(text: str) -> tuple[str, int]:
        try:
            return parse_address(text)
        except BusError as exc:
            raise argparse.ArgumentTypeError(str(exc)) from None

    parser.add_argument(
        "--foxglove",
        nargs="?",
        type=address,
        const=parse_address(DEFAULT_ADDRESS),
        default=None,
        metavar="[HOST:]PORT",
        help=f"serve {what} live to Foxglove over its WebSocket protocol on HOST:PORT "
        f"(alone: {DEFAULT_ADDRESS}; PORT 0: any free port); open it in Foxglove with "
        f"'Open connection' > 'Foxglove WebSocket' and ws://HOST:PORT, and import "
        f"{help_literal(config_dir() / 'foxglove' / 'layout.json')}",
    )


class LiveServer:
    """A Foxglove WebSocket server for the Foxglove forms of bus messages.

    Parameters
    ----------
    host, port : str, int
        Where to listen (port 0: a free one, see :attr:`url`).
    name : str
        Server name shown by Foxglove.
    fingers : iterable of str, optional
        Fingers whose tactile image channels to create at the start; default the default
        rig's (``left``, ``right``).

    Raises
    ------
    BusError
        The server cannot start (the port is taken, the host is not this machine's).

    A host other hosts can reach (``0.0.0.0``, a LAN address) is served with a warning: the view is
    neither encrypted nor authenticated.
    """

    def __init__(
        self,
        host: str = DEFAULT_HOST,
        port: int = DEFAULT_PORT,
        *,
        name: str = "compliance-teleop",
        fingers: Iterable[str] | None = None,
    ):
        self._context = foxglove.Context()
        # Channels before the server: no client can connect before they are all there.
        self._channels: dict[str, foxglove.Channel] = {}
        if fingers is None:
            fingers = [sensor.finger for sensor in Settings().sensors]
        for channel in known_channels(fingers):
            self._channel(channel)
        self._last_ns: dict[str, int] = {}  # topic -> its latest log time
        self.offset_ns = time.time_ns() - now_ns()  # monotonic receive time -> epoch ns
        try:
            self._server = foxglove.start_server(
                name=name, host=host, port=port, context=self._context
            )
        except Exception as exc:  # the SDK reports bind failures as plain RuntimeErrors
            self._close_channels()
            # no errno on them: the message holds the system's words for it
            fix = (": another program (a session still running?) holds the port: stop it or choose another "
                   "(--foxglove PORT, or --foxglove 0 for any free one)"
                   if os.strerror(errno.EADDRINUSE) in str(exc) else "")
            raise BusError(f"cannot serve the Foxglove live view on {host}:{port}: {exc}{fix}") from exc
        self.host = host
        if not host_is_loopback(host):
            # the bus refuses such an endpoint without CURVE keys; this view has none to run
            log.warning("the Foxglove live view %s is reachable from other hosts, unencrypted and without "
                        "authentication (the bus's CURVE keys do not cover it): anyone on the network can watch the "
                        "bus's data; serve it on 127.0.0.1 and reach it through an SSH tunnel (ssh -L %d:127.0.0.1:%d "
                        "THIS-HOST) unless this network is trusted", self.url, self.port, self.port)

    @property
    def port(self) -> int:
        return self._server.port

    @property
    def url(self) -> str:
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"ws://{host}:{self.port}"

    def log(self, converted: Sequence[FoxgloveMessage], log_time_ns: int) -> None:
        """Send Foxglove messages of one bus message whose log time is ``log_time_ns``.

        Each goes out at that time less its age, but never before its topic's previous
        message (a batch's oldest sample can fall before the previous batch's newest when
        delivery latency varies). Has the signature of
        :class:`~teleop.session.recorder.SessionRecorder`'s ``on_foxglove`` hook.
        """
        for item in converted:
            channel = self._channels.get(item.topic) or self._channel(item.channel)
            channel.log(item.data, log_time=in_topic_order(self._last_ns, item.topic, log_time_ns - item.age_ns))

    def log_message(self, message: Message, received_ns: int) -> None:
        """Send the Foxglove forms of one bus message received at ``received_ns`` (this
        host's ``time.monotonic_ns()``)."""
        self.log(foxglove_messages(message, self.offset_ns), received_ns + self.offset_ns)

    def close(self) -> None:
        """Stop serving; calling twice is fine."""
        self._close_channels()
        self._server.stop()

    def _channel(self, spec: FoxgloveChannel) -> foxglove.Channel:
        channel = foxglove.Channel(
            spec.topic,
            message_encoding=spec.message_encoding,
            schema=foxglove.Schema(
                name=spec.schema_name, encoding=spec.schema_encoding, data=spec.schema_data
            ),
            context=self._context,
        )
        self._channels[spec.topic] = channel
        return channel

    def _close_channels(self) -> None:
        for channel in self._channels.values():
            channel.close()
        self._channels.clear()

    def __enter__(self) -> LiveServer:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()


@dataclass
class LiveTapStats:
    """What a :class:`LiveTap` took off the bus and what became of it."""

    received: int = 0  # bus messages taken off the socket (heartbeats not counted)
    served: int = 0  # of those, converted and handed to the server
    dropped: int = 0  # of those, dropped unserved: the tap fell more than max_pending behind
    error: str | None = None  # why the tap stopped early, if it did

    def as_dict(self) -> dict[str, Any]:
        return {"received": self.received, "served": self.served, "dropped": self.dropped,
                "error": self.error}


class LiveTap:
    """Serve what the publishers on ``endpoints`` send live to Foxglove, beside a service.

    A context manager: ``with LiveTap(publisher.endpoint, args.foxglove, bus=bus):``. Entering
    it starts the server, prints its ``ws://`` address on stderr and subscribes; leaving it
    stops both. It never raises once constructed: a failure (the port is taken, the
    subscription cannot be set up, a message cannot be served) is logged once as an error,
    kept in ``stats.error``, and the tap stops while the service carries on.

    Parameters
    ----------
    endpoints : str or iterable of str
        Publisher endpoints to serve, every topic.
    address : (host, port), optional
        Where to serve (``args.foxglove`` of :func:`add_foxglove_argument`); None: the option
        was not given, and the tap does nothing.
    bus : BusSettings, optional
        Size limit and CURVE keys of the subscription (:meth:`Subscriber.from_settings`);
        None: a plain loopback subscriber.
    name : str
        Server name shown by Foxglove.
    fingers : iterable of str, optional
        The rig's fingers, whose image channels are advertised at once (:class:`LiveServer`).
    max_pending : int
        Messages received but not yet served beyond which the oldest are dropped.
    **subscriber_options
        Passed on to :class:`~teleop.bus.pubsub.Subscriber` (``context``, ...).
    """

    def __init__(
        self,
        endpoints: str | Iterable[str],
        address: tuple[str, int] | None,
        *,
        bus: BusSettings | None = None,
        name: str = "compliance-teleop",
        fingers: Iterable[str] | None = None,
        max_pending: int = 1000,
        **subscriber_options: Any,
    ):
        self.endpoints = [endpoints] if isinstance(endpoints, str) else list(endpoints)
        self.address = address
        self.bus = bus
        self.name = name
        self.fingers = None if fingers is None else list(fingers)
        self.max_pending = max(1, max_pending)
        self.subscriber_options = subscriber_options
        self.stats = LiveTapStats()
        self.server: LiveServer | None = None
        self._pending: deque[tuple[Message, int]] = deque()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    @property
    def running(self) -> bool:
        """Whether the tap is serving (started, not stopped, not failed)."""
        return self._thread is not None and self._thread.is_alive()

    def start(self) -> LiveTap:
        """Start serving (nothing when ``address`` is None or already started)."""
        if self.address is None or self.server is not None or self.stats.error:
            return self
        try:
            self.server = LiveServer(*self.address, name=self.name, fingers=self.fingers)
            subscriber = self._subscribe()
        except Exception as exc:  # noqa: BLE001 - the service must carry on whatever happened
            self._fail(exc)
            return self
        print(f"Foxglove live view: {self.server.url} ({', '.join(self.endpoints)})",
              file=sys.stderr, flush=True)
        self._thread = threading.Thread(
            target=self._run, args=(subscriber,), name="foxglove-live-tap", daemon=True
        )
        self._thread.start()
        return self

    def close(self, timeout_s: float = 2.0) -> LiveTapStats:
        """Stop serving and unsubscribe; calling twice is fine."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout_s)
            self._thread = None
        if self.server is not None:
            self.server.close()
            self.server = None
        if self.stats.dropped:
            log.warning("Foxglove live view: dropped %d of %d messages (it fell more than %d behind)",
                        self.stats.dropped, self.stats.received, self.max_pending)
        return self.stats

    def __enter__(self) -> LiveTap:
        return self.start()

    def __exit__(self, *exc: Any) -> None:
        self.close()

    # ------------------------------------------------------------------ the thread

    def _subscribe(self) -> Subscriber:
        if self.bus is not None:
            return Subscriber.from_settings(self.bus, self.endpoints, ("",), conflate=False,
                                            **self.subscriber_options)
        return Subscriber(self.endpoints, ("",), conflate=False, **self.subscriber_options)

    def _run(self, subscriber: Subscriber) -> None:
        try:
            with subscriber:  # closed on the way out: a closed peer is one no publisher waits for
                while not self._stop.is_set():
                    self._take(subscriber, timeout_s=0 if self._pending else 0.1)
                    if self._pending:
                        message, received_ns = self._pending.popleft()
                        self.server.log_message(message, received_ns)
                        self.stats.served += 1
        except Exception as exc:  # noqa: BLE001 - the service must carry on whatever happened
            self._fail(exc)

    def _take(self, subscriber: Subscriber, timeout_s: float) -> None:
        """Take everything queued on the socket (waiting up to ``timeout_s`` for the first)."""
        message = subscriber.recv(timeout_s=timeout_s)
        while message is not None:
            self.stats.received += 1
            if len(self._pending) >= self.max_pending:
                self._pending.popleft()
                self.stats.dropped += 1
            self._pending.append((message, now_ns()))
            message = subscriber.recv(timeout_s=0)

    def _fail(self, exc: Exception) -> None:
        self.stats.error = f"{type(exc).__name__}: {exc}" if not isinstance(exc, BusError) else str(exc)
        log.error("Foxglove live view of %s stopped: %s; the service carries on without it",
                  ", ".join(self.endpoints), self.stats.error)
        self._pending.clear()
