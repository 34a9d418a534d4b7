"""Audit of the operator loop's hold on its device (:mod:`haptics.operator_device`): a failed read never
reports the last reading's presses again, and the first reconnection is tried at once whatever the
clock reads (on the fake device and clock of support.operator_fakes)."""

from __future__ import annotations

import pytest
from support.operator_fakes import Clock, FakeDevice

from haptics.errors import InputDeviceError
from haptics.inputs.base import OperatorInput
from haptics.operator_device import DeviceReader


class _Failing(FakeDevice):
    """Every read fails; ``unplugs`` says whether the failure leaves it disconnected."""

    def __init__(self, clock: Clock, *, unplugs: bool):
        super().__init__(clock)
        self.unplugs = unplugs

    def read(self, *, timeout_s: float) -> OperatorInput:
        if self.connected and self.unplugs:
            self.connected = self.plugged = False
        if not self.connected:
            return super().read(timeout_s=timeout_s)
        raise InputDeviceError("grip report: bad crc")


def _reader(device: FakeDevice, clock: Clock) -> DeviceReader:
    return DeviceReader(device, clock, act=lambda _: None, trouble=lambda _: None, resolved=lambda _: None)


@pytest.mark.parametrize("unplugs", [False, True])
def test_a_failed_read_does_not_report_the_last_readings_presses_again(unplugs):
    clock = Clock()
    device = _Failing(clock, unplugs=unplugs)
    last = OperatorInput(t_s=clock(), grip=0.3, enable=True, buttons=frozenset({"grasp"}))
    reading, _ = _reader(device, clock).read(last)
    assert reading.buttons == frozenset() and reading.enable is False and reading.grip == 0.3


def test_the_first_reconnection_is_tried_at_once_on_a_clock_near_zero():
    clock = Clock()
    clock.t = 0.25  # time.monotonic() soon after boot
    device = FakeDevice(clock)
    device.connected = False
    reading, gap = _reader(device, clock).read(None)
    assert device.connects == 1 and device.connected
    assert gap and reading is not None
