"""The HID backend's own behaviour (discovery, vendor errors) and the backend name table."""

from __future__ import annotations

import subprocess
import sys
import types
from pathlib import Path

import pytest
from support.contract import assert_every_backend_covered

from haptics.devices import BACKENDS, display_class, make_display
from haptics.devices.sim import DisplayFirmware, SimulatedDisplay
from haptics.errors import (
    DisplayBackendNotFoundError,
    DisplayError,
    DisplayNotConnectedError,
    ProtocolError,
)
from haptics.protocol import StiffnessCommand, crc8, encode_output_report
from haptics.protocol_grip import GripReport
from haptics.settings import DisplaySettings

REPO = Path(__file__).resolve().parents[2]
#: More fake reads than any test here makes: beyond them the display's read loop would never end.
MAX_FAKE_READS = 100


def hid_display(**options):
    from haptics.devices.hid import HidDisplay

    return HidDisplay.from_settings(DisplaySettings(), **options)


@pytest.fixture
def read_clock(fake_hid, monkeypatch):
    """The display's clock advances by exactly each fake read's timeout, not by the wall clock.

    The display cuts a read timeout into slices from its clock; on the wall clock a fake read
    descheduled on a loaded machine overshoots its slice, and the slices no longer add up. Reads
    that do not move the clock (timeouts of 0 ms) would never end a wait: after
    :data:`MAX_FAKE_READS` reads the fake fails the test.
    """
    import haptics.devices.base as base

    FakeHidDevice = type(fake_hid.device())  # noqa: N806 (the conftest's class)
    now = [1000.0]
    reads = [0]
    monkeypatch.setattr(base, "time", types.SimpleNamespace(monotonic=lambda: now[0]))
    real_read = FakeHidDevice.read

    def read(self, max_length, timeout_ms=0):
        reads[0] += 1
        assert reads[0] <= MAX_FAKE_READS, f"{reads[0]} reads: the display's clock stopped at {now[0]} s"
        try:
            return real_read(self, max_length, timeout_ms)
        finally:
            now[0] += timeout_ms / 1000

    monkeypatch.setattr(FakeHidDevice, "read", read)
    return fake_hid


def test_every_backend_in_the_table_runs_the_contract_suite(rig_backends):
    assert_every_backend_covered("display", BACKENDS, rig_backends, fixture="rig", where="tests/haptics/conftest.py")


def test_the_table_opens_sim_and_hid():
    assert display_class("sim") is SimulatedDisplay
    assert display_class("hid").__name__ == "HidDisplay"
    assert isinstance(make_display(DisplaySettings(backend="sim")), SimulatedDisplay)


def test_an_unknown_backend_lists_the_known_ones():
    with pytest.raises(DisplayBackendNotFoundError, match="'usb'.*hid, sim"):
        display_class("usb")


def test_backends_are_imported_on_use():
    code = (
        "import sys, haptics.devices; "
        "assert 'haptics.devices.hid' not in sys.modules and 'hid' not in sys.modules; "
        "haptics.devices.display_class('sim'); assert 'haptics.devices.hid' not in sys.modules"
    )
    subprocess.run([sys.executable, "-c", code], cwd=REPO, check=True)


def test_missing_hidapi_is_a_missing_backend(monkeypatch):
    monkeypatch.setitem(sys.modules, "hid", None)  # makes `import hid` raise ImportError
    with pytest.raises(DisplayBackendNotFoundError, match="pip install hidapi") as raised:
        hid_display()
    assert isinstance(raised.value.__cause__, ImportError)


def test_nothing_plugged_in_says_so(fake_hid):
    display = hid_display()
    with pytest.raises(DisplayError, match="no HID display 1209:5EF7 is plugged in"):
        display.connect()
    assert not display.connected


def test_writes_reach_hidapi_byte_for_byte(fake_hid):
    usb = fake_hid.plug()
    command = StiffnessCommand(level=1000, uncertainty=12, provisional=True)
    with hid_display() as display:
        assert display.path == b"/dev/hidraw0"
        display.write_command(command)
        display.write_command(command)
    assert usb.writes == [
        encode_output_report(command, sequence=0),
        encode_output_report(command, sequence=1),
    ]


