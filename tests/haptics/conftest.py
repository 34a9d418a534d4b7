"""Fixtures of the haptics tests: a fake ``hid`` module and one rig per display backend.

This kernel has no uhid, so the HID backend is tested through a fake ``hid``
module injected into ``sys.modules``: its devices record every write byte for
byte, answer through the same firmware model as the simulated display, raise
OSError once unplugged and come back under a new hidraw path when replugged;
the bus keeps every handle opened and every close.
The simulated and the fake-HID displays each run twice, speaking protocol
version 2 (the default, with a grip) and version 1 (a display from before the
grip report). A real display joins the contract suite when COMPLIANCE_TELEOP_HID=1.
"""

from __future__ import annotations

import os
import sys
import time
import types
from collections.abc import Callable
from dataclasses import dataclass, field

import pytest
from support.contract import param_names

from haptics.devices.base import SoftnessDisplay
from haptics.devices.sim import DisplayFirmware, SimulatedDisplay
from haptics.protocol import USAGE_PAGE
from haptics.settings import DisplaySettings, display_settings
from teleop.settings import load_settings

#: hidapi's read() takes its timeout as a C int.
C_INT_MAX = 2**31 - 1


@dataclass
class FakeUsbDisplay:
    """One display on the fake USB bus, with everything that reached it."""

    firmware: DisplayFirmware = field(default_factory=DisplayFirmware)
    vendor_id: int = 0x1209
    product_id: int = 0x5EF7
    serial: str = "SD-0001"
    usage_page: int = USAGE_PAGE
    path: bytes | None = None
    writes: list[bytes] = field(default_factory=list)
    feature_writes: list[bytes] = field(default_factory=list)
    read_timeouts_ms: list[int] = field(default_factory=list)
    #: When set, write() returns this instead of the byte count (hidapi's -1 on error).
    write_result: int | None = None
    #: When set, send_feature_report() returns this instead of the byte count.
    feature_write_result: int | None = None
    #: open_path() fails as it does without permission on the hidraw node.
    refuse_open: bool = False


class FakeHidDevice:
    """Stands in for ``hid.device``: same methods, same types (lists of ints), same errors."""

    def __init__(self, bus: FakeHidBus) -> None:
        self._bus = bus
        self._usb: FakeUsbDisplay | None = None
        self._path: bytes | None = None
        self._blocking = True  # as hidapi opens a handle

    def _live(self) -> FakeUsbDisplay:
        if self._usb is None:
            raise ValueError("not open")
        if self._bus.attached.get(self._path) is not self._usb:
            raise OSError("device disconnected")
        return self._usb

    def open_path(self, path: bytes) -> None:
        if path not in self._bus.attached or self._bus.attached[path].refuse_open:
            raise OSError("open failed")
        self._usb, self._path = self._bus.attached[path], path
        self._bus.opened.append(self)

    def set_nonblocking(self, value: int) -> int:
        self._live()
        self._blocking = not value
        return 0

    def write(self, buff) -> int:
        usb = self._live()
        data = bytes(buff)
        usb.writes.append(data)
        if usb.write_result is not None:
            return usb.write_result
        usb.firmware.receive_output(data)
        return len(data)

    def read(self, max_length: int, timeout_ms: int = 0) -> list[int]:
        """As hidapi's: waits up to ``timeout_ms`` for a report, which must fit a C int; with
        ``timeout_ms`` 0 a blocking handle would wait for ever for one (here: an AssertionError)."""
        usb = self._live()
        if abs(timeout_ms) > C_INT_MAX:
            raise OverflowError("value too large to convert to int")
        usb.read_timeouts_ms.append(timeout_ms)
        deadline = time.monotonic() + timeout_ms / 1000
        while (report := usb.firmware.next_input_report()) is None and time.monotonic() < deadline:
            time.sleep(0.002)
        if report is None and timeout_ms == 0 and self._blocking:
            raise AssertionError("read(n, 0) on a blocking hidapi handle waits for ever for a report")
        self._live()  # a handle closed under the read fails it, as hidapi's may
        return [] if report is None else list(report[:max_length])

    def get_feature_report(self, report_num: int, max_length: int) -> list[int]:
        report = self._live().firmware.feature_report()
        if report_num != report[0]:
            raise OSError(f"no feature report {report_num}")
        return list(report[:max_length])

    def send_feature_report(self, buff) -> int:
        usb = self._live()
        data = bytes(buff)
        usb.feature_writes.append(data)
        if usb.feature_write_result is not None:
            return usb.feature_write_result
        usb.firmware.receive_feature(data)
        return len(data)

    def close(self) -> None:
        self._usb = None
        self._bus.closed.append(self)


