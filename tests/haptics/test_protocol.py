"""The HID protocol: golden vectors byte for byte, decoder error paths, round trips.

Versions 1 and 2: the golden vectors of version 1 are the bytes a version-1 display
always got; version 2 adds the grip report (INPUT 0x04).
"""

from __future__ import annotations

import contextlib
from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st

from haptics.errors import ProtocolError
from haptics.protocol import (
    DEVICE_STATES,
    FAULT_BITS,
    FEATURE_LAYOUT,
    GRIP_LAYOUT,
    INPUT_LAYOUT,
    LAYOUTS,
    OUTPUT_LAYOUT,
    PROTOCOL_VERSIONS,
    REPORT_DESCRIPTOR,
    DeviceStatus,
    DisplayInfo,
    StiffnessCommand,
    crc8,
    decode_feature_report,
    decode_input_report,
    decode_output_report,
    encode_feature_report,
    encode_input_report,
    encode_output_report,
    layout_markdown,
    report_descriptor,
)
from haptics.protocol_grip import GRIP_BUTTONS, GripReport, decode_grip_report, encode_grip_report
from teleop.operator import BUTTONS

PROTOCOL_MD = Path(__file__).resolve().parents[2] / "haptics" / "PROTOCOL.md"


def reference_crc8(data: bytes) -> int:
    """Bit by bit, straight from the definition (poly 0x07, init 0, no reflection)."""
    crc = 0
    for byte in data:
        crc ^= byte
        for _ in range(8):
            crc = ((crc << 1) ^ 0x07) & 0xFF if crc & 0x80 else (crc << 1) & 0xFF
    return crc


def with_crc(body: bytes) -> bytes:
    return body + bytes([reference_crc8(body)])


# --------------------------------------------------------------------------- CRC


def test_crc8_catalogue_check_value():
    assert crc8(b"123456789") == 0xF4
    assert crc8(b"") == 0


@given(st.binary(max_size=64))
def test_crc8_matches_the_bitwise_definition(data):
    assert crc8(data) == reference_crc8(data)


# --------------------------------------------------------------------------- golden vectors

OUTPUT_GOLDEN = [
    (StiffnessCommand(level=0), 0, "01 11 00 00 00 00 00 68"),
    (StiffnessCommand(level=0x1234, uncertainty=42, rigid=True, stale=True), 7,
     "01 11 05 34 12 2a 07 39"),
    (StiffnessCommand(level=0, uncertainty=106, unknown=True), 0, "01 11 02 00 00 6a 00 db"),
    (StiffnessCommand(level=0xFFFF, uncertainty=255, rigid=True, stale=True, fading=True,
                      provisional=True), 255, "01 11 1d ff ff ff ff 70"),
    (StiffnessCommand(level=1, fading=True), 128, "01 11 08 01 00 00 80 ee"),
]


#: The same commands to a version-2 display: only the version nibble (and the CRC) differ.
OUTPUT_GOLDEN_V2 = [
    (StiffnessCommand(level=0), 0, "01 21 00 00 00 00 00 cd"),
    (StiffnessCommand(level=0x1234, uncertainty=42, rigid=True, stale=True), 7,
     "01 21 05 34 12 2a 07 9c"),
]


@pytest.mark.parametrize(("command", "sequence", "expected"), OUTPUT_GOLDEN)
def test_output_report_golden_vectors(command, sequence, expected):
    assert encode_output_report(command, sequence=sequence, version=1) == bytes.fromhex(expected)
    assert decode_output_report(bytes.fromhex(expected)) == (command, sequence)
    assert decode_output_report(bytes.fromhex(expected), version=1) == (command, sequence)


@pytest.mark.parametrize(("command", "sequence", "expected"), OUTPUT_GOLDEN_V2)
def test_output_report_golden_vectors_version_2(command, sequence, expected):
    assert encode_output_report(command, sequence=sequence) == bytes.fromhex(expected)
    assert encode_output_report(command, sequence=sequence, version=2) == bytes.fromhex(expected)
    assert decode_output_report(bytes.fromhex(expected), version=2) == (command, sequence)


