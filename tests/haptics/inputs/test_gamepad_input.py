"""The gamepad backend through a fake evdev device: trigger scaling, enable, presses, unplug, discovery."""

from __future__ import annotations

import errno

import pytest

import haptics.inputs.gamepad as gamepad_module
from haptics.errors import InputDeviceError, InputNotConnectedError
from haptics.inputs import make_input
from haptics.inputs.gamepad import GamepadInput
from haptics.settings import OperatorSettings


@pytest.mark.parametrize(("lo", "hi", "value", "grip"), [
    (0, 255, 0, 0.0), (0, 255, 255, 1.0), (0, 1023, 256, 256 / 1023),
    (-32768, 32767, 0, 32768 / 65535), (-32768, 32767, -32768, 0.0),
    (0, 255, 300, 1.0), (10, 20, 5, 0.0),  # out of the advertised range: clipped
])
def test_the_trigger_is_scaled_by_its_own_range(lo, hi, value, grip, make_pad):
    pad = make_pad(axes={"ABS_RZ": (lo, hi)})
    with GamepadInput(device=pad) as device:
        pad.move("ABS_RZ", value)
        assert device.read().grip == pytest.approx(grip)


def test_another_trigger_and_enable_from_the_settings(make_pad):
    pad = make_pad(keys=("BTN_TL", "BTN_A"))
    settings = OperatorSettings(gamepad_trigger="ABS_Z", gamepad_enable="BTN_TL", gamepad_grasp="BTN_A",
                                gamepad_release="", gamepad_stop="", gamepad_next="", gamepad_quit="")
    with GamepadInput(settings, device=pad) as device:
        pad.move("ABS_RZ", 255)  # not the trigger any more
        pad.move("ABS_Z", 51)
        pad.key("BTN_TL", 1)
        pad.tap("BTN_A")  # BTN_A is BTN_SOUTH: the same code
        reading = device.read()
        assert (reading.grip, reading.enable, reading.buttons) == (pytest.approx(0.2), True, {"grasp"})


@pytest.mark.parametrize(("keys", "match"), [
    ({"gamepad_enable": "BTN_Y"}, r"enable \(BTN_Y\) and stop \(BTN_WEST\) are the same evdev code 308"),
    ({"gamepad_next": "BTN_A"}, r"grasp \(BTN_SOUTH\) and next \(BTN_A\) are the same evdev code 304"),
])
def test_two_names_of_one_code_are_refused_not_remapped(keys, match, monkeypatch, make_pad):
    import haptics.settings as settings_module

    # without evdev the settings check names only (it cannot see codes): the pad must still refuse
    monkeypatch.setattr(settings_module, "_evdev_codes", lambda: None)
    settings = OperatorSettings(**keys)
    with pytest.raises(InputDeviceError, match=match):
        GamepadInput(settings, device=make_pad())


def test_the_state_at_connect_is_read_and_held_buttons_are_no_presses(make_pad):
    pad = make_pad()
    pad.move("ABS_RZ", 128, report=False)
    pad.key("BTN_TR", 1, report=False)
    pad.key("BTN_SOUTH", 1)  # queued before connect: stale
    with GamepadInput(device=pad) as device:
        reading = device.read()
        assert reading.grip == pytest.approx(128 / 255)
        assert reading.enable is True and reading.buttons == frozenset()


def test_enable_is_held_and_key_repeat_is_not_a_press(make_pad):
    pad = make_pad()
    with GamepadInput(device=pad) as device:
        pad.key("BTN_TR", 1)
        pad.key("BTN_SOUTH", 1)
        assert device.read().buttons == {"grasp"}
        pad.key("BTN_TR", 2)
        pad.key("BTN_SOUTH", 2)
        reading = device.read()
        assert reading.enable is True and reading.buttons == frozenset()
        pad.key("BTN_SOUTH", 0)
        pad.key("BTN_SOUTH", 1)
        pad.key("BTN_TR", 0)
        reading = device.read()
        assert reading.enable is False and reading.buttons == {"grasp"}
        pad.tap("BTN_TR")
        assert device.read().buttons == frozenset()  # the enable is no button


