"""The display contract, run over every backend: sim, HID through a fake hid module, real HID.

The simulated and fake-HID displays run in protocol versions 2 and 1: a version-1
display renders through the same code path, and only a version-2 one serves a grip.
"""

from __future__ import annotations

import math

import pytest
from support.threads import close_during_read

from haptics.devices import Reconnector
from haptics.errors import DisplayError, DisplayNotConnectedError, ProtocolError
from haptics.protocol import (
    PROTOCOL_VERSIONS,
    DeviceStatus,
    StiffnessCommand,
    decode_output_report,
    encode_input_report,
    encode_output_report,
)
from haptics.protocol_grip import GripReport, encode_grip_report


def status_for(display, sequence: int, *, timeout_s: float = 0.5) -> DeviceStatus:
    """The first status echoing ``sequence`` (a real display may have older ones queued)."""
    for _ in range(64):
        status = display.read_status(timeout_s=timeout_s)
        assert status is not None, f"no status report echoing sequence {sequence}"
        if status.sequence == sequence:
            return status
    raise AssertionError(f"no status report echoing sequence {sequence}")


def test_use_before_connect_is_refused(rig):
    display = rig.display
    assert not display.connected
    with pytest.raises(DisplayNotConnectedError, match="connect"):
        display.write_command(StiffnessCommand(level=1))
    with pytest.raises(DisplayNotConnectedError):
        display.read_status()
    with pytest.raises(DisplayNotConnectedError):
        display.configure(watchdog_ms=100)


def test_not_connected_says_whether_never_connected_closed_or_unplugged(rig):
    display = rig.display
    display.close()  # closing a display that is not connected leaves the reason as it was
    with pytest.raises(DisplayNotConnectedError, match=r"read_status\(\) .*never connected"):
        display.read_status()
    display.connect()
    display.close()
    with pytest.raises(DisplayNotConnectedError, match=r"write_command\(\) .*was closed"):
        display.write_command(StiffnessCommand(level=1))
    unplug = rig.need("unplug")
    display.connect()
    unplug()
    with pytest.raises(DisplayError):
        display.write_command(StiffnessCommand(level=1))
    with pytest.raises(DisplayNotConnectedError, match=r"read_status\(\) .*failed .*reconnect\(\)"):
        display.read_status()
    display.close()  # as a Reconnector's after a failed attempt
    with pytest.raises(DisplayNotConnectedError, match=r"read_status\(\) .*failed .*reconnect\(\)"):
        display.read_status()


def test_connect_reads_device_info_and_is_idempotent(rig):
    info = rig.display.connect()
    assert rig.display.connected
    assert info.protocol_version in PROTOCOL_VERSIONS
    if rig.version is not None:
        assert info.protocol_version == rig.version
    assert rig.display.protocol_version == info.protocol_version
    assert rig.display.has_grip == (info.protocol_version >= 2)
    assert info.level_max >= 1
    assert rig.display.connect() is info
    assert rig.display.info is info


def test_context_manager_connects_and_closes(rig):
    with rig.display as display:
        assert display.connected
        display.write_command(StiffnessCommand(level=1))
    assert not rig.display.connected
    with pytest.raises(DisplayNotConnectedError):
        rig.display.write_command(StiffnessCommand(level=1))
    rig.display.close()  # a second close is harmless