FEATURE_GOLDEN = (
    DisplayInfo(level_max=4095, firmware_version=(1, 0), watchdog_ms=1000,
                min_stiffness_n_per_m=0, max_stiffness_n_per_m=5000, protocol_version=1),
    "02 01 01 00 ff 0f e8 03 00 00 00 00 88 13 00 00 03",
)
FEATURE_GOLDEN_V2 = (
    DisplayInfo(level_max=4095, firmware_version=(1, 0), watchdog_ms=1000,
                min_stiffness_n_per_m=0, max_stiffness_n_per_m=5000),
    "02 02 01 00 ff 0f e8 03 00 00 00 00 88 13 00 00 db",
)
INPUT_GOLDEN = (DeviceStatus("rendering", 1238, frozenset(), 7), "03 01 d6 04 00 07 1e")
#: Grip reports (version 2), written out by hand from PROTOCOL.md's table.
GRIP_GOLDEN = [
    # grip 0.25 = 2500 = 0x09c4, 12.5 N = 1250 = 0x04e2, enable + grasp, sequence 42
    (GripReport(0.25, 12.5, True, frozenset({"grasp"}), 42), "04 03 00 c4 09 e2 04 2a c6"),
    (GripReport(0.0, 0.0, False, frozenset(), 0), "04 00 00 00 00 00 00 00 4c"),
    (GripReport(1.0, 655.35, True, frozenset(GRIP_BUTTONS), 128), "04 1f 00 10 27 ff ff 80 8d"),
    # no force sensor: flags bit 0, force 0
    (GripReport(0.1, None, True, frozenset({"release"}), 7), "04 05 01 e8 03 00 00 07 c2"),
    (GripReport(1.0, None, False, frozenset({"stop", "next"}), 255), "04 18 01 10 27 00 00 ff 31"),
]


def test_golden_crcs_are_the_reference_crcs():
    goldens = [*OUTPUT_GOLDEN, *OUTPUT_GOLDEN_V2, *GRIP_GOLDEN, FEATURE_GOLDEN, FEATURE_GOLDEN_V2]
    for *_, expected in goldens:
        report = bytes.fromhex(expected)
        assert report[-1] == reference_crc8(report[:-1])


@pytest.mark.parametrize("golden", [FEATURE_GOLDEN, FEATURE_GOLDEN_V2])
def test_feature_report_golden_vector(golden):
    info, expected = golden
    assert encode_feature_report(info) == bytes.fromhex(expected)
    assert decode_feature_report(bytes.fromhex(expected)) == info


@pytest.mark.parametrize(("report", "expected"), GRIP_GOLDEN)
def test_grip_report_golden_vectors(report, expected):
    assert encode_grip_report(report) == bytes.fromhex(expected)
    assert decode_grip_report(bytes.fromhex(expected)) == report


def test_grip_buttons_are_operator_buttons():
    assert set(GRIP_BUTTONS) <= set(BUTTONS)
    assert GRIP_BUTTONS == ("grasp", "release", "stop", "next")


def test_input_report_golden_vectors():
    status, expected = INPUT_GOLDEN
    assert encode_input_report(status) == bytes.fromhex(expected)
    assert decode_input_report(bytes.fromhex(expected)) == status
    faulted = DeviceStatus("fault", 0, frozenset({"over_current", "bad_report"}), 0x2A)
    expected = with_crc(bytes.fromhex("03 02 00 00 12 2a"))
    assert encode_input_report(faulted) == expected
    assert decode_input_report(expected) == faulted


