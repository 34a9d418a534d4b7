"""Vendor-defined USB HID protocol of the softness display, versions 1 and 2.

Softness displays have no standard HID usage, so the display speaks
vendor-defined reports (usage page 0xFF00) with numbered report IDs:

- OUTPUT ``0x01`` *set stiffness* (host to device, 8 bytes): flags, the
  stiffness level, the uncertainty and a sequence number.
- FEATURE ``0x02`` *device info / configuration* (both ways, 17 bytes):
  protocol and firmware versions, the level range, the watchdog and the
  physical stiffness range. Only ``watchdog_ms`` is writable.
- INPUT ``0x03`` *status* (device to host, 7 bytes): device state, the level
  rendered now, fault bits and the echo of the last accepted sequence number.
- INPUT ``0x04`` *grip* (device to host, 9 bytes, version 2 only): the
  operator's grip on the display's handle (position, force where the device
  measures it), its buttons and a sequence number.

Every report starts with its report ID and ends with a CRC-8 over all bytes
before it (polynomial 0x07, initial value 0x00, no reflection, no final XOR;
``crc8(b"123456789") == 0xF4``). Multi-byte integers are little-endian.
The byte-by-byte layout is in ``PROTOCOL.md`` beside this module; ``haptics
protocol`` prints the same tables, rendered from the layouts defined here.

Versions: the display states the version it speaks in its FEATURE report; the
host speaks :data:`PROTOCOL_VERSIONS` and talks to each display in that
display's version (the OUTPUT report carries it). Version 2 adds the grip
report and changes nothing else, so a version-1 display works as before.

This module owns the wire format: every layout, the report descriptor, the
CRC and the versions. The grip report's message class and codec live in
:mod:`haptics.protocol_grip` (built on :data:`GRIP_LAYOUT` and the helpers
here, to keep modules small); ``GripReport``, ``encode_grip_report`` and
``decode_grip_report`` can be imported from either module.

Encoders and decoders are pure functions on ``bytes``. Decoding a report that
is short, long, of another report ID, with a bad CRC, with reserved bits set
or with a value out of its range raises :class:`~haptics.errors.ProtocolError`
naming the report and the field.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass, field
from functools import cached_property
from numbers import Integral
from typing import NamedTuple

from haptics.errors import ProtocolError

__all__ = [
    "FAULT_BITS", "FEATURE_LAYOUT", "FLAG_BITS", "GRIP_BUTTON_BITS", "GRIP_FLAG_NO_FORCE",
    "GRIP_FORCE_COUNTS_PER_N", "GRIP_LAYOUT", "GRIP_LOST_AFTER_S",
    "GRIP_POSITION_FULL_SCALE", "INPUT_LAYOUT",
    "LAYOUTS", "OUTPUT_LAYOUT", "PROTOCOL_VERSION", "PROTOCOL_VERSIONS", "REPORT_DESCRIPTOR",
    "DESCRIPTOR_ITEMS", "DEVICE_STATES", "DISABLING_FAULTS", "UNCERTAINTY_COUNTS_PER_DECADE",
    "USAGE_PAGE", "DeviceStatus", "DisplayInfo", "Field", "OutputReport", "ReportLayout",
    "StiffnessCommand", "crc8", "decode_feature_report", "decode_input_report",
    "decode_output_report", "encode_feature_report", "encode_input_report", "encode_output_report",
    "descriptor_items", "layout_markdown", "report_descriptor",
]

#: The newest protocol version this host speaks.
PROTOCOL_VERSION = 2
#: Every version this host speaks; it talks to each display in the display's own version.
PROTOCOL_VERSIONS = (1, 2)
USAGE_PAGE = 0xFF00
COMMAND_SET_STIFFNESS = 0x1
#: Uncertainty byte resolution: 20 counts per decade of E, so 255 counts = 12.75 decades.
UNCERTAINTY_COUNTS_PER_DECADE = 20

#: Bit number of each flag in the OUTPUT report's flags byte; bits 5-7 are reserved.
FLAG_BITS = {"rigid": 0, "unknown": 1, "stale": 2, "fading": 3, "provisional": 4}
#: Bit number of each fault in the INPUT report's faults byte; bits 5-7 are reserved.
FAULT_BITS = {
    "over_temperature": 0,
    "over_current": 1,
    "position_error": 2,
    "undervoltage": 3,
    "bad_report": 4,
}
#: The faults (bits 0-3) that disable the actuator: the status then says state fault, level 0.
DISABLING_FAULTS = tuple(name for name, bit in FAULT_BITS.items() if bit <= 3)
#: INPUT report device states, by code.
DEVICE_STATES = ("free", "rendering", "fault", "watchdog")
#: Bit number of each button in the grip report's buttons byte (version 2); bits 5-7 reserved.
#: ``enable`` is the dead-man (held); the others are a subset of ``teleop.operator.BUTTONS``.
GRIP_BUTTON_BITS = {"enable": 0, "grasp": 1, "release": 2, "stop": 3, "next": 4}
#: Bit 0 of the grip report's flags byte: the device has no force sensor (force is 0).
GRIP_FLAG_NO_FORCE = 0x01
#: Grip position counts at full travel (fully squeezed): 1/10000 of the travel per count.
GRIP_POSITION_FULL_SCALE = 10_000
#: Grip force counts per newton: 0.01 N per count, so 0 to 655.35 N.
GRIP_FORCE_COUNTS_PER_N = 100
#: After this long (s) without a grip report the host takes the grip as lost and the dead-man as
#: released: five of the longest gaps (20 ms) a display leaves between its grip reports.
GRIP_LOST_AFTER_S = 0.1

_TYPES = {"u8": ("B", "uint8"), "u16": ("H", "uint16 LE"), "u32": ("I", "uint32 LE")}


def _is_version(value: object) -> bool:
    # An integer, not a float or bool that compares equal to one (1.0 in (1, 2) is True).
    return not isinstance(value, bool) and isinstance(value, Integral) and value in PROTOCOL_VERSIONS


# --------------------------------------------------------------------------- layouts


@dataclass(frozen=True)
class Field:
    """One field of a report: name, wire type (``u8``, ``u16``, ``u32``) and meaning with units."""

    name: str
    type: str
    meaning: str


@dataclass(frozen=True)
class ReportLayout:
    """The fields of one report in wire order; offsets follow from the types.

    ``version`` is the first protocol version with this report.
    """

    name: str
    kind: str  # "output", "feature" or "input", as seen from the host
    report_id: int
    fields: tuple[Field, ...] = field(repr=False)
    version: int = 1

    @cached_property
    def packer(self) -> struct.Struct:
        """The ``struct`` codec of the whole report."""
        return struct.Struct("<" + "".join(_TYPES[f.type][0] for f in self.fields))

    @property
    def size(self) -> int:
        """Length of the report on the wire in bytes, report ID and CRC included."""
        return self.packer.size

    def offsets(self) -> list[tuple[int, int, Field]]:
        """``(offset, size, field)`` for every field."""
        rows, offset = [], 0
        for f in self.fields:
            size = struct.calcsize("<" + _TYPES[f.type][0])
            rows.append((offset, size, f))
            offset += size
        return rows


_ID = "report ID"
_CRC = "CRC-8 (poly 0x07, init 0x00) of every byte before it"

OUTPUT_LAYOUT = ReportLayout("set stiffness", "output", 0x01, (
    Field("report_id", "u8", f"{_ID}: 0x01"),
    Field("version_command", "u8",
          "high nibble: protocol version, the display's own (1 or 2); "
          "low nibble: command (1 = set stiffness); 0x11 or 0x21"),
    Field("flags", "u8",
          "bit 0 rigid, bit 1 unknown, bit 2 stale, bit 3 fading, bit 4 provisional; "
          "bits 5-7 reserved, 0; rigid and unknown never both set"),
    Field("level", "u16",
          "stiffness level, 0 (free, softest) to level_max (stiffest); "
          "equal steps are equal ratios of E (logarithmic, perceptual)"),
    Field("uncertainty", "u8",
          "width of the estimate's interval inside the display's E range, "
          "1/20 decade per count (0 = exact; 255 = 12.75 decades or more)"),
    Field("sequence", "u8", "host counter, +1 per report, wraps from 255 to 0"),
    Field("crc", "u8", _CRC),
))

FEATURE_LAYOUT = ReportLayout("device info / configuration", "feature", 0x02, (
    Field("report_id", "u8", f"{_ID}: 0x02"),
    Field("protocol_version", "u8",
          "protocol version the firmware speaks: 1, or 2 (adds the grip report); read-only"),
    Field("firmware_major", "u8", "firmware version, major"),
    Field("firmware_minor", "u8", "firmware version, minor"),
    Field("level_max", "u16", "full-scale stiffness level, >= 1; read-only"),
    Field("watchdog_ms", "u16",
          "ms without an OUTPUT report after which the device goes free (state watchdog); "
          "0 = off; the only writable field"),
    Field("min_stiffness_n_per_m", "u32",
          "stiffness rendered at level 0, N/m (0 = not stated); read-only"),
    Field("max_stiffness_n_per_m", "u32",
          "stiffness rendered at level_max, N/m (0 = not stated); read-only"),
    Field("crc", "u8", _CRC),
))

INPUT_LAYOUT = ReportLayout("status", "input", 0x03, (
    Field("report_id", "u8", f"{_ID}: 0x03"),
    Field("state", "u8",
          "0 free, 1 rendering, 2 fault (actuator disabled), "
          "3 watchdog (went free: no OUTPUT report within watchdog_ms); other values invalid"),
    Field("level", "u16", "stiffness level being rendered now, 0 to level_max"),
    Field("faults", "u8",
          "bit 0 over-temperature, bit 1 over-current, bit 2 actuator position error, "
          "bit 3 supply undervoltage, bit 4 malformed report received since the last status; "
          "bits 5-7 reserved, 0"),
    Field("sequence", "u8", "sequence of the last accepted OUTPUT report (0 before any)"),
    Field("crc", "u8", _CRC),
))

GRIP_LAYOUT = ReportLayout("grip", "input", 0x04, (
    Field("report_id", "u8", f"{_ID}: 0x04"),
    Field("buttons", "u8",
          "bit 0 enable (dead-man held now); bit 1 grasp, bit 2 release, bit 3 stop, bit 4 next "
          "(held now or pressed since the previous grip report); bits 5-7 reserved, 0"),
    Field("flags", "u8",
          "bit 0 no force sensor (force is then 0); bits 1-7 reserved, 0"),
    Field("position", "u16",
          "grip position, 0 (open) to 10000 (fully squeezed), 1/10000 of the handle's travel "
          "per count; 10001-65535 invalid"),
    Field("force", "u16",
          "operator's grip force on the handle, 0.01 N per count (0 to 655.35 N); "
          "0 when flags bit 0 is set"),
    Field("sequence", "u8", "device counter, +1 per grip report, wraps from 255 to 0"),
    Field("crc", "u8", _CRC),
), version=2)

LAYOUTS = (OUTPUT_LAYOUT, FEATURE_LAYOUT, INPUT_LAYOUT, GRIP_LAYOUT)

_MAIN_ITEMS = {"output": (0x91, "Output"), "feature": (0xB1, "Feature"), "input": (0x81, "Input")}


def descriptor_items(version: int = PROTOCOL_VERSION) -> tuple[tuple[bytes, str], ...]:
    """The HID report descriptor of a ``version`` display, item by item: (bytes, meaning).

    Report counts exclude the report ID byte; report ``n`` of :data:`LAYOUTS` has usage
    ``n + 2``. Version 2 adds the grip report's four items before End Collection.
    """
    if not _is_version(version):
        raise ProtocolError(f"descriptor version = {version!r}: expected one of {PROTOCOL_VERSIONS}")
    items = [
        (bytes([0x06, 0x00, 0xFF]), "Usage Page (Vendor Defined 0xFF00)"),
        (bytes([0x09, 0x01]), "Usage (0x01: softness display)"),
        (bytes([0xA1, 0x01]), "Collection (Application)"),
        (bytes([0x15, 0x00]), "  Logical Minimum (0)"),
        (bytes([0x26, 0xFF, 0x00]), "  Logical Maximum (255)"),
        (bytes([0x75, 0x08]), "  Report Size (8 bits)"),
    ]
    for usage, layout in enumerate(LAYOUTS, start=2):
        if layout.version > version:
            continue
        main, main_name = _MAIN_ITEMS[layout.kind]
        items += [
            (bytes([0x85, layout.report_id]), f"  Report ID (0x{layout.report_id:02X})"),
            (bytes([0x09, usage]), f"  Usage (0x{usage:02X}: {layout.name})"),
            (bytes([0x95, layout.size - 1]), f"  Report Count ({layout.size - 1})"),
            (bytes([main, 0x02]), f"  {main_name} (Data, Variable, Absolute)"),
        ]
    items.append((bytes([0xC0]), "End Collection"))
    return tuple(items)


def report_descriptor(version: int = PROTOCOL_VERSION) -> bytes:
    """The HID report descriptor bytes of a ``version`` display."""
    return b"".join(item for item, _ in descriptor_items(version))


#: The report descriptor of a version-2 display, item by item (a version-1 one lacks report 0x04).
DESCRIPTOR_ITEMS = descriptor_items()
REPORT_DESCRIPTOR = report_descriptor()


def layout_markdown(layout: ReportLayout) -> str:
    """The byte-by-byte table of ``layout`` as GitHub markdown (as in PROTOCOL.md)."""
    lines = ["| Offset | Size | Type | Field | Meaning |", "|---|---|---|---|---|"]
    lines += [
        f"| {offset} | {size} | {_TYPES[f.type][1]} | `{f.name}` | {f.meaning} |"
        for offset, size, f in layout.offsets()
    ]
    return "\n".join(lines)


# --------------------------------------------------------------------------- CRC-8


def _crc8_table(polynomial: int) -> bytes:
    table = bytearray(256)
    for byte in range(256):
        crc = byte
        for _ in range(8):
            crc = ((crc << 1) ^ polynomial if crc & 0x80 else crc << 1) & 0xFF
        table[byte] = crc
    return bytes(table)


_CRC8_TABLE = _crc8_table(0x07)


def crc8(data: bytes) -> int:
    """CRC-8 (polynomial 0x07, init 0x00, no reflection, no final XOR) of ``data``."""
    crc = 0
    for byte in data:
        crc = _CRC8_TABLE[crc ^ byte]
    return crc


# --------------------------------------------------------------------------- messages


def _check_uint(owner: str, name: str, value: object, bits: int) -> None:
    if isinstance(value, bool) or not isinstance(value, Integral) or not 0 <= value < 1 << bits:
        raise ProtocolError(
            f"{owner}.{name} = {value!r}: expected an integer in [0, {(1 << bits) - 1}]"
        )


def _check_bool(owner: str, name: str, value: object) -> None:
    if not isinstance(value, bool):
        raise ProtocolError(f"{owner}.{name} = {value!r}: expected True or False")


@dataclass(frozen=True)
class StiffnessCommand:
    """What the display should render: the body of an OUTPUT report without its sequence.

    Parameters
    ----------
    level : int
        Stiffness level, 0 (free) to the display's ``level_max`` (at most 65535).
    uncertainty : int
        Interval width in counts of 1/20 decade of E, 0 to 255.
    rigid, unknown, stale, fading, provisional : bool
        The flags of the OUTPUT report; ``rigid`` and ``unknown`` exclude each other.
    """

    level: int
    uncertainty: int = 0
    rigid: bool = False
    unknown: bool = False
    stale: bool = False
    fading: bool = False
    provisional: bool = False

    def __post_init__(self) -> None:
        _check_uint("StiffnessCommand", "level", self.level, 16)
        _check_uint("StiffnessCommand", "uncertainty", self.uncertainty, 8)
        for name in FLAG_BITS:
            _check_bool("StiffnessCommand", name, getattr(self, name))
        if self.rigid and self.unknown:
            raise ProtocolError("StiffnessCommand flags: rigid and unknown are both set")

    @property
    def flags(self) -> int:
        """The flags byte."""
        return sum(1 << bit for name, bit in FLAG_BITS.items() if getattr(self, name))


class OutputReport(NamedTuple):
    """A decoded OUTPUT report."""

    command: StiffnessCommand
    sequence: int


@dataclass(frozen=True)
class DisplayInfo:
    """A decoded FEATURE report: what the display is and how it is configured.

    ``level_max`` is the full-scale level; ``watchdog_ms`` (0 = off) is how long
    the display keeps rendering without an OUTPUT report; stiffnesses are in N/m
    (0 = not stated by the firmware).
    """

    level_max: int
    firmware_version: tuple[int, int] = (0, 0)
    watchdog_ms: int = 0
    min_stiffness_n_per_m: int = 0
    max_stiffness_n_per_m: int = 0
    protocol_version: int = PROTOCOL_VERSION

    def __post_init__(self) -> None:
        _check_uint("DisplayInfo", "level_max", self.level_max, 16)
        if self.level_max < 1:
            raise ProtocolError("DisplayInfo.level_max = 0: expected at least 1")
        if not isinstance(self.firmware_version, tuple) or len(self.firmware_version) != 2:
            raise ProtocolError(
                f"DisplayInfo.firmware_version = {self.firmware_version!r}: expected a tuple "
                "(major, minor) of integers in [0, 255]"
            )
        for name, part in zip(("major", "minor"), self.firmware_version, strict=True):
            _check_uint("DisplayInfo", f"firmware_version.{name}", part, 8)
        _check_uint("DisplayInfo", "watchdog_ms", self.watchdog_ms, 16)
        _check_uint("DisplayInfo", "min_stiffness_n_per_m", self.min_stiffness_n_per_m, 32)
        _check_uint("DisplayInfo", "max_stiffness_n_per_m", self.max_stiffness_n_per_m, 32)
        if 0 < self.max_stiffness_n_per_m < self.min_stiffness_n_per_m:
            raise ProtocolError(
                f"DisplayInfo.max_stiffness_n_per_m = {self.max_stiffness_n_per_m}: below "
                f"min_stiffness_n_per_m = {self.min_stiffness_n_per_m}"
            )
        if not _is_version(self.protocol_version):
            raise ProtocolError(
                f"DisplayInfo.protocol_version = {self.protocol_version!r}: this host speaks "
                f"versions {_versions()}"
            )


@dataclass(frozen=True)
class DeviceStatus:
    """A decoded INPUT report.

    ``state`` is one of :data:`DEVICE_STATES`; ``level`` the level rendered now;
    ``faults`` the names (keys of :data:`FAULT_BITS`) of the fault bits set;
    ``sequence`` the echo of the last accepted OUTPUT report's sequence number.
    """

    state: str
    level: int
    faults: frozenset[str] = frozenset()
    sequence: int = 0

    def __post_init__(self) -> None:
        if self.state not in DEVICE_STATES:
            raise ProtocolError(
                f"DeviceStatus.state = {self.state!r}: expected one of {', '.join(DEVICE_STATES)}"
            )
        _check_uint("DeviceStatus", "level", self.level, 16)
        unknown = set(self.faults) - set(FAULT_BITS)
        if unknown:
            raise ProtocolError(
                f"DeviceStatus.faults names {sorted(unknown)}: expected names from "
                f"{', '.join(FAULT_BITS)}"
            )
        _check_uint("DeviceStatus", "sequence", self.sequence, 8)
        # PROTOCOL.md: while any fault bit 0-3 is set the actuator is disabled (state 2, level 0).
        disabling = sorted(set(self.faults) & set(DISABLING_FAULTS))
        if disabling and (self.state != "fault" or self.level != 0):
            raise ProtocolError(
                f"DeviceStatus: faults {', '.join(disabling)} disable the actuator, so state must "
                f"be 'fault' with level 0, got state {self.state!r} with level {self.level}"
            )


# --------------------------------------------------------------------------- encode / decode


def _pack(layout: ReportLayout, *values: int) -> bytes:
    body = layout.packer.pack(layout.report_id, *values, 0)[:-1]
    return body + bytes([crc8(body)])


def _unpack(layout: ReportLayout, data: bytes) -> tuple[int, ...]:
    """Check report ID, length and CRC; return the field values between ID and CRC."""
    where = f"{layout.kind} report 0x{layout.report_id:02X} ({layout.name})"
    if not isinstance(data, bytes | bytearray | memoryview):
        raise ProtocolError(f"{where}: expected bytes, got {type(data).__name__}")
    data = bytes(data)
    # The ID first: a foreign report (a grip report from a version-1 display) is named as such.
    if data and data[0] != layout.report_id:
        raise ProtocolError(
            f"{where}: report_id = 0x{data[0]:02X}, expected 0x{layout.report_id:02X}"
        )
    if len(data) != layout.size:
        raise ProtocolError(
            f"{where}: report length is {len(data)} bytes, expected {layout.size}"
        )
    expected = crc8(data[:-1])
    if data[-1] != expected:
        raise ProtocolError(
            f"{where}: crc = 0x{data[-1]:02X}, expected 0x{expected:02X} (report corrupted)"
        )
    return layout.packer.unpack(data)[1:-1]


def _versions() -> str:
    return " and ".join(str(v) for v in PROTOCOL_VERSIONS)


def _check_version(owner: str, version: object) -> None:
    if not _is_version(version):
        raise ProtocolError(f"{owner}.version = {version!r}: this host speaks versions {_versions()}")


def _reserved_bits(where: str, name: str, value: int, used: int) -> None:
    if value & ~used & 0xFF:
        raise ProtocolError(
            f"{where}: {name} = 0b{value:08b} sets reserved bits 0b{value & ~used & 0xFF:08b}"
        )


def encode_output_report(
    command: StiffnessCommand, *, sequence: int, version: int = PROTOCOL_VERSION
) -> bytes:
    """The 8-byte OUTPUT report (ID 0x01) that sets ``command``, numbered ``sequence`` (0-255).

    ``version`` is the protocol version of the display it is for (its FEATURE report's
    ``protocol_version``); the layout is the same in every version.
    """
    _check_uint("output report", "sequence", sequence, 8)
    _check_version("output report", version)
    version_command = version << 4 | COMMAND_SET_STIFFNESS
    return _pack(
        OUTPUT_LAYOUT, version_command, command.flags, command.level, command.uncertainty, sequence
    )


def decode_output_report(data: bytes, *, version: int | None = None) -> OutputReport:
    """Decode an OUTPUT report (what a display's firmware does with the host's bytes).

    ``version``: the only protocol version accepted (a display's own); None accepts every
    version of :data:`PROTOCOL_VERSIONS`.
    """
    if version is not None:
        _check_version("decode_output_report", version)
    version_command, flags, level, uncertainty, sequence = _unpack(OUTPUT_LAYOUT, data)
    where = "output report 0x01"
    accepted = PROTOCOL_VERSIONS if version is None else (version,)
    if version_command >> 4 not in accepted:
        raise ProtocolError(
            f"{where}: version_command = 0x{version_command:02X} says protocol version "
            f"{version_command >> 4}, expected {' or '.join(str(v) for v in accepted)}"
        )
    if version_command & 0x0F != COMMAND_SET_STIFFNESS:
        raise ProtocolError(
            f"{where}: version_command = 0x{version_command:02X} names command "
            f"{version_command & 0x0F}, expected {COMMAND_SET_STIFFNESS} (set stiffness)"
        )
    _reserved_bits(where, "flags", flags, sum(1 << bit for bit in FLAG_BITS.values()))
    states = {name: bool(flags >> bit & 1) for name, bit in FLAG_BITS.items()}
    try:
        command = StiffnessCommand(level=level, uncertainty=uncertainty, **states)
    except ProtocolError as exc:
        raise ProtocolError(f"{where}: {exc}") from None
    return OutputReport(command, sequence)


def encode_feature_report(info: DisplayInfo) -> bytes:
    """The 17-byte FEATURE report (ID 0x02) describing ``info``."""
    return _pack(
        FEATURE_LAYOUT,
        info.protocol_version,
        *info.firmware_version,
        info.level_max,
        info.watchdog_ms,
        info.min_stiffness_n_per_m,
        info.max_stiffness_n_per_m,
    )


def decode_feature_report(data: bytes) -> DisplayInfo:
    """Decode a FEATURE report; a version this host does not speak is an error naming the field."""
    version, major, minor, level_max, watchdog_ms, k_min, k_max = _unpack(FEATURE_LAYOUT, data)
    try:
        return DisplayInfo(
            level_max=level_max,
            firmware_version=(major, minor),
            watchdog_ms=watchdog_ms,
            min_stiffness_n_per_m=k_min,
            max_stiffness_n_per_m=k_max,
            protocol_version=version,
        )
    except ProtocolError as exc:
        raise ProtocolError(f"feature report 0x02: {exc}") from None


def encode_input_report(status: DeviceStatus) -> bytes:
    """The 7-byte INPUT report (ID 0x03) carrying ``status`` (what firmware sends)."""
    faults = sum(1 << FAULT_BITS[name] for name in status.faults)
    return _pack(
        INPUT_LAYOUT, DEVICE_STATES.index(status.state), status.level, faults, status.sequence
    )


def decode_input_report(data: bytes) -> DeviceStatus:
    """Decode an INPUT (status) report."""
    state, level, faults, sequence = _unpack(INPUT_LAYOUT, data)
    where = "input report 0x03"
    if state >= len(DEVICE_STATES):
        raise ProtocolError(
            f"{where}: state = {state}, expected 0-{len(DEVICE_STATES) - 1} "
            f"({', '.join(DEVICE_STATES)})"
        )
    _reserved_bits(where, "faults", faults, sum(1 << bit for bit in FAULT_BITS.values()))
    names = frozenset(name for name, bit in FAULT_BITS.items() if faults >> bit & 1)
    try:
        return DeviceStatus(DEVICE_STATES[state], level, names, sequence)
    except ProtocolError as exc:
        raise ProtocolError(f"{where}: {exc}") from None


# --------------------------------------------------------------------------- grip (version 2)

_GRIP_NAMES = frozenset({"GRIP_BUTTONS", "GripReport", "decode_grip_report", "encode_grip_report"})


def __getattr__(name: str) -> object:
    """The grip report's API, defined in :mod:`haptics.protocol_grip`, imported on first use."""
    if name in _GRIP_NAMES:
        from haptics import protocol_grip

        return getattr(protocol_grip, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