def test_read_timeout_is_passed_in_milliseconds_in_short_slices(read_clock):
    usb = read_clock.plug()
    with hid_display() as display:
        display.read_status(timeout_s=0.25)
        display.read_status()
    *waited, polled = usb.read_timeouts_ms
    assert all(0 <= ms <= 50 for ms in waited) and sum(waited) == 250
    assert polled == 0


def test_open_failure_wraps_the_vendor_error(fake_hid):
    fake_hid.plug(refuse_open=True)
    display = hid_display()
    with pytest.raises(DisplayError, match="cannot open .*udev") as raised:
        display.connect()
    assert isinstance(raised.value.__cause__, OSError)
    assert not display.connected


def test_an_unplug_wraps_oserror_and_disconnects(fake_hid):
    usb = fake_hid.plug()
    display = hid_display()
    display.connect()
    fake_hid.unplug(usb)
    with pytest.raises(DisplayError, match="write failed") as raised:
        display.write_command(StiffnessCommand(level=3))
    assert isinstance(raised.value.__cause__, OSError)
    assert not display.connected
    with pytest.raises(DisplayNotConnectedError):
        display.read_status()


@pytest.mark.parametrize("written", [-1, 4])  # hidapi's error return, or part of the report
def test_a_short_write_is_a_failure(fake_hid, written):
    usb = fake_hid.plug()
    display = hid_display()
    display.connect()
    usb.write_result = written
    with pytest.raises(DisplayError, match=f"wrote {written} of 8 bytes"):
        display.write_command(StiffnessCommand(level=3))
    assert not display.connected


def test_a_short_feature_write_is_a_failure_that_disconnects(fake_hid):
    usb = fake_hid.plug()
    display = hid_display()
    display.connect()
    usb.feature_write_result = 3
    with pytest.raises(DisplayError, match="feature report wrote 3 of 17 bytes"):
        display.configure(watchdog_ms=250)
    assert not display.connected


def test_an_unplugged_displays_handle_is_released_once_the_link_fails(fake_hid):
    usb = fake_hid.plug()
    display = hid_display()
    display.connect()
    fake_hid.unplug(usb)
    with pytest.raises(DisplayError):
        display.write_command(StiffnessCommand(level=3))
    assert fake_hid.closed == fake_hid.opened  # released at the failure ...
    fake_hid.plug(usb)
    display.reconnect()
    display.close()
    assert fake_hid.closed == fake_hid.opened and len(fake_hid.opened) == 2  # ... and every handle once


def test_a_handle_that_fails_to_close_after_an_unplug_still_gives_a_display_error(fake_hid, monkeypatch):
    # The handle of an unplugged device may raise on close: the caller (the Reconnector, the renderer)
    # still sees the DisplayError of the failed write, and close() raises nothing.
    def close(self):
        raise OSError("handle already gone")

    monkeypatch.setattr(type(fake_hid.device()), "close", close)
    usb = fake_hid.plug()
    display = hid_display()
    display.connect()
    fake_hid.unplug(usb)
    with pytest.raises(DisplayError, match="write failed"):
        display.write_command(StiffnessCommand(level=3))
    display.close()
    fake_hid.plug(usb)
    display.reconnect()
    display.close()


def test_replug_under_a_new_path_is_found_again(fake_hid):
    usb = fake_hid.plug()
    display = hid_display()
    display.connect()
    display.write_command(StiffnessCommand(level=77))
    fake_hid.unplug(usb)
    fake_hid.plug(usb)
    with pytest.raises(DisplayError):
        display.write_command(StiffnessCommand(level=78))
    display.reconnect()
    assert display.path == b"/dev/hidraw1"
    assert usb.firmware.last_command == StiffnessCommand(level=78)


def test_serial_picks_one_of_several_displays(fake_hid):
    fake_hid.plug(serial="A")
    second = fake_hid.plug(serial="B")
    with hid_display(serial="B") as display:
        display.write_command(StiffnessCommand(level=5))
    assert second.firmware.last_command == StiffnessCommand(level=5)
    with pytest.raises(DisplayError, match="serial 'C'"):
        hid_display(serial="C").connect()


