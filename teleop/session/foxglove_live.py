"""Live view: the bus served over Foxglove's WebSocket protocol, as the session log shows it.

:class:`LiveServer` starts a ``foxglove-sdk`` WebSocket server (subprotocol
``foxglove.sdk.v1``) in its own SDK context and logs the Foxglove forms of each bus message
(:mod:`teleop.session.foxglove`, the same conversion the log uses, so the shipped layout
works on both) on channels created as topics first appear. Message times are the receive
times the log uses (this host's ``time.monotonic_ns()``). ``teleop record --foxglove``
serves what it records; ``teleop demo --foxglove`` passes the option to its recorder.
Clients that fall behind lose the oldest messages (the SDK's per-client backlog), never
the recording.
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from typing import Any

import foxglove

from teleop.errors import BusError
from teleop.session.foxglove import FoxgloveMessage

__all__ = [
    "DEFAULT_ADDRESS",
    "LiveServer",
    "add_foxglove_argument",
    "parse_address",
]

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
        "'Open connection' > 'Foxglove WebSocket' and ws://HOST:PORT, and import "
        "configs/foxglove/layout.json",
    )


class LiveServer:
    """A Foxglove WebSocket server for the Foxglove forms of bus messages.

    Parameters
    ----------
    host, port : str, int
        Where to listen (port 0: a free one, see :attr:`url`).
    name : str
        Server name shown by Foxglove.

    Raises
    ------
    BusError
        The server cannot start (the port is taken, the host is not this machine's).
    """

    def __init__(
        self, host: str = DEFAULT_HOST, port: int = DEFAULT_PORT, *, name: str = "compliance-teleop"
    ):
        self._context = foxglove.Context()
        try:
            self._server = foxglove.start_server(
                name=name, host=host, port=port, context=self._context
            )
        except Exception as exc:  # the SDK reports bind failures as plain RuntimeErrors
            raise BusError(f"cannot serve the Foxglove live view on {host}:{port}: {exc}") from exc
        self.host = host
        self._channels: dict[str, foxglove.Channel] = {}

    @property
    def port(self) -> int:
        return self._server.port

    @property
    def url(self) -> str:
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"ws://{host}:{self.port}"

    def log(self, converted: Sequence[FoxgloveMessage], received_ns: int) -> None:
        """Send Foxglove messages of one bus message received at ``received_ns``.

        Has the signature of :class:`~teleop.session.recorder.SessionRecorder`'s
        ``on_foxglove`` hook.
        """
        for item in converted:
            channel = self._channels.get(item.topic)
            if channel is None:
                channel = foxglove.Channel(
                    item.topic,
                    message_encoding=item.message_encoding,
                    schema=foxglove.Schema(
                        name=item.schema_name, encoding=item.schema_encoding, data=item.schema_data
                    ),
                    context=self._context,
                )
                self._channels[item.topic] = channel
            channel.log(item.data, log_time=received_ns - item.age_ns)

    def close(self) -> None:
        """Stop serving; calling twice is fine."""
        for channel in self._channels.values():
            channel.close()
        self._channels.clear()
        self._server.stop()

    def __enter__(self) -> LiveServer:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()
