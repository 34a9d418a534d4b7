"""Session logs written by hand: MCAP files of chosen bus messages, as the recorder stores them."""

from __future__ import annotations

from types import SimpleNamespace

from mcap.writer import Writer

from teleop.bus.wire import encode
from teleop.session.logfile import MESSAGE_ENCODING, PROFILE, SCHEMA_ENCODING, schema_data
from teleop.session.logframes import pack_frames


def register_bus_channel(writer: Writer, topic: str, message_type: str) -> int:
    """The id of a new channel for bus messages of ``message_type`` on ``topic``, with its schema."""
    schema = writer.register_schema(f"compliance-teleop/{message_type}", SCHEMA_ENCODING, schema_data(message_type))
    return writer.register_channel(topic, MESSAGE_ENCODING, schema, {"type": message_type})


def write_log(path, messages):
    """A complete session log of ``messages`` ((log time ns, bus message)), in that order."""
    with path.open("wb") as f:
        writer = Writer(f)
        writer.start(PROFILE, "test")
        channels = {}
        for log_time, message in messages:
            if message.topic not in channels:
                channels[message.topic] = register_bus_channel(writer, message.topic, message.type)
            writer.add_message(channels[message.topic], log_time=log_time, data=pack_frames(encode(message)),
                               publish_time=log_time, sequence=message.seq % 2**32)
        writer.finish()
    return path


def logged(kind: str, t_s: float, **fields) -> SimpleNamespace:
    """One logged bus message as :class:`~teleop.session.logfile.LogReader` yields it: its type, capture
    time and fields (``grasp_id`` "g" unless given)."""
    fields.setdefault("grasp_id", "g")
    return SimpleNamespace(message=SimpleNamespace(type=kind, t_capture_s=t_s, fields=SimpleNamespace(**fields)))


class ListedLog:
    """A session log reader over ``entries`` (from :func:`logged`), in their order."""

    def __init__(self, entries):
        self.entries = entries

    def messages(self, types):
        return [entry for entry in self.entries if entry.message.type in types]
