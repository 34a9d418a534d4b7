"""The display backend: a version-2 display's grip, a version-1 display refused, unplug, staleness."""

from __future__ import annotations

import math

import pytest
from support.threads import close_during_read

from haptics.devices.sim import SimulatedDisplay
from haptics.errors import InputDeviceError, InputNotConnectedError, ProtocolError
from haptics.inputs import make_input
from haptics.inputs.display import DisplayInput
from haptics.protocol import GRIP_LOST_AFTER_S


def test_the_latest_grip_force_and_enable_are_read(make_grip_display):
    display = make_grip_display()
    with DisplayInput(display) as device:
        display.push(0.2, force_n=1.5, enable=True)
        display.push(0.6, force_n=4.25, enable=True)
        reading = device.read(timeout_s=0.01)
        assert (reading.grip, reading.force_n, reading.enable) == (0.6, 4.25, True)
        display.push(0.7, force_n=None, enable=False)
        reading = device.read(timeout_s=0.01)
        assert (reading.grip, reading.force_n, reading.enable) == (0.7, None, False)
        assert device.read(timeout_s=0.0).grip == 0.7  # nothing new: the latest state


def test_a_held_button_is_one_press_and_pressed_again_another(make_grip_display):
    display = make_grip_display()
    with DisplayInput(display) as device:
        for _ in range(3):
            display.push(0.1, buttons=("grasp",))
        assert device.read().buttons == {"grasp"}
        display.push(0.1, buttons=("grasp", "stop"))
        assert device.read().buttons == {"stop"}
        display.push(0.1)
        display.push(0.1, buttons=("grasp",))
        assert device.read().buttons == {"grasp"}
        assert device.read().buttons == frozenset()


def test_a_version_1_display_is_refused_at_connect(make_grip_display):
    display = make_grip_display(protocol_version=1)
    device = DisplayInput(display)
    with pytest.raises(InputDeviceError, match="display speaks protocol version 1: it has no grip"):
        device.connect()
    assert not device.connected
    assert not display.connected  # connected here for the check, so closed here again


def test_a_shared_display_stays_connected_and_an_owned_one_is_closed(make_grip_display):
    shared = make_grip_display()
    shared.connect()
    with DisplayInput(shared):
        pass
    assert shared.connected and shared.closes == 0
    owned = make_grip_display()
    with DisplayInput(owned, owned=True):
        assert owned.connected
    assert not owned.connected


def test_an_unplugged_display_is_an_input_device_error(make_grip_display):
    display = make_grip_display()
    device = DisplayInput(display).connect()
    display.push(0.5)
    display.unplugged = True
    with pytest.raises(InputDeviceError, match="the display failed: .*disconnected"):
        device.read()
    assert not device.connected
    with pytest.raises(InputNotConnectedError):
        device.read()
    with pytest.raises(InputDeviceError, match="cannot be connected"):
        device.connect()
    display.unplugged = False
    device.connect()
    display.push(0.25)
    assert device.read().grip == 0.25


def test_a_display_that_stops_reporting_reads_not_enabled(make_grip_display):
    display = make_grip_display()
    now = [10.0]
    with DisplayInput(display, stale_s=0.05, clock=lambda: now[0]) as device:
        display.push(0.4, enable=True)
        assert device.read().enable is True
        now[0] += 0.08
        reading = device.read()
        assert reading.enable is False and reading.grip == 0.4 and reading.t_s == 10.08
        display.push(0.4, enable=True)
        assert device.read().enable is True
    for bad in (0, -1.0, math.nan, math.inf, True):
        with pytest.raises(InputDeviceError, match="stale_s"):
            DisplayInput(display, stale_s=bad)


def test_by_default_the_dead_man_is_released_after_the_protocol_s_100_ms(make_grip_display):
    # PROTOCOL.md: no grip report for 100 ms: take the grip as lost and the dead-man as released.
    assert GRIP_LOST_AFTER_S == 0.1
    display = make_grip_display()
    now = [0.0]
    with DisplayInput(display, clock=lambda: now[0]) as device:
        assert device.stale_s == GRIP_LOST_AFTER_S
        display.push(0.4, enable=True)
        assert device.read().enable is True
        now[0] = 0.095
        assert device.read().enable is True
        now[0] = 0.105
        assert device.read().enable is False


def test_a_release_and_a_new_press_between_two_reads_is_a_press():
    display = SimulatedDisplay()  # the real SoftnessDisplay path: every report since the last read
    with DisplayInput(display) as device:
        display.firmware.set_grip(0.2, buttons=("grasp",))
        assert device.read().buttons == {"grasp"}
        display.firmware.set_grip(0.2, buttons=("grasp",))  # still held: no new press
        assert device.read().buttons == frozenset()
        display.firmware.set_grip(0.2)  # let go ...
        display.firmware.set_grip(0.2, buttons=("grasp",))  # ... and pressed again before a read
        assert device.read().buttons == {"grasp"}


# ------------------------------------------------------------------ the shipped simulated display


def test_the_simulated_display_s_grip(settings):
    display = SimulatedDisplay()
    with make_input("display", settings, display=display) as device:
        assert device.read(timeout_s=0.01).enable is False  # nothing reported yet
        display.firmware.set_grip(0.3, force_n=2.0, buttons=("next",))
        display.firmware.set_grip(0.35, force_n=2.5)
        reading = device.read(timeout_s=0.01)
        assert reading.grip == pytest.approx(0.35) and reading.force_n == pytest.approx(2.5)
        assert reading.enable is True and reading.buttons == {"next"}


def test_a_malformed_grip_report_is_refused_and_the_link_stays(settings):
    display = SimulatedDisplay()
    with make_input("display", settings, display=display) as device:
        garbled = bytearray(display.firmware.set_grip(0.5))
        display.firmware.next_input_report()
        garbled[3] ^= 0x10
        display.firmware.queue_input_report(bytes(garbled))
        with pytest.raises(ProtocolError, match="crc"):
            device.read(timeout_s=0.01)
        assert device.connected
        display.firmware.set_grip(0.6)
        assert device.read(timeout_s=0.01).grip == pytest.approx(0.6)


def test_a_simulated_version_1_display_is_refused(settings):
    with pytest.raises(InputDeviceError, match="display speaks protocol version 1: it has no grip"):
        make_input("display", settings, display=SimulatedDisplay(protocol_version=1)).connect()


def test_by_default_it_owns_a_display_made_from_the_settings(settings):
    device = make_input("display", settings)
    assert isinstance(device.display, SimulatedDisplay)
    with device:
        assert device.display.connected
    assert not device.display.connected


def test_the_input_names_its_display_as_the_display_names_itself():
    from haptics.devices.sim import SimulatedDisplay

    assert repr(DisplayInput(SimulatedDisplay())) == "<DisplayInput simulated display>"  # not "object at 0x..."


def test_close_from_another_thread_ends_a_read_on_an_owned_hid_display(fake_hid):
    from haptics.devices.hid import HidDisplay
    from haptics.settings import DisplaySettings

    fake_hid.plug()
    device = DisplayInput(HidDisplay.from_settings(DisplaySettings()), owned=True).connect()
    ended = close_during_read(lambda: device.read(timeout_s=3.0), device.close, errors=InputNotConnectedError)
    assert ended.close_s < 1.0 and ended.ended_s < 1.0
    assert isinstance(ended.outcome, InputNotConnectedError) and "closed" in str(ended.outcome), ended.outcome
    assert not device.connected and not device.display.connected