def test_report_descriptor_golden_bytes():
    version_1 = bytes.fromhex(
        "06 00 ff 09 01 a1 01 15 00 26 ff 00 75 08"
        " 85 01 09 02 95 07 91 02"
        " 85 02 09 03 95 10 b1 02"
        " 85 03 09 04 95 06 81 02"
        " c0"
    )
    assert report_descriptor(1) == version_1  # a version-1 display's, as it always was
    version_2 = bytes.fromhex(
        "06 00 ff 09 01 a1 01 15 00 26 ff 00 75 08"
        " 85 01 09 02 95 07 91 02"
        " 85 02 09 03 95 10 b1 02"
        " 85 03 09 04 95 06 81 02"
        " 85 04 09 05 95 08 81 02"
        " c0"
    )
    assert version_2 == REPORT_DESCRIPTOR == report_descriptor(2)
    with pytest.raises(ProtocolError, match="version = 3"):
        report_descriptor(3)


def parse_report_lengths(descriptor: bytes) -> dict[tuple[str, int], int]:
    """Bytes per (main item, report ID) from HID short items, per the HID 1.11 spec."""
    mains = {0x80: "input", 0x90: "output", 0xB0: "feature"}
    size_bits = count = report_id = 0
    lengths: dict[tuple[str, int], int] = {}
    i = 0
    while i < len(descriptor):
        prefix = descriptor[i]
        n = (0, 1, 2, 4)[prefix & 0x03]
        value = int.from_bytes(descriptor[i + 1:i + 1 + n], "little")
        tag = prefix & 0xFC
        if tag == 0x74:
            size_bits = value
        elif tag == 0x94:
            count = value
        elif tag == 0x84:
            report_id = value
        elif tag in mains:
            key = (mains[tag], report_id)
            lengths[key] = lengths.get(key, 0) + size_bits * count // 8
        i += 1 + n
    return lengths


@pytest.mark.parametrize("version", PROTOCOL_VERSIONS)
def test_descriptor_declares_the_encoders_report_lengths(version):
    declared = parse_report_lengths(report_descriptor(version))
    assert declared == {(layout.kind, layout.report_id): layout.size - 1 for layout in LAYOUTS
                        if layout.version <= version}
    assert report_descriptor(version)[:3] == bytes([0x06, 0x00, 0xFF])  # vendor-defined page
    assert (("input", GRIP_LAYOUT.report_id) in declared) == (version >= 2)


def test_protocol_document_matches_the_code():
    text = PROTOCOL_MD.read_text(encoding="utf-8")
    for layout in LAYOUTS:
        assert layout_markdown(layout) in text, f"PROTOCOL.md is out of date for {layout.name}"
    assert REPORT_DESCRIPTOR.hex(" ") in text
    assert report_descriptor(1).hex(" ") in text
    for *_, expected in (OUTPUT_GOLDEN[1], OUTPUT_GOLDEN_V2[1], FEATURE_GOLDEN, FEATURE_GOLDEN_V2,
                         INPUT_GOLDEN, GRIP_GOLDEN[0], GRIP_GOLDEN[3]):
        assert expected in text


def test_layout_offsets_are_contiguous():
    for layout in LAYOUTS:
        rows = layout.offsets()
        assert rows[0][0] == 0 and rows[0][2].name == "report_id"
        assert rows[-1][2].name == "crc" and rows[-1][0] == layout.size - 1
        assert all(a + s == b for (a, s, _), (b, _, _) in zip(rows, rows[1:], strict=False))


# --------------------------------------------------------------------------- decoder errors

GOOD_OUTPUT = bytes.fromhex("01 11 05 34 12 2a 07 39")


