"""The ``framing`` text a log carries is enough to read its bus messages: a reader written from
that text alone (no project code) gets back every frame as sent, JPEG frames' elided bytes included."""

from __future__ import annotations

import json
import re
import struct

from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage
from mcap.reader import make_reader

from teleop.bus.wire import encode
from teleop.session.logframes import ELIDED, FRAMING


def _read_as_documented(framing: str, record, before) -> tuple[list[bytes], bool]:
    """The frames of the stored bus message ``record`` (``before``: the (schema, record) stored
    just before it), following ``framing``'s stated rule; and whether its last frame was elided."""
    count_mask, flag = (int(h, 16) for h in re.findall(r"0x[0-9a-f]+", framing))
    data = record.data
    (word,) = struct.unpack_from("<I", data)
    n, elided = word & count_mask, bool(word & flag)
    lengths = struct.unpack_from(f"<{n}I", data, 4)
    frames, at = [], 4 * (n + 1)
    for length in lengths[:-1] if elided else lengths:
        frames.append(data[at : at + length])
        at += length
    assert at == len(data)
    if elided:
        schema, image = before
        assert schema.name == "foxglove.CompressedImage"
        assert (image.log_time, image.sequence) == (record.log_time, record.sequence)
        frames.append(CompressedImage.FromString(image.data).data)
        assert len(frames[-1]) == lengths[-1]
    return frames, elided


def test_framing_names_the_flag_and_where_elided_bytes_are():
    assert f"w & {ELIDED - 1:#x} is the frame count" in FRAMING
    assert f"w & {ELIDED:#x} (bit 16" in FRAMING
    assert "foxglove.CompressedImage message stored immediately before" in FRAMING
    assert "same log_time and sequence" in FRAMING


def test_a_reader_following_the_logs_framing_text_decodes_every_bus_message(recorded):
    with recorded.path.open("rb") as f:
        metadata = [m.metadata for m in make_reader(f).iter_metadata()]
        f.seek(0)
        everything = list(make_reader(f).iter_messages(log_time_order=False))  # file order
    framings = {m["framing"] for m in metadata if "framing" in m}
    bus, elided, before = [], 0, None
    for schema, channel, record in everything:
        if schema.name.startswith("compliance-teleop/"):
            framing = json.loads(schema.data)["framing"]
            framings.add(framing)
            frames, was_elided = _read_as_documented(framing, record, before)
            bus.append((channel.topic, frames))
            elided += was_elided
        before = (schema, record)
    assert framings == {FRAMING}  # the schemas and the session metadata state the same rule
    assert elided > 0  # the session has JPEG frames: the flag was exercised
    for (topic, frames), sent in zip(bus, recorded.sent, strict=True):
        assert topic == sent.topic
        assert frames == [bytes(memoryview(f).cast("B")) for f in encode(sent)]
