"""HX711 line protocols, shared by the host backends and the bridge (standard library only), and
:func:`import_pyserial`, the library of both sides' serial links.

The HX711 is a 24-bit ADC (10 or 80 samples/s) whose readings are raw signed counts.
A reading that is not valid raises :class:`Unreadable` with a ``reason``: ``garbage``
(not a reading), ``version`` (framed protocol of another version), ``out_of_range``
(outside the ADC's range, or at a rail: -2**23 and 2**23 - 1 are what a saturated
HX711 reports); :class:`LineSplitter` drops ``overlong`` lines.

Serial line protocol
--------------------
An Arduino-style bridge prints one reading per line: ASCII, optional sign, decimal
digits, then ``\\n`` (``\\r\\n`` is fine), e.g. ``b"-123456\\r\\n"``. Nothing else is
expected on the line. The text before the first newline after opening the port is
dropped (the port may open mid-line).

Framed TCP protocol (version 1)
-------------------------------
Replaces the published rig's bare, undelimited ASCII numbers. The bridge
(:mod:`teleop.devices.hx711_bridge`, e.g. on a Raspberry Pi) listens; the host connects.
From then on the bridge sends one frame per reading, and nothing else:

* a frame is one UTF-8 JSON object followed by ``\\n`` (0x0A), at most
  :data:`MAX_LINE_BYTES` bytes with the newline; no newline inside the object;
* the object has exactly these keys:

  ``v``           int, protocol version, 1
  ``seq``         int >= 0, +1 per reading since the bridge started; a jump means lost
                  readings
  ``t_bridge_s``  float, when the reading was taken, seconds on the bridge's monotonic
                  clock (the instant of sampling, not of sending)
  ``counts``      int, the raw HX711 reading, -2**23 < counts < 2**23 - 1

  e.g. ``{"v":1,"seq":42,"t_bridge_s":1831.204117,"counts":-51234}\\n``.
"""

from __future__ import annotations

import json
import math
import re
from types import ModuleType

from teleop.errors import BackendNotFoundError

__all__ = [
    "COUNTS_MAX",
    "COUNTS_MIN",
    "MAX_LINE_BYTES",
    "PROTOCOL_VERSION",
    "LineSplitter",
    "Unreadable",
    "format_frame",
    "import_pyserial",
    "parse_frame",
    "parse_serial_line",
]

PROTOCOL_VERSION = 1
MAX_LINE_BYTES = 256
COUNTS_MIN = -(2**23)  # the rails: a saturated HX711 reads exactly these
COUNTS_MAX = 2**23 - 1
_COUNTS_LINE = re.compile(rb"[+-]?[0-9]{1,9}")
_FRAME_KEYS = frozenset({"v", "seq", "t_bridge_s", "counts"})


class Unreadable(ValueError):
    """One line that is not a reading; ``reason`` is the counter it goes to."""

    def __init__(self, reason: str, detail: str):
        super().__init__(detail)
        self.reason = reason


def _check_counts(counts: int) -> int:
    if not COUNTS_MIN < counts < COUNTS_MAX:
        raise Unreadable("out_of_range", f"counts {counts} outside the HX711's range or at a rail")
    return counts


def parse_serial_line(line: bytes) -> int:
    """Counts from one serial line (newline removed); raises Unreadable."""
    text = line.strip()
    if not _COUNTS_LINE.fullmatch(text):
        raise Unreadable("garbage", f"not a reading: {line[:40]!r}")
    return _check_counts(int(text))


def format_frame(seq: int, t_bridge_s: float, counts: int) -> bytes:
    """One framed TCP reading (see the module docstring)."""
    return json.dumps(
        {"v": PROTOCOL_VERSION, "seq": seq, "t_bridge_s": t_bridge_s, "counts": counts}, separators=(",", ":")
    ).encode("utf-8") + b"\n"


def parse_frame(line: bytes) -> tuple[int, float, int]:
    """``(seq, t_bridge_s, counts)`` from one framed TCP line (newline removed); raises Unreadable."""
    try:
        frame = json.loads(line)
    except (ValueError, UnicodeDecodeError) as exc:
        raise Unreadable("garbage", f"not JSON: {line[:40]!r}") from exc
    if not isinstance(frame, dict) or set(frame) != _FRAME_KEYS:
        raise Unreadable("garbage", f"not a reading frame: {line[:60]!r}")
    if type(frame["v"]) is not int or frame["v"] != PROTOCOL_VERSION:
        raise Unreadable("version", f"protocol version {frame['v']!r}, expected {PROTOCOL_VERSION}")
    seq, t, counts = frame["seq"], frame["t_bridge_s"], frame["counts"]
    if type(seq) is not int or seq < 0 or type(counts) is not int:
        raise Unreadable("garbage", f"seq and counts must be integers: {line[:60]!r}")
    if type(t) not in (int, float) or not math.isfinite(t):
        raise Unreadable("garbage", f"t_bridge_s must be a finite number: {line[:60]!r}")
    return seq, float(t), _check_counts(counts)


class LineSplitter:
    """Cuts a byte stream into lines; drops lines longer than ``max_bytes``.

    ``skip_first``: drop everything before the first newline (a port opened mid-line).
    """

    def __init__(self, *, max_bytes: int = MAX_LINE_BYTES, skip_first: bool = False):
        self.max_bytes = max_bytes
        self.overlong = 0
        self._pending = b""
        self._skipping = skip_first

    def feed(self, data: bytes) -> list[bytes]:
        """Complete lines in ``data`` (after what came before), without their newlines."""
        *lines, rest = (self._pending + data).split(b"\n")
        if self._skipping and lines:
            lines = lines[1:]
            self._skipping = False
        if len(rest) > self.max_bytes:  # a line that never ends: drop it now, not at the newline
            self.overlong += 1
            rest, self._skipping = b"", True
        self._pending = rest
        kept = [line for line in lines if len(line) < self.max_bytes]
        self.overlong += len(lines) - len(kept)
        return kept


def import_pyserial(user: str) -> ModuleType:
    """pyserial (the ``robot`` extra), which ``user`` needs; BackendNotFoundError saying what to install when
    it is missing, so commands and ``teleop doctor`` report it rather than fail with a traceback."""
    try:
        import serial
    except ImportError as exc:
        raise BackendNotFoundError.missing_library(user, exc) from exc
    return serial