def test_writes_are_encoded_with_consecutive_sequence_numbers(rig):
    display = rig.display
    level_max = display.connect().level_max
    commands = [
        StiffnessCommand(level=level_max // 3, uncertainty=17, provisional=True),
        StiffnessCommand(level=level_max, rigid=True),
        StiffnessCommand(level=0, uncertainty=106, unknown=True),
    ]
    reports = [display.write_command(command) for command in commands]
    decoded = [decode_output_report(report, version=display.info.protocol_version)
               for report in reports]
    # The OUTPUT report speaks the display's own version: 0x11 to a version-1 display.
    assert {report[1] for report in reports} == {display.info.protocol_version << 4 | 1}
    assert [d.command for d in decoded] == commands
    first = decoded[0].sequence
    assert [d.sequence for d in decoded] == [(first + i) % 256 for i in range(3)]
    assert display.last_command == commands[-1]
    assert display.reports_written == 3
    if rig.received is not None:
        assert rig.received()[-3:] == reports  # byte for byte as the device got them


def test_status_echoes_the_last_command(rig):
    display = rig.display
    level_max = display.connect().level_max
    report = display.write_command(StiffnessCommand(level=level_max // 2))
    status = status_for(display, decode_output_report(report).sequence)
    assert status.state == "rendering"
    assert status.level == level_max // 2
    assert not status.faults


def test_sequence_wraps_after_255(rig):
    display = rig.display
    display.connect()
    sequences = [decode_output_report(display.write_command(StiffnessCommand(level=1))).sequence
                 for _ in range(258)]
    assert sequences[256] == sequences[0]
    assert all((b - a) % 256 == 1 for a, b in zip(sequences, sequences[1:], strict=False))


def test_level_above_the_display_range_is_refused_before_writing(rig):
    display = rig.display
    level_max = display.connect().level_max
    if level_max == 0xFFFF:
        pytest.skip("this display uses the whole 16-bit range")
    before = len(rig.received()) if rig.received else None
    with pytest.raises(ProtocolError, match="level_max"):
        display.write_command(StiffnessCommand(level=level_max + 1))
    assert display.connected
    if rig.received:
        assert len(rig.received()) == before


def test_configure_sets_the_watchdog(rig):
    display = rig.display
    original = display.connect().watchdog_ms
    try:
        assert display.configure(watchdog_ms=250).watchdog_ms == 250
        assert display.info.watchdog_ms == 250
    finally:
        display.configure(watchdog_ms=original)


def test_read_status_returns_none_when_nothing_arrives(rig):
    firmware = rig.need("firmware")
    rig.display.connect()
    while firmware.next_input_report() is not None:
        pass
    assert rig.display.read_status(timeout_s=0.01) is None


def test_close_from_another_thread_ends_a_pending_read_at_once(rig):
    firmware = rig.need("firmware")
    display = rig.display
    display.connect()
    while firmware.next_input_report() is not None:
        pass
    ended = close_during_read(lambda: display.read_status(timeout_s=3.0), display.close, errors=DisplayError)
    assert ended.close_s < 1.0 and ended.ended_s < 1.0
    assert ended.outcome is None or isinstance(ended.outcome, DisplayNotConnectedError), ended.outcome
    assert not display.connected


def test_a_huge_timeout_is_taken_and_a_bool_one_refused(rig):
    display = rig.display
    display.connect()
    report = display.write_command(StiffnessCommand(level=2))
    # A report is there: the read returns it however long it was allowed to wait.
    assert status_for(display, decode_output_report(report).sequence, timeout_s=3e6).level == 2
    for read in (display.read_status, display.read_operator):
        with pytest.raises(DisplayError, match="timeout_s = True"):
            read(timeout_s=True)
    assert display.connected


@pytest.mark.parametrize("timeout_s", [math.inf, math.nan])
def test_a_non_finite_timeout_is_refused(timeout_s):
    # An infinite timeout would keep a HID read slicing for ever, the renderer's loop with it; NaN is no
    # number of seconds. On the simulated display, whose reads never wait: were it taken, the read ends.
    from haptics.devices.sim import SimulatedDisplay

    display = SimulatedDisplay()
    display.connect()
    for read in (display.read_status, display.read_operator):
        with pytest.raises(DisplayError, match=f"timeout_s = {timeout_s!r}: expected a number >= 0"):
            read(timeout_s=timeout_s)
    assert display.connected


def test_a_garbled_status_report_is_a_protocol_error_and_the_link_stays(rig):
    firmware = rig.need("firmware")
    display = rig.display
    display.connect()
    garbled = bytearray(firmware.status_report())
    garbled[2] ^= 0x40
    firmware.queue_input_report(bytes(garbled))
    with pytest.raises(ProtocolError, match="crc"):
        display.read_status()
    assert display.connected


def test_a_status_level_above_level_max_is_refused_naming_the_report_and_field(rig):
    firmware = rig.need("firmware")
    display = rig.display
    level_max = display.connect().level_max
    firmware.queue_input_report(encode_input_report(DeviceStatus("rendering", level_max + 1, frozenset(), 0)))
    firmware.queue_input_report(encode_input_report(DeviceStatus("rendering", level_max, frozenset(), 0)))
    with pytest.raises(ProtocolError, match=rf"input report 0x03: level = {level_max + 1}, expected 0-{level_max}"):
        display.read_status(timeout_s=0.5)
    assert display.connected
    assert display.read_status(timeout_s=0.5).level == level_max  # the next one is taken


def test_faults_are_reported(rig):
    firmware = rig.need("firmware")
    display = rig.display
    display.connect()
    firmware.inject_fault("over_temperature")
    report = display.write_command(StiffnessCommand(level=5))
    status = status_for(display, decode_output_report(report).sequence)
    assert status.state == "fault"
    assert status.faults == {"over_temperature"}
    assert status.level == 0


def test_a_malformed_output_report_is_flagged_by_the_device(rig):
    firmware = rig.need("firmware")
    display = rig.display
    display.connect()
    display.write_command(StiffnessCommand(level=9))
    bad = bytearray(encode_output_report(StiffnessCommand(level=3), sequence=200))
    bad[-1] ^= 0xFF
    display._write_report(bytes(bad))  # bytes the encoder would never make
    statuses = []
    while (status := display.read_status()) is not None:
        statuses.append(status)
    assert "bad_report" in statuses[-1].faults
    assert firmware.last_command == StiffnessCommand(level=9)


def test_unplug_disconnects_and_reconnect_resends_the_last_command(rig):
    unplug, replug = rig.need("unplug"), rig.need("replug")
    display = rig.display
    level_max = display.connect().level_max
    display.write_command(StiffnessCommand(level=level_max // 4))
    last = StiffnessCommand(level=level_max, uncertainty=9, stale=True)  # the top of the range is resent too
    unplug()
    with pytest.raises(DisplayError) as raised:
        display.write_command(last)
    assert not isinstance(raised.value, DisplayNotConnectedError)
    assert not display.connected
    with pytest.raises(DisplayNotConnectedError):
        display.write_command(last)
    with pytest.raises(DisplayError):
        display.reconnect()  # still unplugged
    replug()
    assert rig.firmware.last_command is None  # power-on reset: the display forgot
    display.reconnect()
    assert display.connected
    assert rig.firmware.last_command == last
    assert decode_output_report(rig.received()[-1]).command == last


def test_a_status_set_aside_before_a_reconnect_is_not_read_after_it(rig):
    # A status a version-2 display sent before it was unplugged (here: a fault) is not the state of the
    # display that came back (power-on reset: no fault).
    firmware = rig.need("firmware")
    if firmware.info.protocol_version < 2:
        pytest.skip("only a version-2 display has reports set aside")
    unplug, replug = rig.need("unplug"), rig.need("replug")
    display = rig.display
    display.connect()
    firmware.inject_fault("over_temperature")
    display.write_command(StiffnessCommand(level=5))  # a status with the fault is queued ...
    firmware.set_grip(0.5)
    assert display.read_operator(timeout_s=0.5) is not None  # ... and set aside on the way to the grip
    unplug()
    with pytest.raises(DisplayError):
        display.write_command(StiffnessCommand(level=6))
    replug()
    display.reconnect()  # resends level 6: the display answers with one status
    statuses = []
    while (status := display.read_status(timeout_s=0.05)) is not None:
        statuses.append(status)
    assert [(s.level, s.faults) for s in statuses] == [(6, frozenset())]


def test_reconnector_backs_off_then_resends(rig):
    unplug, replug = rig.need("unplug"), rig.need("replug")
    display = rig.display
    display.connect()
    command = StiffnessCommand(level=7, provisional=True)
    display.write_command(command)
    unplug()
    reconnector = Reconnector(display, initial_s=0.05, max_s=0.1)
    with pytest.raises(DisplayError):
        display.write_command(command)
    assert not reconnector.poll(0.0)  # attempt 1 fails: next at 0.05
    assert (reconnector.failures, reconnector.next_attempt_s) == (1, 0.05)
    assert not reconnector.poll(0.04)  # too early: no attempt
    assert reconnector.failures == 1
    assert not reconnector.poll(0.05)  # attempt 2 fails: next at 0.15
    assert reconnector.next_attempt_s == pytest.approx(0.15)
    assert not reconnector.poll(0.16)  # attempt 3 fails: the wait is capped at max_s
    assert (reconnector.failures, reconnector.next_attempt_s) == (3, pytest.approx(0.26))
    replug()
    assert not reconnector.poll(0.2)
    assert reconnector.poll(0.26)
    assert reconnector.failures == 0
    assert rig.firmware.last_command == command


# --------------------------------------------------------------------------- the grip (version 2)


def need_grip(rig):
    firmware = rig.need("firmware")
    if firmware.info.protocol_version < 2:
        pytest.skip("a version-1 display has no grip")
    return firmware


def test_a_version_1_display_has_no_grip_and_still_renders(rig):
    firmware = rig.need("firmware")
    if firmware.info.protocol_version != 1:
        pytest.skip("about version-1 displays")
    display = rig.display
    display.connect()
    assert not display.has_grip
    assert display.read_operator(timeout_s=0.01) is None
    report = display.write_command(StiffnessCommand(level=300, uncertainty=4))
    assert report == bytes.fromhex("01 11 00 2c 01 04 00") + report[-1:]  # byte for byte as ever
    assert firmware.last_command == StiffnessCommand(level=300, uncertainty=4)
    assert display.read_operator(timeout_s=0.0) is None
    assert status_for(display, 0).level == 300  # the status stays for read_status
    with pytest.raises(ProtocolError):
        firmware.set_grip(0.5)  # its firmware has no grip to send


def test_a_grip_report_from_a_version_1_display_is_refused_as_a_foreign_report(rig):
    firmware = rig.need("firmware")
    if firmware.info.protocol_version != 1:
        pytest.skip("about version-1 displays")
    rig.display.connect()
    firmware.queue_input_report(encode_grip_report(GripReport(0.5, None, True, frozenset(), 0)))
    with pytest.raises(ProtocolError, match=r"input report 0x03 \(status\): report_id = 0x04, "
                                            "expected 0x03"):
        rig.display.read_status()
    assert rig.display.connected


def test_an_empty_input_report_is_no_report(rig):
    firmware = rig.need("firmware")
    display = rig.display
    display.connect()
    firmware.queue_input_report(b"")
    assert display.read_status(timeout_s=0.01) is None
    assert display.read_operator(timeout_s=0.01) is None
    assert display.connected


def test_the_grip_arrives_as_the_device_sent_it(rig):
    firmware = need_grip(rig)
    display = rig.display
    display.connect()
    assert display.has_grip
    firmware.set_grip(0.25, force_n=12.5, enable=True, buttons={"grasp"})
    report = display.read_operator(timeout_s=0.5)
    assert report == GripReport(0.25, 12.5, True, frozenset({"grasp"}), 0)
    assert display.read_operator(timeout_s=0.01) is None  # nothing new
    firmware.set_grip(0.5, force_n=None, enable=False)
    assert display.read_operator(timeout_s=0.5) == GripReport(0.5, None, False, frozenset(), 1)


def test_read_operator_returns_the_newest_grip_and_every_press(rig):
    firmware = need_grip(rig)
    display = rig.display
    display.connect()
    firmware.set_grip(0.1, buttons={"release"})
    firmware.set_grip(0.2)
    firmware.set_grip(0.3, force_n=4.0, buttons={"next"})
    firmware.set_grip(0.4, force_n=5.0)
    report = display.read_operator(timeout_s=0.5)
    assert report == GripReport(0.4, 5.0, True, frozenset({"release", "next"}), 3)


def test_read_operator_reports_returns_every_grip_report_oldest_first(rig):
    firmware = need_grip(rig)
    display = rig.display
    display.connect()
    firmware.set_grip(0.1, buttons={"grasp"})
    firmware.set_grip(0.2)  # grasp let go ...
    firmware.set_grip(0.3, buttons={"grasp"})  # ... and pressed again: two presses
    reports = display.read_operator_reports(timeout_s=0.5)
    assert [(r.grip, r.buttons, r.sequence) for r in reports] == [
        (0.1, {"grasp"}, 0), (0.2, frozenset(), 1), (0.3, {"grasp"}, 2)]
    assert display.read_operator_reports(timeout_s=0.01) == ()


def test_status_and_grip_reports_interleave_and_each_reader_gets_its_own(rig):
    firmware = need_grip(rig)
    display = rig.display
    display.connect()
    firmware.set_grip(0.6, force_n=2.0)
    first = display.write_command(StiffnessCommand(level=40))
    firmware.set_grip(0.7, force_n=3.0, buttons={"stop"})
    second = display.write_command(StiffnessCommand(level=41))
    # read_status skips (and keeps) the grip reports; read_operator skips (and keeps) statuses.
    assert status_for(display, decode_output_report(first).sequence).level == 40
    assert display.read_operator(timeout_s=0.5) == GripReport(0.7, 3.0, True,
                                                              frozenset({"stop"}), 1)
    assert status_for(display, decode_output_report(second).sequence).level == 41
    assert display.read_status(timeout_s=0.01) is None
    assert display.read_operator(timeout_s=0.01) is None


def test_a_garbled_grip_report_is_refused_by_read_operator_and_named(rig):
    firmware = need_grip(rig)
    display = rig.display
    display.connect()
    good = firmware.set_grip(0.5)
    garbled = bytearray(good)
    garbled[3] ^= 0x01
    firmware.queue_input_report(bytes(garbled))
    firmware.set_grip(0.75)
    # The good report before it comes first; the bad one is refused by the next call ...
    assert display.read_operator(timeout_s=0.5).grip == 0.5
    with pytest.raises(ProtocolError, match=r"input report 0x04 \(grip\): crc"):
        display.read_operator(timeout_s=0.5)
    assert display.connected
    # ... and the one after it is not lost.
    assert display.read_operator(timeout_s=0.5).grip == 0.75


def test_read_operator_checks_its_timeout_and_the_connection(rig):
    display = rig.display
    with pytest.raises(DisplayNotConnectedError, match="read_operator"):
        display.read_operator(timeout_s=0.0)
    display.connect()
    with pytest.raises(DisplayError, match="timeout_s = -1"):
        display.read_operator(timeout_s=-1)


def test_the_grip_comes_back_after_a_replug(rig):
    firmware = need_grip(rig)
    unplug, replug = rig.need("unplug"), rig.need("replug")
    display = rig.display
    display.connect()
    firmware.set_grip(0.3)
    unplug()
    with pytest.raises(DisplayError):
        display.read_operator(timeout_s=0.0)
    assert not display.connected
    replug()
    display.reconnect()
    firmware.set_grip(0.9, force_n=1.5)
    assert display.read_operator(timeout_s=0.5) == GripReport(0.9, 1.5, True, frozenset(), 0)


def test_a_simulated_displays_log_keeps_only_the_newest_reports():
    from haptics.devices.sim import LOG_REPORTS, SimulatedDisplay

    display = SimulatedDisplay()
    display.connect()
    for level in range(LOG_REPORTS + 5):
        display.write_command(StiffnessCommand(level=level % 100))
    assert len(display.log) == LOG_REPORTS and display.log[-1][0] == "output"
