"""The operator loop's hold on its input device (:mod:`haptics.operator_device`): a failed read with the
device left disconnected is a gap, one with it still connected a ``lost`` reading without one; ``feel`` is
not passed to a device that is not connected (on a fake device and clock)."""

from __future__ import annotations

from support.operator_fakes import Clock, FakeDevice, loop_rig

from haptics.errors import InputDeviceError, InputNotConnectedError
from haptics.inputs.base import OperatorInput
from haptics.operator_device import DeviceReader
from haptics.operator_link import OperatorView


class FlakyDevice(FakeDevice):
    """Fails its next read as ``fail_next`` says: "unplug" (InputDeviceError, the device left
    disconnected) or "bad report" (InputDeviceError, still connected)."""

    def __init__(self, clock: Clock):
        super().__init__(clock)
        self.fail_next: str | None = None

    def read(self, *, timeout_s: float) -> OperatorInput:
        failure, self.fail_next = self.fail_next, None
        if failure == "unplug":
            self.connected = self.plugged = False
            raise InputDeviceError("gamepad unplugged")
        if failure is not None:
            raise InputDeviceError(failure)
        reading = super().read(timeout_s=timeout_s)
        return OperatorInput(t_s=reading.t_s, grip=reading.grip, enable=reading.enable, force_n=reading.force_n,
                             buttons=reading.buttons)


class ClosedUnderFeel(FakeDevice):
    """Says it is connected, but is closed (by another thread) as ``feel`` runs."""

    def feel(self, *, force_n: float, width_m: float, stiffness: float | None) -> None:
        self.connected = False
        raise InputNotConnectedError("feel() needs a connected device")


def _reader(device: FakeDevice, clock: Clock) -> tuple[DeviceReader, list[str]]:
    troubles: list[str] = []
    reader = DeviceReader(device, clock, act=lambda _: None, trouble=troubles.append, resolved=lambda _: None)
    return reader, troubles


def _holding() -> tuple[FlakyDevice, DeviceReader, OperatorInput, list[str]]:
    """A flaky device read once with the enable held and the grip at 0.4."""
    clock = Clock()
    device = FlakyDevice(clock)
    device.grip, device.enable = 0.4, True
    reader, troubles = _reader(device, clock)
    last, gap = reader.read(None)
    assert last.enable and not gap
    return device, reader, last, troubles


def test_a_read_that_leaves_the_device_disconnected_is_a_gap_not_a_lost_reading():
    device, reader, last, troubles = _holding()
    device.fail_next = "unplug"
    reading, gap = reader.read(last)
    assert gap  # the enable counts as let go, and drives again only once held anew
    assert not reading.enable and reading.buttons == frozenset() and reading.grip == 0.4
    assert not reading.lost
    assert "gamepad unplugged" in troubles[-1]


def test_one_bad_report_on_a_connected_device_is_a_lost_reading_without_a_gap():
    device, reader, last, troubles = _holding()
    device.fail_next = "bad report"
    reading, gap = reader.read(last)
    assert not gap and reading.lost and not reading.enable and reading.grip == 0.4
    assert "bad report" in troubles[-1]


def test_while_unplugged_the_loop_shows_the_enable_released_not_suspended():
    clock, link, device, loop = loop_rig(grip=0.5)
    device.enable = True
    for _ in range(200):
        loop.step()
        clock.t += 0.001
    grasp_id = link.sent[-1][2]["grasp_id"]
    link.view = OperatorView(t_s=clock(), grasp_id=grasp_id, phase="loading")
    device.plugged = device.connected = False  # the hand still on the enable, the cable out
    for _ in range(300):
        loop.step()
        clock.t += 0.001
    status = loop.status
    assert not status.held and not status.suspended and not status.enable
    assert status.mode == "follow (paused)"


def test_feel_on_a_device_closed_meanwhile_shows_no_problem():
    # The next read says the device is gone: a feel() failure would hide that.
    clock = Clock()
    reader, troubles = _reader(ClosedUnderFeel(clock), clock)
    reader.feel(force_n=3.0, width_m=0.05, stiffness=0.5)
    assert troubles == []


def test_feel_is_not_passed_to_a_disconnected_device():
    clock = Clock()
    device = FakeDevice(clock)
    device.connected = False
    reader, _ = _reader(device, clock)
    reader.feel(force_n=3.0, width_m=0.05, stiffness=0.5)
    assert device.felt == []
    device.connected = True
    reader.feel(force_n=3.0, width_m=0.05, stiffness=0.5)
    assert device.felt == [(3.0, 0.05, 0.5)]