def test_interfaces_of_another_usage_page_are_skipped(fake_hid):
    from haptics.devices.hid import list_hid_displays

    fake_hid.plug(usage_page=0x0001)  # e.g. a keyboard interface of the same device
    assert list_hid_displays(0x1209, 0x5EF7) == []
    fake_hid.plug(usage_page=0)  # platform does not report usage pages
    assert len(list_hid_displays(0x1209, 0x5EF7)) == 1


def test_a_display_speaking_another_protocol_is_refused_and_its_handle_released(fake_hid, monkeypatch):
    usb = fake_hid.plug()
    report = bytearray(usb.firmware.feature_report())
    report[1] = 3  # protocol version 3
    report[-1] = crc8(bytes(report[:-1]))
    monkeypatch.setattr(usb.firmware, "feature_report", lambda: bytes(report))
    display = hid_display()
    for _ in range(3):  # as a Reconnector retries: no handle may pile up
        with pytest.raises(DisplayError, match="protocol_version = 3: this host speaks versions 1 and 2") as raised:
            display.connect()
        assert not display.connected
        assert raised.value.__cause__ is not None
    assert len(fake_hid.opened) == 3 and fake_hid.closed == fake_hid.opened


def test_a_handle_that_cannot_be_made_non_blocking_is_released(fake_hid, monkeypatch):
    fake_hid.plug()

    def refuse(self, value):
        raise OSError("set_nonblocking failed")

    monkeypatch.setattr(type(fake_hid.device()), "set_nonblocking", refuse)
    display = hid_display()
    with pytest.raises(DisplayError, match="cannot open .*set_nonblocking failed"):
        display.connect()
    assert len(fake_hid.opened) == 1 and fake_hid.closed == fake_hid.opened


def test_a_version_1_display_gets_the_bytes_it_always_got(fake_hid):
    usb = fake_hid.plug(firmware=DisplayFirmware(protocol_version=1))
    with hid_display() as display:
        assert display.info.protocol_version == 1 and not display.has_grip
        display.write_command(StiffnessCommand(level=0x0123, uncertainty=42, rigid=True, stale=True))
        assert display.read_operator(timeout_s=0.5) is None
    assert usb.writes == [bytes.fromhex("01 11 05 23 01 2a 00 36")]
    assert usb.read_timeouts_ms == []  # read_operator never touched the device


def test_a_version_2_display_speaks_version_2(fake_hid):
    usb = fake_hid.plug()
    with hid_display() as display:
        assert display.info.protocol_version == 2 and display.has_grip
        display.write_command(StiffnessCommand(level=0x0123, uncertainty=42, rigid=True, stale=True))
    assert usb.writes == [bytes.fromhex("01 21 05 23 01 2a 00 93")]


def test_the_grip_is_read_from_hidapi_with_the_timeout_then_drained(read_clock):
    usb = read_clock.plug()
    with hid_display() as display:
        assert display.read_operator(timeout_s=0.25) is None
        waited = list(usb.read_timeouts_ms)
        usb.firmware.set_grip(0.5, force_n=2.0)
        assert display.read_operator(timeout_s=0.25) == GripReport(0.5, 2.0, True, frozenset(), 0)
    # Nothing there: 250 ms in slices. A report there: it, then a poll that finds nothing more.
    assert all(0 <= ms <= 50 for ms in waited) and sum(waited) == 250
    assert usb.read_timeouts_ms[len(waited):] == [50, 0]


def test_a_simulated_display_speaks_the_version_it_is_given():
    assert SimulatedDisplay().connect().protocol_version == 2
    assert SimulatedDisplay(protocol_version=1).connect().protocol_version == 1
    firmware = DisplayFirmware(protocol_version=1)
    assert SimulatedDisplay(firmware=firmware).connect().protocol_version == 1
    with pytest.raises(ProtocolError, match="disagrees"):
        SimulatedDisplay(firmware=firmware, protocol_version=2)