@pytest.mark.parametrize(
    ("data", "field"),
    [
        (GOOD_OUTPUT[:7], "report length is 7 bytes, expected 8"),
        (GOOD_OUTPUT + b"\x00", "report length is 9 bytes"),
        (b"", "report length is 0"),
        (with_crc(bytes.fromhex("03 11 05 34 12 2a 07")), "report_id = 0x03, expected 0x01"),
        (GOOD_OUTPUT[:-1] + b"\x38", "crc = 0x38, expected 0x39"),
        (bytes.fromhex("01 11 05 35 12 2a 07 39"), "crc"),
        (with_crc(bytes.fromhex("01 11 25 34 12 2a 07")), "flags = 0b00100101 sets reserved"),
        (with_crc(bytes.fromhex("01 11 85 34 12 2a 07")), "reserved bits 0b10000000"),
        (with_crc(bytes.fromhex("01 31 05 34 12 2a 07")), "protocol version 3, expected 1 or 2"),
        (with_crc(bytes.fromhex("01 01 05 34 12 2a 07")), "protocol version 0, expected 1 or 2"),
        (with_crc(bytes.fromhex("01 12 05 34 12 2a 07")), "names command 2"),
        (with_crc(bytes.fromhex("01 11 03 34 12 2a 07")), "rigid and unknown are both set"),
    ],
)
def test_output_decoder_names_the_bad_field(data, field):
    with pytest.raises(ProtocolError, match=field):
        decode_output_report(data)


def test_a_display_refuses_another_versions_output_report():
    version_2 = bytes.fromhex(OUTPUT_GOLDEN_V2[1][2])
    with pytest.raises(ProtocolError, match="0x21 says protocol version 2, expected 1"):
        decode_output_report(version_2, version=1)
    with pytest.raises(ProtocolError, match="0x11 says protocol version 1, expected 2"):
        decode_output_report(bytes.fromhex(OUTPUT_GOLDEN[1][2]), version=2)
    with pytest.raises(ProtocolError, match="version = 3: this host speaks versions 1 and 2"):
        encode_output_report(StiffnessCommand(level=1), sequence=0, version=3)


GOOD_GRIP = bytes.fromhex(GRIP_GOLDEN[0][1])


@pytest.mark.parametrize(
    ("data", "field"),
    [
        (GOOD_GRIP[:-1], r"input report 0x04 \(grip\): report length is 8 bytes, expected 9"),
        (GOOD_GRIP + b"\x00", r"\(grip\): report length is 10 bytes, expected 9"),
        (bytes.fromhex(INPUT_GOLDEN[1]), r"\(grip\): report_id = 0x03, expected 0x04"),
        (with_crc(bytes.fromhex("03 03 00 c4 09 e2 04 2a")),
         r"\(grip\): report_id = 0x03, expected 0x04"),
        (GOOD_GRIP[:-1] + b"\xc7", r"\(grip\): crc = 0xC7, expected 0xC6"),
        (bytes.fromhex("04 03 00 c5 09 e2 04 2a c6"), r"\(grip\): crc"),
        (with_crc(bytes.fromhex("04 23 00 c4 09 e2 04 2a")),
         r"\(grip\): buttons = 0b00100011 sets reserved bits 0b00100000"),
        (with_crc(bytes.fromhex("04 83 00 c4 09 e2 04 2a")), r"\(grip\): buttons .*0b10000000"),
        (with_crc(bytes.fromhex("04 03 02 c4 09 e2 04 2a")),
         r"\(grip\): flags = 0b00000010 sets reserved bits"),
        (with_crc(bytes.fromhex("04 03 80 c4 09 e2 04 2a")), r"\(grip\): flags .*0b10000000"),
        (with_crc(bytes.fromhex("04 03 00 11 27 e2 04 2a")),
         r"\(grip\): position = 10001, expected 0 to 10000"),
        (with_crc(bytes.fromhex("04 03 00 ff ff e2 04 2a")), r"\(grip\): position = 65535"),
        (with_crc(bytes.fromhex("04 03 01 c4 09 e2 04 2a")),
         r"\(grip\): force = 1250 with flags bit 0 \(no force sensor\) set, expected 0"),
    ],
)
def test_grip_decoder_names_the_report_and_the_bad_field(data, field):
    with pytest.raises(ProtocolError, match=field):
        decode_grip_report(data)


