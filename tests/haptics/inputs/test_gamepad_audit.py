"""Audit of the gamepad backend (:mod:`haptics.inputs.gamepad`): the enable reads released whenever the
shoulder button is not held now, across dropped events and reconnections; a found pad that cannot
serve is closed again (on the fake evdev device of conftest)."""

from __future__ import annotations

import pytest

import haptics.inputs.gamepad as gamepad_module
from haptics.errors import InputDeviceError
from haptics.inputs.gamepad import GamepadInput
from haptics.settings import OperatorSettings


def test_an_enable_tapped_between_two_reads_reads_released(make_pad):
    pad = make_pad()
    with GamepadInput(device=pad) as device:
        pad.tap("BTN_TR")
        reading = device.read()
        assert reading.enable is False and reading.buttons == frozenset()


def test_an_enable_let_go_while_events_were_dropped_reads_released(make_pad):
    pad = make_pad()
    with GamepadInput(device=pad) as device:
        pad.key("BTN_TR", 1)
        assert device.read().enable is True
        pad.key("BTN_TR", 0, report=False)  # its release event is among those lost
        pad.drop()
        assert device.read().enable is False


def test_an_enable_let_go_in_a_packet_dropped_across_reads_reads_released(make_pad):
    # SYN_DROPPED in one read, the rest of the lost packet and its SYN_REPORT in the next: the state
    # must be read again at that SYN_REPORT, or the release (dropped) is never seen.
    pad = make_pad()
    with GamepadInput(device=pad) as device:
        pad.key("BTN_TR", 1)
        pad.drop()
        assert device.read().enable is True
        pad.key("BTN_TR", 0)  # the release event (dropped) and the SYN_REPORT that ends the drop
        assert device.read().enable is False


def test_a_reconnection_while_events_were_being_dropped_takes_new_events(make_pad):
    pad = make_pad()
    device = GamepadInput(device=pad).connect()
    pad.drop()
    device.read()  # now dropping until the next SYN_REPORT
    device.close()
    device.connect()
    pad.tap("BTN_SOUTH")
    assert device.read().buttons == {"grasp"}
    device.close()


def test_every_event_queued_before_connect_is_drained_not_taken_as_a_press(make_pad):
    pad = make_pad()
    pad.tap("BTN_SOUTH")
    pad.tap("BTN_WEST")
    with GamepadInput(device=pad) as device:
        assert device.read().buttons == frozenset()


def test_a_pad_found_by_path_with_a_flat_trigger_is_closed_again(monkeypatch, make_pad):
    pad = make_pad("/dev/input/event4", axes={"ABS_RZ": (9, 9)})
    monkeypatch.setattr(gamepad_module, "_input_device", lambda path: pad)
    device = GamepadInput(OperatorSettings(gamepad_path=pad.path))
    with pytest.raises(InputDeviceError, match="range 9..9"):
        device.connect()
    assert pad.closed and not device.connected
