"""Reading on past damage in a session log without its summary: record heads, names, and
where the next intact chunk starts; and the check of a log's format version
(:mod:`teleop.session.logfile` uses these)."""

from __future__ import annotations

import struct
from pathlib import Path
from typing import Any

from mcap.opcode import Opcode

from teleop.errors import SessionLogError

_RECORD_START = struct.Struct("<BQ")  # an MCAP record's opcode and length
_CHUNK_START = struct.Struct("<BQQQQII")  # opcode, length, times, sizes, CRC, compression length
OPCODES = frozenset(o.value for o in Opcode)
UNKNOWN_NS = 2**64 - 1  # a lost part's end time while no message after it has been read
_SCAN_BLOCK = 1 << 20


def check_format(path: Path, metadata: dict[str, str], newest: int) -> None:
    """Refuse a log written in a newer format than this reader knows (:class:`SessionLogError`)."""
    text = metadata.get("log_format")
    if text is None:
        return
    try:
        version = int(text)
    except ValueError:
        version = None
    if version is None or not 1 <= version <= newest:
        raise SessionLogError(
            f"{path}: session metadata log_format = {text!r}: expected an integer from 1 to "
            f"{newest} (a newer format needs a newer compliance-teleop)"
        )


def record_head(file: Any, start: int) -> tuple[int, int] | None:
    """The opcode and length of the record at byte ``start`` (None: the file ends first)."""
    file.seek(start)
    data = file.read(_RECORD_START.size)
    return _RECORD_START.unpack(data) if len(data) == _RECORD_START.size else None


def record_name(file: Any, start: int, opcode: int) -> str:
    """`` 'name'`` of the attachment or metadata record at ``start`` if it reads, else ``""``."""
    skip = {Opcode.ATTACHMENT: 16, Opcode.METADATA: 0}.get(opcode)
    if skip is None:
        return ""
    file.seek(start + _RECORD_START.size + skip)
    data = file.read(4)
    length = struct.unpack("<I", data)[0] if len(data) == 4 else 1 << 20
    name = file.read(length).decode("utf-8", "replace") if length <= 256 else ""
    return f" {name!r}" if name else ""


def next_chunk(file: Any, start: int, size: int) -> int | None:
    """The first byte at or after ``start`` where a well-formed chunk record starts (None: none).

    One pass over the rest of the file in blocks; a candidate's lengths must add up exactly
    (its checksum is checked when it is read).
    """
    pos = start
    while pos < size:
        file.seek(pos)
        block = file.read(_SCAN_BLOCK + 64)
        at = block.find(b"\x06")
        while 0 <= at < min(len(block), _SCAN_BLOCK):
            if len(block) - at >= _CHUNK_START.size:
                _, length, first, last, _, _, clen = _CHUNK_START.unpack_from(block, at)
                end = pos + at + 9 + length
                inner = 8 * 3 + 4 + 4 + clen + 8
                if end <= size and first <= last and clen <= 8 and length >= inner:
                    name = block[at + _CHUNK_START.size : at + _CHUNK_START.size + clen]
                    rest = block[at + _CHUNK_START.size + clen : at + _CHUNK_START.size + clen + 8]
                    if (
                        name in (b"", b"zstd", b"lz4")
                        and len(rest) == 8
                        and (struct.unpack("<Q", rest)[0] == length - inner)
                    ):
                        return pos + at
            at = block.find(b"\x06", at + 1)
        pos += _SCAN_BLOCK
    return None
