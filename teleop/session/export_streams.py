"""A grasp's messages gathered as the log is read, and turned into a record's streams
(:mod:`teleop.session.export`).

:class:`OpenGrasp` holds what a grasp has gathered so far: its ``frame`` messages by finger,
its ``force`` and ``width`` sample batches. :func:`frame_stream` makes one finger's frames a
:class:`~teleop.record.FrameStream` (``raw`` frames as lossless PNG; ``jpeg``/``png`` kept as
the camera produced them), and :func:`concatenated_samples` the batches one
:class:`~teleop.record.Samples`, in receive order. The first encoded frame is decoded (for the
stream's shape) only once its header declares a size no larger than any sensor's: a few bytes of a
corrupt or hostile log may declare an image of gigabytes.
"""

from __future__ import annotations

from collections import defaultdict
from dataclasses import dataclass, field

import numpy as np
from PIL import Image

from teleop.bus.wire import Message
from teleop.grasp_data import _declared_size
from teleop.record import FrameStream, Samples, decode_image

__all__ = ["OpenGrasp", "concatenated_samples", "frame_stream"]

# The largest raw frame side any sensor's settings allow (SensorSettings raw_width_px, raw_height_px).
_MAX_SIDE_PX = 4096


@dataclass
class OpenGrasp:
    """A grasp being gathered: what it holds so far (module notes)."""

    grasp_id: str
    start_s: float
    object_name: str | None
    source: str  # the publisher of its start: only its loading_end and end count
    frames: dict[str, list[tuple[float, str, np.ndarray]]] = field(
        default_factory=lambda: defaultdict(list)
    )
    force: list[tuple[np.ndarray, np.ndarray]] = field(default_factory=list)
    width: list[tuple[np.ndarray, np.ndarray]] = field(default_factory=list)
    loading_end_s: float | None = None
    start_log_ns: int | None = None  # log time of its start event
    dropped: dict[str, int] = field(default_factory=lambda: defaultdict(int))  # by topic

    def add(self, message: Message) -> None:
        """Keep a ``frame``, ``force`` or ``width`` message of the grasp."""
        body = message.fields
        if message.type == "frame":
            data = body.data if body.encoding == "raw" else body.data.tobytes()
            self.frames[body.finger].append((message.t_capture_s, body.encoding, data))
        elif message.type == "force":
            self.force.append((body.t_s, body.value_n))
        else:
            self.width.append((body.t_s, body.value_m))


def concatenated_samples(parts: list[tuple[np.ndarray, np.ndarray]]) -> Samples:
    """Sample batches ``(t_s, value)`` as one :class:`~teleop.record.Samples`, in order."""
    return Samples(np.concatenate([t for t, _ in parts]), np.concatenate([v for _, v in parts]))


def frame_stream(
    finger: str, frames: list[tuple[float, str, np.ndarray | bytes]]
) -> FrameStream | str:
    """The frames of one finger as a FrameStream, or the reason they cannot be one."""
    t_s = [t for t, _, _ in frames]
    encodings = {encoding for _, encoding, _ in frames}
    if len(encodings) > 1:
        return (
            f"finger {finger!r} sent frames in several encodings ({', '.join(sorted(encodings))})"
        )
    encoding = encodings.pop()
    if encoding == "raw":
        data = [d for _, _, d in frames]
        if any(d.dtype != np.uint8 for d in data):
            return (
                f"finger {finger!r} sent 16-bit raw frames; a grasp record holds 8-bit BGR frames"
            )
        return FrameStream.from_frames(finger, t_s, data, encoding="png")
    encoded = [d for _, _, d in frames]
    try:
        first = _first_frame(encoded[0])
    except ValueError as exc:
        return f"finger {finger!r}: the first {encoding} frame is refused: {exc}"
    if first is None:
        return f"finger {finger!r}: the first {encoding} frame does not decode"
    return FrameStream(
        finger=finger,
        t_s=np.asarray(t_s),
        encoded=tuple(encoded),
        encoding=encoding,
        shape=tuple(first.shape),
    )


def _first_frame(data: np.ndarray | bytes) -> np.ndarray | None:
    """``data`` decoded (None when it does not decode) once its header declares at most the largest
    frame a sensor allows; ValueError saying why otherwise."""
    buffer = np.frombuffer(data, dtype=np.uint8) if isinstance(data, bytes | bytearray) else np.asarray(data)
    try:
        declared = _declared_size(buffer)
    except Image.DecompressionBombError as exc:  # Pillow's own limit, far above any frame's size
        raise ValueError(f"{exc}; refused before decoding") from exc
    if declared is None:
        return None  # no JPEG or PNG header
    cols, rows = declared
    if max(rows, cols) > _MAX_SIDE_PX:
        raise ValueError(f"image declares {cols}x{rows} px, more than the largest frame a sensor allows "
                         f"({_MAX_SIDE_PX}x{_MAX_SIDE_PX} px): refused before decoding")
    return decode_image(buffer, shape=(rows, cols))
