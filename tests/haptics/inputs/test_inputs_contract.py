"""The operator input contract, run over every backend: keyboard, gamepad (fake evdev device),
the display's grip (fake version-2 display) and the simulated operator (scripted)."""

from __future__ import annotations

import math
import time

import pytest
from support.contract import assert_every_backend_covered
from support.threads import close_during_read

from haptics.errors import InputBackendNotFoundError, InputNotConnectedError, OperatorInputError
from haptics.inputs import BACKENDS, OperatorInput, input_class, make_input
from haptics.settings import INPUT_BACKENDS
from teleop.operator import BUTTONS


def test_a_new_device_is_unconnected_and_refuses_use(input_rig):
    device = input_rig.device
    assert not device.connected
    with pytest.raises(InputNotConnectedError, match=r"read\(\) .*call connect\(\)"):
        device.read(timeout_s=0.0)
    with pytest.raises(InputNotConnectedError, match="connect"):
        device.feel(force_n=1.0, width_m=0.05, stiffness=None)


def test_connect_returns_the_device_and_twice_is_harmless(input_rig):
    device = input_rig.device
    assert device.connect() is device
    assert device.connect() is device
    assert device.connected


def test_context_manager_connects_and_closes_and_close_twice_is_fine(input_rig):
    with input_rig.device as device:
        assert device is input_rig.device and device.connected
        device.read(timeout_s=0.0)
    assert not input_rig.device.connected
    with pytest.raises(InputNotConnectedError, match="closed"):
        input_rig.device.read(timeout_s=0.0)
    input_rig.device.close()
    input_rig.device.close()


def test_a_reading_is_valid_and_starts_safe(input_rig):
    device = input_rig.device.connect()
    before = time.monotonic()
    reading = device.read(timeout_s=0.01)
    assert isinstance(reading, OperatorInput)
    assert before <= reading.t_s <= time.monotonic()
    assert 0.0 <= reading.grip <= 1.0
    assert reading.enable is False  # nothing held: not enabled
    assert reading.buttons == frozenset()
    assert reading.force_n is None or math.isfinite(reading.force_n)


@pytest.mark.parametrize("grip", [0.5, 1.0, 0.25, 0.0])
def test_the_grip_follows_the_hand(input_rig, grip):
    device = input_rig.device.connect()
    input_rig.set_grip(grip)
    assert device.read(timeout_s=0.01).grip == pytest.approx(grip, abs=0.005)


def test_the_enable_follows_the_dead_man(input_rig):
    device = input_rig.device.connect()
    input_rig.set_enable(True)
    assert device.read(timeout_s=0.01).enable is True
    assert device.read(timeout_s=0.01).enable is True  # held: still enabled
    input_rig.set_enable(False)
    assert device.read(timeout_s=0.01).enable is False


def test_each_press_is_reported_once(input_rig):
    device = input_rig.device.connect()
    assert input_rig.buttons and set(input_rig.buttons) <= set(BUTTONS)
    for button in input_rig.buttons:
        input_rig.press(button)
        assert button in device.read(timeout_s=0.01).buttons, button
        assert button not in device.read(timeout_s=0.01).buttons, button


def test_feel_is_taken_when_connected_and_checked(input_rig):
    device = input_rig.device.connect()
    device.feel(force_n=2.5, width_m=0.04, stiffness=None)
    device.feel(force_n=0.0, width_m=0.08, stiffness=0.3)
    with pytest.raises(OperatorInputError, match="force_n"):
        device.feel(force_n=math.nan, width_m=0.04, stiffness=None)
    with pytest.raises(OperatorInputError, match="width_m"):
        device.feel(force_n=1.0, width_m=math.inf, stiffness=None)
    assert device.connected


@pytest.mark.parametrize("timeout_s", [-0.1, math.nan, math.inf, "0.1"])
def test_a_bad_timeout_is_refused(input_rig, timeout_s):
    device = input_rig.device.connect()
    with pytest.raises(OperatorInputError, match="timeout_s"):
        device.read(timeout_s=timeout_s)
    assert device.connected


def test_a_read_never_waits_longer_than_its_timeout(input_rig):
    device = input_rig.device.connect()
    start = time.monotonic()
    for _ in range(3):
        device.read(timeout_s=0.02)
    # 60 ms of timeouts in all. Bounded well below the 3 s three reads waiting a second each (a
    # timeout ignored, or taken in the wrong unit) would take, as a loaded machine is slow.
    assert time.monotonic() - start < 1.5


def test_close_from_another_thread_ends_a_pending_read_at_once(input_rig):
    device = input_rig.device.connect()
    ended = close_during_read(lambda: device.read(timeout_s=3.0), device.close, errors=InputNotConnectedError)
    assert ended.close_s < 1.0 and ended.ended_s < 1.0
    assert isinstance(ended.outcome, OperatorInput | InputNotConnectedError), ended.outcome
    assert not device.connected


def test_closed_and_connected_again_it_starts_safe(input_rig):
    device = input_rig.device.connect()
    input_rig.set_enable(True)
    device.close()
    input_rig.set_enable(False)
    device.connect()
    reading = device.read(timeout_s=0.01)
    assert reading.enable is False and reading.buttons == frozenset()


def test_a_press_before_a_reconnect_is_not_reported_after_it(input_rig):
    if input_rig.device.name == "sim":
        pytest.skip("the scripted operator's presses are the script's, kept across connections")
    device = input_rig.device.connect()
    input_rig.press(input_rig.buttons[0])
    device.close()
    device.connect()
    assert device.read(timeout_s=0.01).buttons == frozenset()


# ------------------------------------------------------------------ the name table


def test_every_backend_in_the_table_runs_the_contract_suite(input_rig_backends):
    assert_every_backend_covered("operator input", BACKENDS, input_rig_backends, fixture="input_rig",
                                 where="tests/haptics/inputs/conftest.py")


def test_the_table_names_every_backend_the_settings_allow():
    assert tuple(BACKENDS) == INPUT_BACKENDS
    for name in BACKENDS:
        cls = input_class(name)
        assert cls.name == name and cls.family == "operator input"


def test_an_unknown_backend_is_named_with_the_ones_there_are(settings):
    with pytest.raises(InputBackendNotFoundError, match=r"'joystick'.*display, gamepad, keyboard, sim"):
        make_input("joystick", settings)


def test_make_input_builds_each_backend_unconnected(settings, input_rig):
    name = input_rig.device.name
    options = {"gamepad": {"device": input_rig.fake}, "display": {"display": input_rig.fake}}.get(name, {})
    device = make_input(name, settings, **options)
    assert type(device) is type(input_rig.device) and not device.connected
    with device:
        assert isinstance(device.read(timeout_s=0.0), OperatorInput)


def test_a_gamepad_without_evdev_names_evdev_to_install(monkeypatch):
    import sys

    from haptics.inputs import input_class

    monkeypatch.setitem(sys.modules, "evdev", None)  # an import of evdev fails, as where it is missing
    monkeypatch.delitem(sys.modules, "haptics.inputs.gamepad", raising=False)
    with pytest.raises(InputBackendNotFoundError, match=r"\(install evdev, a dependency of the project on Linux only"):
        input_class("gamepad")