def test_a_press_and_release_between_reads_counts_once_and_others_are_ignored(make_pad):
    pad = make_pad(keys=(*("BTN_TR", "BTN_EAST", "BTN_NORTH"), "BTN_THUMBL"))
    with GamepadInput(device=pad) as device:
        pad.tap("BTN_EAST")
        pad.tap("BTN_NORTH")
        pad.tap("BTN_THUMBL")  # not mapped
        pad.move("ABS_X", 1000)  # not the trigger
        reading = device.read()
        assert reading.buttons == {"release", "next"} and reading.grip == 0.0


def test_dropped_events_make_it_read_the_state_again(make_pad):
    pad = make_pad()
    with GamepadInput(device=pad) as device:
        pad.move("ABS_RZ", 200, report=False)
        pad.key("BTN_TR", 1, report=False)
        pad.key("BTN_WEST", 1, report=False)
        pad.drop()
        reading = device.read()
        assert reading.grip == pytest.approx(200 / 255) and reading.enable is True
        assert reading.buttons == {"stop"}


def test_a_button_held_across_dropped_events_is_not_pressed_again(make_pad):
    # The state read again still has it down: a grasp button kept down must not start a second grasp.
    pad = make_pad()
    with GamepadInput(device=pad) as device:
        pad.key("BTN_SOUTH", 1)
        assert device.read().buttons == {"grasp"}
        pad.drop()
        assert device.read().buttons == frozenset()


def test_events_after_dropped_events_are_dropped_up_to_the_next_report(make_pad):
    pad = make_pad()
    with GamepadInput(device=pad) as device:
        pad.drop()
        # The rest of a partial packet: the state (read again) has neither of them.
        pad.key("BTN_SOUTH", 1, report=False)
        pad._event(gamepad_module.ecodes.EV_KEY, gamepad_module.ecodes.BTN_SOUTH, 1)
        pad._event(gamepad_module.ecodes.EV_ABS, gamepad_module.ecodes.ABS_RZ, 255)
        pad.key("BTN_SOUTH", 0, report=False)
        pad.syn()
        pad.tap("BTN_EAST")  # after the SYN_REPORT: taken
        reading = device.read()
        assert reading.buttons == {"release"} and reading.grip == 0.0


def test_dropped_events_across_reads_are_dropped_until_the_report(make_pad):
    pad = make_pad()
    with GamepadInput(device=pad) as device:
        pad.drop()
        assert device.read().buttons == frozenset()
        pad._event(gamepad_module.ecodes.EV_KEY, gamepad_module.ecodes.BTN_NORTH, 1)  # still the lost packet
        pad.syn()
        pad.tap("BTN_WEST")
        assert device.read().buttons == {"stop"}


@pytest.mark.parametrize(("lo", "hi"), [(0, 0), (255, 0)])
def test_a_flat_or_inverted_range_after_a_resync_disconnects_the_pad(lo, hi, make_pad):
    pad = make_pad()
    device = GamepadInput(device=pad).connect()
    code = gamepad_module.ecodes.ABS_RZ
    pad.axes[code] = pad.axes[code]._replace(min=lo, max=hi)
    pad.drop()
    with pytest.raises(InputDeviceError, match=rf"trigger ABS_RZ reports the range {lo}..{hi}: expected max > min"):
        device.read()
    assert not device.connected
    with pytest.raises(InputNotConnectedError):
        device.read()
    pad.axes[code] = pad.axes[code]._replace(min=0, max=255, value=51)
    assert device.connect().read().grip == pytest.approx(0.2)
    device.close()


def test_unplugged_it_says_so_and_is_disconnected(make_pad):
    pad = make_pad()
    device = GamepadInput(device=pad).connect()
    pad.move("ABS_RZ", 100)
    pad.unplugged = True
    with pytest.raises(InputDeviceError, match="went away .*No such device.*connect"):
        device.read()
    assert not device.connected
    with pytest.raises(InputNotConnectedError):
        device.read()
    with pytest.raises(InputDeviceError, match="went away"):
        device.connect()
    pad.unplugged = False
    assert device.connect().read().grip == pytest.approx(100 / 255)
    device.close()
    assert not pad.closed  # a given device stays its owner's


