"""Audit of haptics.protocol against PROTOCOL.md: reports built byte by byte from the document
(offsets, little-endian integers, the CRC by polynomial division), the range of every field and
the report named in every refusal."""

from __future__ import annotations

import pytest

from haptics import protocol, protocol_grip
from haptics.errors import ProtocolError
from haptics.protocol import (
    DeviceStatus,
    DisplayInfo,
    StiffnessCommand,
    decode_feature_report,
    decode_input_report,
    decode_output_report,
    encode_feature_report,
    encode_input_report,
    encode_output_report,
)


def polynomial_division_crc8(data: bytes) -> int:
    """CRC-8 as PROTOCOL.md defines it, as the remainder of data * x^8 divided by x^8+x^2+x+1.

    Init 0, no reflection and no final XOR make the CRC exactly this remainder; computing it
    by long division over GF(2) does not share the table or the shift register of the module.
    """
    value = int.from_bytes(data, "big") << 8
    divisor = 0x107
    while value.bit_length() > 8:
        value ^= divisor << (value.bit_length() - 9)
    return value


def report(*parts: bytes) -> bytes:
    body = b"".join(parts)
    return body + bytes([polynomial_division_crc8(body)])


def u8(value: int) -> bytes:
    return value.to_bytes(1, "little")


def u16(value: int) -> bytes:
    return value.to_bytes(2, "little")


def u32(value: int) -> bytes:
    return value.to_bytes(4, "little")


def test_the_division_crc_is_the_documented_crc():
    assert polynomial_division_crc8(b"123456789") == 0xF4
    # PROTOCOL.md's OUTPUT example: its last byte is the CRC of the seven before it
    assert polynomial_division_crc8(bytes.fromhex("01 11 05 34 12 2a 07")) == 0x39


# --------------------------------------------------------------------------- documented offsets


@pytest.mark.parametrize("version", [1, 2])
def test_an_output_report_puts_every_field_at_its_documented_offset(version):
    command = StiffnessCommand(level=0xABCD, uncertainty=0x5A, fading=True, provisional=True)
    expected = report(
        u8(0x01),
        u8(version << 4 | 0x1),  # high nibble version, low nibble command 1
        u8(1 << 3 | 1 << 4),  # bit 3 fading, bit 4 provisional
        u16(0xABCD),
        u8(0x5A),
        u8(0xC3),
    )
    assert len(expected) == 8
    assert encode_output_report(command, sequence=0xC3, version=version) == expected
    assert decode_output_report(expected, version=version) == (command, 0xC3)


@pytest.mark.parametrize(
    ("flag", "bit"), [("rigid", 0), ("unknown", 1), ("stale", 2), ("fading", 3), ("provisional", 4)]
)
def test_each_output_flag_is_its_documented_bit(flag, bit):
    expected = report(u8(0x01), u8(0x21), u8(1 << bit), u16(7), u8(0), u8(1))
    command = StiffnessCommand(level=7, **{flag: True})
    assert encode_output_report(command, sequence=1, version=2) == expected
    assert decode_output_report(expected).command == command


@pytest.mark.parametrize("version", [1, 2])
def test_a_feature_report_puts_every_field_at_its_documented_offset(version):
    info = DisplayInfo(level_max=0x0102, firmware_version=(3, 7), watchdog_ms=0x0304,
                       min_stiffness_n_per_m=0x05060708, max_stiffness_n_per_m=0x090A0B0C,
                       protocol_version=version)
    expected = report(
        u8(0x02), u8(version), u8(3), u8(7), u16(0x0102), u16(0x0304),
        u32(0x05060708), u32(0x090A0B0C),
    )
    assert len(expected) == 17
    assert encode_feature_report(info) == expected
    assert decode_feature_report(expected) == info


@pytest.mark.parametrize(("state", "code"), [("free", 0), ("rendering", 1), ("watchdog", 3)])
def test_a_status_report_puts_every_field_at_its_documented_offset(state, code):
    status = DeviceStatus(state, 0x0A0B, frozenset({"bad_report"}), 0xEE)
    expected = report(u8(0x03), u8(code), u16(0x0A0B), u8(1 << 4), u8(0xEE))
    assert len(expected) == 7
    assert encode_input_report(status) == expected
    assert decode_input_report(expected) == status


@pytest.mark.parametrize(
    ("fault", "bit"),
    [("over_temperature", 0), ("over_current", 1), ("position_error", 2), ("undervoltage", 3)],
)
def test_each_disabling_fault_is_its_documented_bit(fault, bit):
    status = DeviceStatus("fault", 0, frozenset({fault}), 5)
    expected = report(u8(0x03), u8(2), u16(0), u8(1 << bit), u8(5))
    assert encode_input_report(status) == expected
    assert decode_input_report(expected) == status


# --------------------------------------------------------------------------- field ranges