@pytest.mark.parametrize(
    ("args", "field"),
    [
        ((1.5, None, True, frozenset(), 0), r"GripReport.grip = 1.5: expected a number in \[0, 1\]"),
        ((-0.1, None, True, frozenset(), 0), "grip = -0.1"),
        ((float("nan"), None, True, frozenset(), 0), "grip = nan"),
        ((True, None, True, frozenset(), 0), "grip = True"),
        ((0.5, -1.0, True, frozenset(), 0), "force_n = -1.0"),
        ((0.5, 700.0, True, frozenset(), 0), r"force_n = 700.0: expected a number in \[0, 655.35\]"),
        ((0.5, float("inf"), True, frozenset(), 0), "force_n = inf"),
        ((0.5, None, 1, frozenset(), 0), "enable = 1: expected True or False"),
        ((0.5, None, True, frozenset({"quit"}), 0), r"buttons names \['quit'\]"),
        ((0.5, None, True, frozenset({"enable"}), 0), r"buttons names \['enable'\]"),
        ((0.5, None, True, "grasp", 0), "not a string"),
        ((0.5, None, True, frozenset(), 256), "sequence = 256"),
        ((0.5, None, True, frozenset(), -1), "sequence = -1"),
    ],
)
def test_grip_reports_are_checked_on_construction(args, field):
    with pytest.raises(ProtocolError, match=field):
        GripReport(*args)


def test_grip_report_rounds_to_the_wire_resolution_and_takes_any_set_of_names():
    report = GripReport(0.123456, 1.234, True, ["grasp", "grasp"], 1)
    assert report.buttons == frozenset({"grasp"})
    decoded = decode_grip_report(encode_grip_report(report))
    assert (decoded.grip, decoded.force_n) == (0.1235, 1.23)


@pytest.mark.parametrize(
    ("data", "field"),
    [
        (bytes.fromhex(INPUT_GOLDEN[1])[:-2], "report length is 5 bytes, expected 7"),
        (with_crc(bytes.fromhex("03 04 d6 04 00 07")), "state = 4"),
        (with_crc(bytes.fromhex("03 01 d6 04 20 07")), "faults = 0b00100000 sets reserved"),
        (with_crc(bytes.fromhex("01 01 d6 04 00 07")), "report_id = 0x01, expected 0x03"),
        (bytes.fromhex("03 01 d6 04 00 07 1f"), "crc = 0x1F, expected 0x1E"),
    ],
)
def test_input_decoder_names_the_bad_field(data, field):
    with pytest.raises(ProtocolError, match=field):
        decode_input_report(data)


@pytest.mark.parametrize(
    ("body", "field"),
    [
        ("02 03 01 00 ff 0f e8 03 00 00 00 00 88 13 00 00",
         "protocol_version = 3: this host speaks versions 1 and 2"),
        ("02 00 01 00 ff 0f e8 03 00 00 00 00 88 13 00 00", "protocol_version = 0"),
        ("02 01 01 00 00 00 e8 03 00 00 00 00 88 13 00 00", "level_max = 0"),
        ("02 01 01 00 ff 0f e8 03 88 13 00 00 10 00 00 00", "max_stiffness_n_per_m = 16: below"),
    ],
)
def test_feature_decoder_names_the_bad_field(body, field):
    with pytest.raises(ProtocolError, match=field):
        decode_feature_report(with_crc(bytes.fromhex(body)))


def test_decoders_refuse_non_bytes():
    with pytest.raises(ProtocolError, match="expected bytes, got list"):
        decode_output_report(list(GOOD_OUTPUT))