def test_a_device_without_the_trigger_or_a_flat_trigger_is_refused(make_pad):
    with pytest.raises(InputDeviceError, match="no absolute axis ABS_RZ"):
        GamepadInput(device=make_pad(axes={"ABS_X": (0, 255)})).connect()
    with pytest.raises(InputDeviceError, match="no enable button BTN_TR"):
        GamepadInput(device=make_pad(keys=("BTN_SOUTH",))).connect()
    with pytest.raises(InputDeviceError, match="range 7..7"):
        GamepadInput(device=make_pad(axes={"ABS_RZ": (7, 7)})).connect()
    with pytest.raises(InputDeviceError, match="range 255..0: expected max > min"):
        GamepadInput(device=make_pad(axes={"ABS_RZ": (255, 0)})).connect()


@pytest.fixture
def bus(monkeypatch):
    """Fake /dev/input: path -> make_pad (or an OSError to raise on open)."""
    devices: dict = {}

    def input_device(path, readonly=False):
        assert readonly, "the gamepad is opened read-only"
        found = devices.get(path)
        if found is None:
            raise OSError(errno.ENOENT, "No such file or directory")
        if isinstance(found, OSError):
            raise found
        found.closed = False
        return found

    monkeypatch.setattr(gamepad_module.evdev, "list_devices", lambda writable=True: list(devices))
    monkeypatch.setattr(gamepad_module.evdev, "InputDevice", input_device)
    return devices


def _plug(bus, **devices):
    bus.update(devices)


def test_the_first_device_with_the_trigger_is_found(bus, settings, make_pad):
    keyboard = make_pad("/dev/input/event2", "AT keyboard", axes={}, keys=("KEY_A",))
    mouse = make_pad("/dev/input/event10", "Second pad")
    pad = make_pad("/dev/input/event3", "Pad")
    _plug(bus, **{"/dev/input/event10": mouse, "/dev/input/event2": keyboard, "/dev/input/event3": pad,
                  "/dev/input/event1": OSError(errno.EACCES, "Permission denied")})
    with make_input("gamepad", settings) as device:
        pad.move("ABS_RZ", 255)
        assert device.read().grip == 1.0
        assert "event3" in repr(device)
    assert keyboard.closed and pad.closed and not mouse.closed  # event10 comes after event3


def test_no_suitable_device_lists_what_was_seen(bus, settings, make_pad):
    _plug(bus, **{"/dev/input/event0": make_pad("/dev/input/event0", "Mouse", axes={}, keys=()),
                  "/dev/input/event1": OSError(errno.EACCES, "Permission denied")})
    with pytest.raises(InputDeviceError, match=r"no gamepad with the trigger axis ABS_RZ .*event0 'Mouse': "
                                               r"no absolute axis ABS_RZ; /dev/input/event1 \(Permission denied\)"
                                               r".*gamepad_path"):
        make_input("gamepad", settings).connect()
    bus.clear()
    with pytest.raises(InputDeviceError, match="no readable /dev/input/event"):
        make_input("gamepad", settings).connect()


def test_the_path_from_the_settings_is_used(bus, with_operator, make_pad):
    pad = make_pad("/dev/input/by-id/usb-pad-event-joystick")
    _plug(bus, **{pad.path: pad, "/dev/input/event0": make_pad("/dev/input/event0")})
    with make_input("gamepad", with_operator(gamepad_path=pad.path)) as device:
        pad.key("BTN_TR", 1)
        assert device.read().enable is True
    # the setting and what to do, in the error itself: every command says it, not `teleop doctor` alone
    with pytest.raises(InputDeviceError, match=r"^cannot open gamepad /dev/input/nope: No such file or directory: "
                                               r"plug the pad in and check `\[operator\] gamepad_path`"):
        make_input("gamepad", with_operator(gamepad_path="/dev/input/nope")).connect()
    bus["/dev/input/locked"] = OSError(errno.EACCES, "Permission denied")
    with pytest.raises(InputDeviceError, match="Permission denied: add yourself to the 'input' group$"):
        make_input("gamepad", with_operator(gamepad_path="/dev/input/locked")).connect()
    bus["/dev/input/event9"] = make_pad("/dev/input/event9", "Mouse", axes={"ABS_X": (0, 9)})
    with pytest.raises(InputDeviceError, match="event9 \\(Mouse\\) has no absolute axis ABS_RZ: set"):
        make_input("gamepad", with_operator(gamepad_path="/dev/input/event9")).connect()
    assert bus["/dev/input/event9"].closed
