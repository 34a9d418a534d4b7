"""The grip report of protocol version 2: the operator's grip on the display's own handle.

The wire format belongs to :mod:`haptics.protocol` (the layout :data:`GRIP_LAYOUT`, the
CRC, the report descriptor and the versions are defined there, and ``PROTOCOL.md``
documents them byte by byte); this module holds only the grip report's message class and
its codec, to keep that module small. ``from haptics.protocol import GripReport`` works too.

A version-2 display sends one grip report (INPUT ``0x04``, 9 bytes) whenever its grip or
buttons change and at its own report rate while the handle moves: the position (0 open to 1
fully squeezed, in 1/10000 of the travel), the force the operator squeezes with where the
device has a force sensor, the dead-man enable, the buttons and a sequence number.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from haptics.errors import ProtocolError
from haptics.protocol import (
    GRIP_BUTTON_BITS,
    GRIP_FLAG_NO_FORCE,
    GRIP_FORCE_COUNTS_PER_N,
    GRIP_LAYOUT,
    GRIP_POSITION_FULL_SCALE,
    _check_bool,
    _check_uint,
    _pack,
    _reserved_bits,
    _unpack,
)

__all__ = ["GRIP_BUTTONS", "GripReport", "decode_grip_report", "encode_grip_report"]

#: The buttons a grip report carries besides enable; a subset of ``teleop.operator.BUTTONS``.
GRIP_BUTTONS = tuple(name for name in GRIP_BUTTON_BITS if name != "enable")
#: Largest force the report can carry, in newtons.
MAX_FORCE_N = 0xFFFF / GRIP_FORCE_COUNTS_PER_N

_WHERE = f"input report 0x{GRIP_LAYOUT.report_id:02X} ({GRIP_LAYOUT.name})"


def _check_number(name: str, value: object, high: float) -> None:
    if (isinstance(value, bool) or not isinstance(value, int | float)
            or not math.isfinite(value) or not 0 <= value <= high):
        raise ProtocolError(f"GripReport.{name} = {value!r}: expected a number in [0, {high:g}]")


@dataclass(frozen=True)
class GripReport:
    """A grip report: what the operator does with the display's handle.

    Parameters
    ----------
    grip : float
        Handle position, 0 (open) to 1 (fully squeezed); sent in 1/10000 of the travel.
    force_n : float or None
        The operator's grip force in N (0 to 655.35, sent in 0.01 N), None when the
        device has no force sensor.
    enable : bool
        The dead-man is held: the operator's commands count only while it is.
    buttons : frozenset of str
        Buttons held now or pressed since the previous report, from :data:`GRIP_BUTTONS`
        (``grasp``, ``release``, ``stop``, ``next``); any iterable of names is accepted.
    sequence : int
        The device's grip report counter, 0 to 255 (wraps).
    """

    grip: float
    force_n: float | None
    enable: bool
    buttons: frozenset[str]
    sequence: int

    def __post_init__(self) -> None:
        _check_number("grip", self.grip, 1.0)
        if self.force_n is not None:
            _check_number("force_n", self.force_n, MAX_FORCE_N)
        _check_bool("GripReport", "enable", self.enable)
        if isinstance(self.buttons, str):
            raise ProtocolError(
                f"GripReport.buttons = {self.buttons!r}: expected a set of names, not a string"
            )
        buttons = frozenset(self.buttons)
        unknown = buttons - set(GRIP_BUTTONS)
        if unknown:
            raise ProtocolError(
                f"GripReport.buttons names {sorted(unknown, key=str)}: expected names from "
                f"{', '.join(GRIP_BUTTONS)}"
            )
        object.__setattr__(self, "buttons", buttons)
        _check_uint("GripReport", "sequence", self.sequence, 8)

    @property
    def position_counts(self) -> int:
        """The ``position`` field: the grip in 1/10000 of the travel."""
        return round(self.grip * GRIP_POSITION_FULL_SCALE)

    @property
    def force_counts(self) -> int:
        """The ``force`` field: the force in 0.01 N (0 without a force sensor)."""
        return 0 if self.force_n is None else round(self.force_n * GRIP_FORCE_COUNTS_PER_N)


def encode_grip_report(report: GripReport) -> bytes:
    """The 9-byte INPUT report (ID 0x04) carrying ``report`` (what version-2 firmware sends).

    The grip and the force are rounded to the nearest count (1/10000 of the travel, 0.01 N).
    """
    pressed = {"enable"} if report.enable else set()
    buttons = sum(1 << GRIP_BUTTON_BITS[name] for name in pressed | report.buttons)
    flags = GRIP_FLAG_NO_FORCE if report.force_n is None else 0
    return _pack(GRIP_LAYOUT, buttons, flags, report.position_counts, report.force_counts,
                 report.sequence)


def decode_grip_report(data: bytes) -> GripReport:
    """Decode a grip report; a malformed one raises ProtocolError naming the report and field."""
    buttons, flags, position, force, sequence = _unpack(GRIP_LAYOUT, data)
    _reserved_bits(_WHERE, "buttons", buttons, sum(1 << bit for bit in GRIP_BUTTON_BITS.values()))
    _reserved_bits(_WHERE, "flags", flags, GRIP_FLAG_NO_FORCE)
    if position > GRIP_POSITION_FULL_SCALE:
        raise ProtocolError(
            f"{_WHERE}: position = {position}, expected 0 to {GRIP_POSITION_FULL_SCALE}"
        )
    no_force = bool(flags & GRIP_FLAG_NO_FORCE)
    if no_force and force:
        raise ProtocolError(
            f"{_WHERE}: force = {force} with flags bit 0 (no force sensor) set, expected 0"
        )
    held = {name for name, bit in GRIP_BUTTON_BITS.items() if buttons >> bit & 1}
    return GripReport(
        grip=position / GRIP_POSITION_FULL_SCALE,
        force_n=None if no_force else force / GRIP_FORCE_COUNTS_PER_N,
        enable="enable" in held,
        buttons=frozenset(held - {"enable"}),
        sequence=sequence,
    )