@pytest.mark.parametrize(
    ("kwargs", "field"),
    [
        ({"level": 0x10000}, "level = 65536"),
        ({"level": -1}, "level = -1"),
        ({"level": 1.0}, "level = 1.0"),
        ({"level": True}, "level = True"),
        ({"level": 1, "uncertainty": 256}, "uncertainty = 256"),
        ({"level": 1, "stale": 1}, "stale = 1: expected True or False"),
        ({"level": 1, "rigid": True, "unknown": True}, "rigid and unknown"),
    ],
)
def test_commands_are_checked_on_construction(kwargs, field):
    with pytest.raises(ProtocolError, match=field):
        StiffnessCommand(**kwargs)


@pytest.mark.parametrize("sequence", [-1, 256, 1.5])
def test_encoder_refuses_a_bad_sequence(sequence):
    with pytest.raises(ProtocolError, match="sequence"):
        encode_output_report(StiffnessCommand(level=1), sequence=sequence)


def test_a_grip_report_from_a_version_1_display_is_named_as_a_foreign_report():
    # PROTOCOL.md: from a version-1 display a 0x04 report is refused like any unknown report.
    with pytest.raises(ProtocolError, match=r"\(status\): report_id = 0x04, expected 0x03"):
        decode_input_report(GOOD_GRIP)


@pytest.mark.parametrize(
    ("body", "field"),
    [
        ("03 01 64 00 01 07", "faults over_temperature disable the actuator, so state must be "
                              "'fault' with level 0, got state 'rendering' with level 100"),
        ("03 00 00 00 02 07", "faults over_current .* got state 'free'"),
        ("03 02 64 00 08 07", "faults undervoltage .* got state 'fault' with level 100"),
    ],
)
def test_a_status_whose_faults_contradict_its_state_is_refused(body, field):
    with pytest.raises(ProtocolError, match="input report 0x03: DeviceStatus: " + field):
        decode_input_report(with_crc(bytes.fromhex(body)))
    # a malformed-report fault does not disable the actuator; fault bits with state 2, level 0 agree
    assert decode_input_report(with_crc(bytes.fromhex("03 01 64 00 10 07"))).level == 100
    assert decode_input_report(with_crc(bytes.fromhex("03 02 00 00 0f 07"))).state == "fault"


@pytest.mark.parametrize("version", [2.0, 1.0, True, "2"])
def test_a_version_must_be_an_integer(version):
    with pytest.raises(ProtocolError, match=f"DisplayInfo.protocol_version = {version!r}"):
        DisplayInfo(4095, protocol_version=version)
    with pytest.raises(ProtocolError, match=f"output report.version = {version!r}"):
        encode_output_report(StiffnessCommand(level=1), sequence=7, version=version)
    with pytest.raises(ProtocolError, match=f"decode_output_report.version = {version!r}"):
        decode_output_report(GOOD_OUTPUT, version=version)
    with pytest.raises(ProtocolError, match="descriptor version"):
        report_descriptor(version)


@pytest.mark.parametrize("firmware", [5, (1,), (1, 2, 3), [1, 0], "10"])
def test_a_firmware_version_must_be_a_pair(firmware):
    with pytest.raises(ProtocolError, match=r"DisplayInfo.firmware_version = .*expected a tuple"):
        DisplayInfo(4095, firmware_version=firmware)


def test_status_fields_are_checked():
    with pytest.raises(ProtocolError, match="state = 'asleep'"):
        DeviceStatus("asleep", 0)
    with pytest.raises(ProtocolError, match="faults names \\['smoke'\\]"):
        DeviceStatus("fault", 0, frozenset({"smoke"}))


# --------------------------------------------------------------------------- round trips

commands = st.builds(
    StiffnessCommand,
    level=st.integers(0, 0xFFFF),
    uncertainty=st.integers(0, 255),
    rigid=st.booleans(),
    unknown=st.just(False),
    stale=st.booleans(),
    fading=st.booleans(),
    provisional=st.booleans(),
) | st.builds(StiffnessCommand, level=st.integers(0, 0xFFFF), uncertainty=st.integers(0, 255),
              unknown=st.just(True), stale=st.booleans(), fading=st.booleans())