class FakeHidBus:
    """The fake USB bus behind the fake ``hid`` module."""

    def __init__(self) -> None:
        self.attached: dict[bytes, FakeUsbDisplay] = {}
        self._next_node = 0
        #: Every handle opened (open_path succeeded) and every close(), in order.
        self.opened: list[FakeHidDevice] = []
        self.closed: list[FakeHidDevice] = []

    def plug(self, usb: FakeUsbDisplay | None = None, **fields) -> FakeUsbDisplay:
        """Attach ``usb`` (or a new one with ``fields``) under a fresh hidraw path, powered up."""
        usb = usb or FakeUsbDisplay(**fields)
        usb.path = f"/dev/hidraw{self._next_node}".encode()
        self._next_node += 1
        usb.firmware.power_on_reset()
        self.attached[usb.path] = usb
        return usb

    def unplug(self, usb: FakeUsbDisplay) -> None:
        del self.attached[usb.path]
        usb.path = None

    def enumerate(self, vendor_id: int = 0, product_id: int = 0) -> list[dict]:
        return [
            {
                "path": path, "vendor_id": usb.vendor_id, "product_id": usb.product_id,
                "serial_number": usb.serial, "release_number": 0x0100,
                "manufacturer_string": "Test Haptics", "product_string": "Softness Display",
                "usage_page": usb.usage_page, "usage": 1, "interface_number": 0,
            }
            for path, usb in self.attached.items()
            if vendor_id in (0, usb.vendor_id) and product_id in (0, usb.product_id)
        ]

    def device(self) -> FakeHidDevice:
        return FakeHidDevice(self)


@pytest.fixture
def fake_hid(monkeypatch: pytest.MonkeyPatch) -> FakeHidBus:
    """A fake ``hid`` module in ``sys.modules``; returns its bus (nothing plugged in)."""
    bus = FakeHidBus()
    module = types.ModuleType("hid")
    module.enumerate = bus.enumerate
    module.device = bus.device
    monkeypatch.setitem(sys.modules, "hid", module)
    return bus


@dataclass
class Rig:
    """A display under test and, where the backend allows, a view of the device side."""

    display: SoftnessDisplay
    #: Output reports as the device received them, byte for byte (None on real hardware).
    received: Callable[[], list[bytes]] | None = None
    firmware: DisplayFirmware | None = None
    unplug: Callable[[], None] | None = None
    replug: Callable[[], None] | None = None
    #: The protocol version the device speaks (None: whatever a real display says).
    version: int | None = None

    def need(self, what: str):
        value = getattr(self, what)
        if value is None:
            pytest.skip(f"this backend cannot provide {what}")
        return value


def _sim_rig(version: int) -> Rig:
    display = SimulatedDisplay.from_settings(DisplaySettings(), protocol_version=version)
    return Rig(
        display=display,
        received=lambda: [data for kind, data in display.log if kind == "output"],
        firmware=display.firmware,
        unplug=display.unplug,
        replug=display.replug,
        version=version,
    )


def _fake_hid_rig(bus: FakeHidBus, version: int) -> Rig:
    from haptics.devices.hid import HidDisplay

    usb = bus.plug(firmware=DisplayFirmware(protocol_version=version))
    return Rig(
        display=HidDisplay.from_settings(DisplaySettings()),
        received=lambda: list(usb.writes),
        firmware=usb.firmware,
        unplug=lambda: bus.unplug(usb),
        replug=lambda: bus.plug(usb),
        version=version,
    )


def _hardware_rig() -> Rig:
    if os.environ.get("COMPLIANCE_TELEOP_HID") != "1":
        pytest.skip("set COMPLIANCE_TELEOP_HID=1 with a display plugged in to test real hardware")
    from haptics.devices.hid import HidDisplay

    return Rig(display=HidDisplay.from_settings(display_settings(load_settings())))


# The display rigs, each a backend's name, with "-v1" speaking protocol version 1 and "fake-" on a
# faked device; plain "hid" is the real display.
RIG_PARAMS = ["sim", "sim-v1", "fake-hid", "fake-hid-v1", pytest.param("hid", marks=pytest.mark.hardware)]


@pytest.fixture
def rig_backends() -> set[str]:
    """The display backends the ``rig`` fixture runs the contract suite on."""
    return {name.removeprefix("fake-").removesuffix("-v1") for name in param_names(RIG_PARAMS)}


@pytest.fixture(params=RIG_PARAMS)
def rig(request: pytest.FixtureRequest) -> Rig:
    """Every display backend in turn, the simulated ones in both protocol versions; closed after."""
    version = 1 if request.param.endswith("-v1") else 2
    if request.param.startswith("sim"):
        made = _sim_rig(version)
    elif request.param.startswith("fake-hid"):
        made = _fake_hid_rig(request.getfixturevalue("fake_hid"), version)
    else:
        made = _hardware_rig()
    yield made
    made.display.close()
