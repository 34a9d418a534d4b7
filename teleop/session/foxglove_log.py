"""Writing one session log's messages: each bus message verbatim, after its Foxglove forms.

The layout (and why a JPEG's bytes are stored once, in its ``foxglove.CompressedImage``)
is documented in :mod:`teleop.session.logfile`; the conversion is
:mod:`teleop.session.foxglove`'s. :class:`LogChannels` registers schemas and channels on
first use and writes; :func:`rig_metadata` is the rig summary for Foxglove's metadata panel.

A log holds at most :data:`MAX_CHANNELS` channels (bus and Foxglove topics together): the wire
takes any topic ``frame/<finger>``, and a sender making up fingers would otherwise grow the
log's (and its writer's) channels without bound. A real session has a few dozen; a message
that would need a channel past the cap is not written (:meth:`LogChannels.admits`), unless its
topic is one of the ``reserved`` (each type's own and the settings' fingers' frames), which
made-up topics therefore never crowd out.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from typing import Any

from mcap.writer import Writer

from teleop.bus.wire import Message
from teleop.session.foxglove import IMAGE_SCHEMA, FoxgloveMessage, foxglove_messages, in_topic_order
from teleop.session.logfile import MESSAGE_ENCODING, SCHEMA_ENCODING, schema_data
from teleop.session.logframes import pack_frames
from teleop.settings import Settings

__all__ = ["MAX_CHANNELS", "LogChannels", "rig_metadata"]

# Most channels one log holds: a session has one per bus topic (a frame topic per finger, force,
# width, estimate, ...) plus its Foxglove forms', a few dozen in all.
MAX_CHANNELS = 256

_SENSOR_METADATA = (
    "model",
    "serial",
    "gel_modulus_pa",
    "gel_poisson",
    "gel_thickness_m",
    "pixel_pitch_m",
    "markers",
    "camera_hz",
)


def rig_metadata(settings: Settings) -> dict[str, str]:
    """Each finger's gel and camera geometry and the gripper's stiffness, as MCAP metadata.

    Keys ``<finger>.<setting>`` (SI units, as in the settings), values strings (MCAP
    metadata holds only strings; flags as ``true``/``false``).
    """
    out = {}
    for sensor in settings.sensors:
        for name in _SENSOR_METADATA:
            value = getattr(sensor, name)
            text = str(value).lower() if isinstance(value, bool) else str(value)
            out[f"{sensor.finger}.{name}"] = text
    out["gripper.finger_stiffness_n_per_m"] = str(settings.gripper.finger_stiffness_n_per_m)
    return out


class LogChannels:
    """The schemas and channels of one log's MCAP writer, and the writing of each message.

    Parameters
    ----------
    writer : mcap.writer.Writer
        Started writer of the log.
    offset_ns : int
        Added to this host's ``time.monotonic_ns()`` times (receive, send, capture) to give
        the log's times, nanoseconds since the Unix epoch (:mod:`teleop.session.logfile`).
    max_channels : int
        Most channels registered (module notes); :meth:`admits` says whether a message fits.
    reserved : iterable of str
        Bus topics admitted past the cap (with their Foxglove forms' channels).
    """

    def __init__(
        self, writer: Writer, offset_ns: int = 0, max_channels: int = MAX_CHANNELS, reserved: Iterable[str] = ()
    ):
        self.writer = writer
        self.offset_ns = offset_ns
        self.max_channels = max_channels
        self.reserved = frozenset(reserved)
        self._schemas: dict[tuple[str, str], int] = {}  # (name, encoding) -> id
        self._channels: dict[str, int] = {}  # topic -> id
        self._last_ns: dict[str, int] = {}  # Foxglove topic -> its latest log time

    def convert(self, message: Message) -> list[FoxgloveMessage]:
        """The Foxglove forms of ``message``, on this log's clock."""
        return foxglove_messages(message, self.offset_ns)

    def admits(self, message: Message, converted: Sequence[FoxgloveMessage]) -> bool:
        """Whether the channels ``message`` and its Foxglove forms need fit under the cap (or its
        topic is reserved)."""
        if message.topic in self.reserved:
            return True
        new = {message.topic, *(item.topic for item in converted)} - self._channels.keys()
        return len(self._channels) + len(new) <= self.max_channels

    def write_foxglove(
        self, message: Message, received_ns: int, converted: Sequence[FoxgloveMessage] | None = None
    ) -> list[FoxgloveMessage]:
        """Write the Foxglove forms of ``message`` (call first; ``converted`` when already made
        by :meth:`convert`); returns them."""
        converted = self.convert(message) if converted is None else list(converted)
        log_time_ns = received_ns + self.offset_ns
        for item in converted:
            channel = self._channels.get(item.topic)
            if channel is None:
                schema = self._schema(item.schema_name, item.schema_encoding, item.schema_data)
                channel = self._channel(item.topic, item.message_encoding, schema, {})
            at = in_topic_order(self._last_ns, item.topic, log_time_ns - item.age_ns)
            self._add(channel, item.data, message, at)
        return converted

    def write_bus(
        self, message: Message, frames: Sequence[Any], received_ns: int, *, elide_image: bool
    ) -> int:
        """Write ``message``'s frames verbatim (the image bytes left out when ``elide_image``:
        the CompressedImage just written holds them); returns the bytes of message data."""
        channel = self.bus_channel(message)
        data = pack_frames(frames, elide_last=elide_image)
        self._add(channel, data, message, received_ns + self.offset_ns)
        return len(data)

    def bus_channel(self, message: Message) -> int:
        """The channel of ``message``'s topic, registered (with its schema) on first use: a
        registration may write the open chunk when it fills it (mcap)."""
        channel = self._channels.get(message.topic)
        if channel is None:
            name = f"compliance-teleop/{message.type}"
            schema = self._schema(name, SCHEMA_ENCODING, schema_data(message.type))
            channel = self._channel(message.topic, MESSAGE_ENCODING, schema, {"type": message.type})
        return channel

    @staticmethod
    def carries_image(converted: Sequence[FoxgloveMessage]) -> bool:
        """Whether the Foxglove forms hold the bus message's image bytes (a frame's only buffer)."""
        return any(item.schema_name == IMAGE_SCHEMA for item in converted)

    def _add(self, channel: int, data: bytes, message: Message, log_time_ns: int) -> None:
        self.writer.add_message(
            channel,
            log_time=log_time_ns,
            data=data,
            publish_time=message.t_send_ns + self.offset_ns,
            sequence=message.seq % 2**32,
        )

    def _schema(self, name: str, encoding: str, data: bytes) -> int:
        """The id of schema ``(name, encoding)``, registered with ``data`` on first use."""
        schema = self._schemas.get((name, encoding))
        if schema is None:
            schema = self.writer.register_schema(name, encoding, data)
            self._schemas[name, encoding] = schema
        return schema

    def _channel(self, topic: str, encoding: str, schema: int, metadata: dict[str, str]) -> int:
        channel = self.writer.register_channel(topic, encoding, schema, metadata)
        self._channels[topic] = channel
        return channel
