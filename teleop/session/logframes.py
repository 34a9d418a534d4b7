"""How bus messages are stored in the session log's ``Message`` records: the frame container.

One message's ZeroMQ frames ``[topic, header, body, *buffers]`` packed back to back behind
their count and lengths, the last frame's bytes optionally elided (stored in the image message
before it); :data:`FRAMING` states the layout, as written into each log.
"""

from __future__ import annotations

import struct
from collections.abc import Sequence
from typing import Any

from teleop.bus.wire import MAX_BUFFERS
from teleop.errors import MessageRejected

__all__ = ["ELIDED", "FRAMING", "MAX_FRAMES", "MIN_FRAMES", "elides", "pack_frames", "unpack_frames"]

_U32 = struct.Struct("<I")
MIN_FRAMES, MAX_FRAMES = 3, 3 + MAX_BUFFERS
ELIDED = 0x1_0000  # flag added to the frame count: the last frame's bytes are stored elsewhere

# Written into every log (schemas, session metadata): an outside reader's only guide.
FRAMING = (
    "uint32 LE word w, then n x uint32 LE frame length, then the frames "
    "[topic, header, body, *buffers] back to back, exactly as received from ZeroMQ; "
    f"n = w & {ELIDED - 1:#x} is the frame count ({MIN_FRAMES} to {MAX_FRAMES}) and w & {ELIDED:#x} "
    f"(bit 16, the only flag) marks the last frame as elided: its length is listed but its bytes "
    "are not stored here, they are the data field of the foxglove.CompressedImage message stored "
    "immediately before this one with the same log_time and sequence"
)


def pack_frames(frames: Sequence[Any], *, elide_last: bool = False) -> bytes:
    """One message's frames (bytes, memoryviews or ``zmq.Frame``) in the log's container.

    ``elide_last``: list the last frame's length but leave its bytes out (they are stored
    in the image message written just before, see :mod:`teleop.session.logfile`).
    """
    views = [memoryview(getattr(f, "buffer", f)).cast("B") for f in frames]
    count = len(views) + (ELIDED if elide_last else 0)
    lengths = struct.pack(f"<{len(views) + 1}I", count, *(v.nbytes for v in views))
    return b"".join([lengths, *(views[:-1] if elide_last else views)])


def elides(data: bytes | memoryview) -> bool:
    """Whether the container ``data`` leaves its last frame's bytes out."""
    return len(data) >= _U32.size and bool(_U32.unpack_from(data)[0] & ELIDED)


def unpack_frames(
    data: bytes | memoryview, *, elided: bytes | memoryview | None = None
) -> list[memoryview]:
    """The frames in a container written by :func:`pack_frames`, as views over ``data``.

    ``elided``: the bytes of the last frame when the container leaves them out.

    Raises
    ------
    MessageRejected
        (reason ``corrupt`` or ``frame_count``) the container is not well formed, or it
        leaves the last frame out and ``elided`` is missing or of another length.
    """
    view = memoryview(data).cast("B")
    if view.nbytes < _U32.size:
        raise MessageRejected("corrupt", f"stored message has {view.nbytes} bytes, no frame count")
    (word,) = _U32.unpack_from(view)
    count, flags = word & (ELIDED - 1), word & ~(ELIDED - 1)
    if flags not in (0, ELIDED):
        raise MessageRejected("corrupt", f"stored message has unknown flags {flags:#x}")
    if not MIN_FRAMES <= count <= MAX_FRAMES:
        raise MessageRejected(
            "frame_count", f"stored message has {count} frames, expected 3 to {MAX_FRAMES}"
        )
    start = _U32.size * (count + 1)
    if view.nbytes < start:
        raise MessageRejected("corrupt", f"stored message ends inside its {count} frame lengths")
    lengths = struct.unpack_from(f"<{count}I", view, _U32.size)
    stored = lengths[:-1] if flags else lengths
    if start + sum(stored) != view.nbytes:
        raise MessageRejected(
            "corrupt",
            f"stored frame lengths add up to {start + sum(stored)} bytes, "
            f"the message has {view.nbytes}",
        )
    frames = []
    for length in stored:
        frames.append(view[start : start + length])
        start += length
    if flags:
        if elided is None:
            raise MessageRejected(
                "corrupt", "stored frame data is elided and its image message was not found"
            )
        image = memoryview(elided).cast("B")
        if image.nbytes != lengths[-1]:
            raise MessageRejected(
                "corrupt",
                f"elided frame has {lengths[-1]} bytes, its image message {image.nbytes}",
            )
        frames.append(image)
    return frames