def test_a_display_that_states_its_minimum_but_not_its_maximum_stiffness_is_accepted():
    # PROTOCOL.md: max_stiffness_n_per_m 0 = not stated, so it is no maximum below the minimum
    data = report(u8(0x02), u8(2), u8(1), u8(0), u16(4095), u16(400), u32(800), u32(0))
    info = decode_feature_report(data)
    assert (info.min_stiffness_n_per_m, info.max_stiffness_n_per_m) == (800, 0)
    assert encode_feature_report(info) == data


@pytest.mark.parametrize(
    ("field", "largest"),
    [
        ("level_max", 0xFFFF),
        ("watchdog_ms", 0xFFFF),
        ("min_stiffness_n_per_m", 0xFFFF_FFFF),
        ("max_stiffness_n_per_m", 0xFFFF_FFFF),
    ],
)
def test_display_info_fields_take_their_whole_wire_range_and_no_more(field, largest):
    info = DisplayInfo(**{"level_max": 1, field: largest})
    assert decode_feature_report(encode_feature_report(info)) == info
    with pytest.raises(ProtocolError, match=f"DisplayInfo.{field} = {largest + 1}: expected"):
        DisplayInfo(**{"level_max": 1, field: largest + 1})
    with pytest.raises(ProtocolError, match=f"DisplayInfo.{field} = -1: expected"):
        DisplayInfo(**{"level_max": 1, field: -1})


@pytest.mark.parametrize("part", [0, 1])
def test_a_firmware_version_part_is_a_byte(part):
    largest = [0, 0]
    largest[part] = 255
    info = DisplayInfo(level_max=1, firmware_version=tuple(largest))
    assert decode_feature_report(encode_feature_report(info)) == info
    largest[part] = 256
    with pytest.raises(ProtocolError, match=r"firmware_version\.(major|minor) = 256"):
        DisplayInfo(level_max=1, firmware_version=tuple(largest))


@pytest.mark.parametrize(("field", "largest"), [("level", 0xFFFF), ("sequence", 0xFF)])
def test_status_fields_take_their_whole_wire_range_and_no_more(field, largest):
    values = {"level": 0, "sequence": 0, field: largest}
    status = DeviceStatus("rendering", **values)
    assert decode_input_report(encode_input_report(status)) == status
    values[field] = largest + 1
    with pytest.raises(ProtocolError, match=f"DeviceStatus.{field} = {largest + 1}: expected"):
        DeviceStatus("rendering", **values)


# --------------------------------------------------------------------------- refusals


@pytest.mark.parametrize(
    ("decode", "data", "message"),
    [
        (decode_output_report, report(u8(0x01), u8(0x11), u8(0x03), u16(1), u8(0), u8(0)),
         r"output report 0x01: StiffnessCommand flags: rigid and unknown"),
        (decode_feature_report,
         report(u8(0x02), u8(1), u8(1), u8(0), u16(0), u16(0), u32(0), u32(0)),
         r"feature report 0x02: DisplayInfo\.level_max = 0"),
        (decode_input_report, report(u8(0x03), u8(1), u16(9), u8(1), u8(0)),
         r"input report 0x03: DeviceStatus: faults over_temperature"),
    ],
)
def test_a_refusal_by_the_decoded_message_names_the_report(decode, data, message):
    with pytest.raises(ProtocolError, match="^" + message):
        decode(data)


@pytest.mark.parametrize("wrap", [bytearray, memoryview])
def test_decoders_take_any_bytes_like_buffer(wrap):
    command = StiffnessCommand(level=3)
    assert decode_output_report(wrap(encode_output_report(command, sequence=4))) == (command, 4)
    info = DisplayInfo(level_max=9)
    assert decode_feature_report(wrap(encode_feature_report(info))) == info
    status = DeviceStatus("free", 0)
    assert decode_input_report(wrap(encode_input_report(status))) == status


# --------------------------------------------------------------------------- module API


@pytest.mark.parametrize(
    "name", ["GRIP_BUTTONS", "GripReport", "decode_grip_report", "encode_grip_report"]
)
def test_the_grip_api_can_be_imported_from_the_protocol_module(name):
    assert getattr(protocol, name) is getattr(protocol_grip, name)


def test_an_unknown_protocol_name_is_an_attribute_error():
    with pytest.raises(AttributeError, match="has no attribute 'GripStatus'"):
        protocol.GripStatus  # noqa: B018


def test_the_usage_page_constant_is_the_one_the_descriptor_declares():
    # PROTOCOL.md: vendor-defined usage page 0xFF00, a 2-byte Usage Page item (prefix 0x06)
    assert protocol.REPORT_DESCRIPTOR[0] == 0x06
    assert protocol.USAGE_PAGE == 0xFF00 == int.from_bytes(protocol.REPORT_DESCRIPTOR[1:3], "little")
