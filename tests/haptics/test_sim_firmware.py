"""The firmware model behind the simulated display and the fake ``hid`` module answers as
haptics/PROTOCOL.md says a display does."""

from __future__ import annotations

import pytest

from haptics.devices.sim import DisplayFirmware
from haptics.errors import ProtocolError
from haptics.protocol import (
    DisplayInfo,
    StiffnessCommand,
    decode_input_report,
    encode_output_report,
)
from haptics.protocol_grip import decode_grip_report


def statuses(firmware: DisplayFirmware) -> list:
    """Every status report queued, decoded, oldest first."""
    out = []
    while (report := firmware.next_input_report()) is not None:
        out.append(decode_input_report(report))
    return out


def test_a_malformed_report_is_flagged_once_and_the_last_good_command_stays_rendered():
    # Fault bit 4 is "malformed report received since the last status": in the next status only. The
    # refused report is not rendered, and it does not disable the actuator.
    firmware = DisplayFirmware()
    firmware.receive_output(encode_output_report(StiffnessCommand(level=9), sequence=0))
    bad = bytearray(encode_output_report(StiffnessCommand(level=3), sequence=1))
    bad[-1] ^= 0xFF
    firmware.receive_output(bytes(bad))
    firmware.receive_output(encode_output_report(StiffnessCommand(level=9), sequence=2))
    first, flagged, after = statuses(firmware)
    assert (first.state, first.level, first.faults) == ("rendering", 9, frozenset())
    assert (flagged.state, flagged.level, flagged.faults, flagged.sequence) == ("rendering", 9, {"bad_report"}, 0)
    assert not after.faults and after.sequence == 2
    assert firmware.bad_reports == 1


def test_a_level_above_level_max_is_refused_as_malformed():
    firmware = DisplayFirmware()
    firmware.receive_output(encode_output_report(StiffnessCommand(level=firmware.info.level_max + 1), sequence=0))
    assert firmware.last_command is None and firmware.bad_reports == 1
    assert "bad_report" in statuses(firmware)[-1].faults


def test_a_rigid_command_at_level_0_is_rendering():
    firmware = DisplayFirmware()
    firmware.receive_output(encode_output_report(StiffnessCommand(level=0, rigid=True), sequence=0))
    assert firmware.state == "rendering"
    assert statuses(firmware)[-1].state == "rendering"


def test_the_grip_counter_wraps_from_255_to_0():
    firmware = DisplayFirmware()
    reports = [firmware.set_grip(0.5) for _ in range(257)]
    assert [decode_grip_report(r).sequence for r in reports[254:]] == [254, 255, 0]


def test_a_protocol_version_that_disagrees_with_the_info_is_refused():
    info = DisplayInfo(level_max=4095, firmware_version=(1, 0), watchdog_ms=1000, min_stiffness_n_per_m=0,
                       max_stiffness_n_per_m=5000, protocol_version=1)
    with pytest.raises(ProtocolError, match="protocol_version = 2 disagrees with info.protocol_version = 1"):
        DisplayFirmware(info, protocol_version=2)
    assert DisplayFirmware(info, protocol_version=1).info.protocol_version == 1