@given(commands, st.integers(0, 255), st.sampled_from(PROTOCOL_VERSIONS))
def test_output_round_trip(command, sequence, version):
    report = encode_output_report(command, sequence=sequence, version=version)
    assert len(report) == OUTPUT_LAYOUT.size
    assert report[1] >> 4 == version
    assert decode_output_report(report, version=version) == (command, sequence)


@given(commands, st.integers(0, 255), st.integers(0, 8 * OUTPUT_LAYOUT.size - 1))
def test_every_single_bit_error_is_caught(command, sequence, bit):
    report = bytearray(encode_output_report(command, sequence=sequence))
    report[bit // 8] ^= 1 << (bit % 8)
    with pytest.raises(ProtocolError):
        decode_output_report(bytes(report))


@given(
    st.builds(
        DisplayInfo,
        level_max=st.integers(1, 0xFFFF),
        firmware_version=st.tuples(st.integers(0, 255), st.integers(0, 255)),
        watchdog_ms=st.integers(0, 0xFFFF),
        min_stiffness_n_per_m=st.integers(0, 1000),
        max_stiffness_n_per_m=st.integers(1000, 2**32 - 1),
        protocol_version=st.sampled_from(PROTOCOL_VERSIONS),
    )
)
def test_feature_round_trip(info):
    report = encode_feature_report(info)
    assert len(report) == FEATURE_LAYOUT.size
    assert decode_feature_report(report) == info


@given(
    st.builds(
        DeviceStatus,
        state=st.sampled_from(DEVICE_STATES),
        level=st.integers(0, 0xFFFF),
        faults=st.frozensets(st.just("bad_report")),
        sequence=st.integers(0, 255),
    )
    | st.builds(  # a disabling fault: state fault, level 0
        DeviceStatus,
        state=st.just("fault"),
        level=st.just(0),
        faults=st.frozensets(st.sampled_from(sorted(FAULT_BITS)), min_size=1),
        sequence=st.integers(0, 255),
    )
)
def test_input_round_trip(status):
    report = encode_input_report(status)
    assert len(report) == INPUT_LAYOUT.size
    assert decode_input_report(report) == status


#: Grip reports as the wire carries them: positions and forces in whole counts.
grip_reports = st.builds(
    GripReport,
    grip=st.integers(0, 10_000).map(lambda counts: counts / 10_000),
    force_n=st.none() | st.integers(0, 0xFFFF).map(lambda counts: counts / 100),
    enable=st.booleans(),
    buttons=st.frozensets(st.sampled_from(GRIP_BUTTONS)),
    sequence=st.integers(0, 255),
)


@given(grip_reports)
def test_grip_round_trip(report):
    data = encode_grip_report(report)
    assert len(data) == GRIP_LAYOUT.size
    assert decode_grip_report(data) == report
    assert encode_grip_report(decode_grip_report(data)) == data  # byte-exact both ways


@given(st.binary(min_size=GRIP_LAYOUT.size - 2, max_size=GRIP_LAYOUT.size - 2))
def test_every_valid_grip_report_re_encodes_byte_exact(body):
    data = with_crc(b"\x04" + body)
    try:
        report = decode_grip_report(data)
    except ProtocolError:
        return
    assert encode_grip_report(report) == data


@given(grip_reports, st.integers(0, 8 * GRIP_LAYOUT.size - 1))
def test_every_single_bit_error_in_a_grip_report_is_caught(report, bit):
    data = bytearray(encode_grip_report(report))
    data[bit // 8] ^= 1 << (bit % 8)
    with pytest.raises(ProtocolError):
        decode_grip_report(bytes(data))


@given(st.binary(min_size=0, max_size=24))
def test_random_bytes_decode_or_raise_protocol_error(data):
    for decode in (decode_output_report, decode_feature_report, decode_input_report,
                   decode_grip_report):
        with contextlib.suppress(ProtocolError):
            decode(data)
