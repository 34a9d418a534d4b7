"""The keyboard backend: the console's keys, stepped grip, toggled enable."""

from __future__ import annotations

import pytest

from haptics.errors import InputNotConnectedError, OperatorInputError
from haptics.inputs import OperatorInput, make_input
from haptics.inputs.keyboard import KEYS, KeyboardInput
from teleop.operator import BUTTONS


@pytest.fixture
def keys():
    with KeyboardInput(grip_step=0.05, clock=lambda: 12.5) as device:
        yield device


def test_every_mapped_key_is_taken_and_others_are_left_to_the_console(keys):
    for key in KEYS:
        assert keys.press(key) is True, key
    keys.read()
    before = keys.read()
    for key in ("x", "enter", "space", "escape", "E", "ctrl+c", ""):
        assert keys.press(key) is False, key
    assert keys.read() == before


def test_up_and_down_step_the_grip_and_stop_at_the_ends(keys):
    for _ in range(3):
        keys.press("up")
    assert keys.read().grip == pytest.approx(0.15)
    keys.press("j")
    assert keys.read().grip == pytest.approx(0.10)
    for _ in range(40):
        keys.press("k")
    assert keys.read().grip == 1.0
    keys.press("o")
    assert keys.read().grip == 0.0
    keys.press("down")
    assert keys.read().grip == 0.0


def test_the_step_is_settable_and_checked(keys):
    keys.grip_step = 0.25
    keys.press("up")
    keys.press("up")
    assert keys.read().grip == pytest.approx(0.5)
    for bad in (0, -0.1, 1.5, float("nan"), True, 1e-10, 0.0009):
        with pytest.raises(OperatorInputError, match="grip_step"):
            keys.grip_step = bad
    assert keys.grip_step == 0.25


def test_the_smallest_step_still_moves_the_grip(keys):
    keys.grip_step = 1e-3
    keys.press("up")
    assert keys.read().grip == pytest.approx(1e-3)
    for _ in range(999):
        keys.press("up")
    assert keys.read().grip == pytest.approx(1.0)
    with pytest.raises(OperatorInputError, match=r"grip_step = 1e-10: expected a value in \[0.001, 1\]"):
        keys.grip_step = 1e-10


def test_e_toggles_the_enable(keys):
    assert keys.read().enable is False
    keys.press("e")
    assert keys.read().enable is True
    assert keys.read().enable is True
    keys.press("e")
    assert keys.read().enable is False


def test_let_go_turns_the_toggle_off_and_one_e_holds_it_again(keys):
    keys.press("e")
    keys.let_go()  # the console's, when the loop waits for the enable to be let go
    assert keys.read().enable is False
    keys.press("e")
    assert keys.read().enable is True


def test_release_lets_go_and_stop_drops_the_enable(keys):
    keys.press("e")
    for _ in range(10):
        keys.press("up")
    keys.press("s")
    reading = keys.read()
    assert reading.buttons == {"stop"} and reading.enable is False and reading.grip == pytest.approx(0.5)
    keys.press("e")
    keys.press("r")
    reading = keys.read()
    assert reading.buttons == {"release"} and reading.enable is False and reading.grip == 0.0


def test_button_keys_and_several_presses_between_reads(keys):
    for key in "gnq":
        keys.press(key)
    keys.press("g")
    assert keys.read() == OperatorInput(t_s=12.5, grip=0.0, enable=False, force_n=None,
                                        buttons=frozenset({"grasp", "next", "quit"}))
    assert keys.read().buttons == frozenset()
    assert {b for key in KEYS if (b := {"g": "grasp", "r": "release", "s": "stop", "n": "next",
                                        "q": "quit"}.get(key))} == set(BUTTONS)


def test_keys_before_connect_are_refused():
    device = KeyboardInput()
    with pytest.raises(InputNotConnectedError, match=r"press\(\)"):
        device.press("up")


def test_the_step_comes_from_the_settings(settings, with_operator):
    with make_input("keyboard", with_operator(keyboard_grip_step=0.2)) as device:
        assert device.grip_step == 0.2
    with make_input("keyboard", settings, grip_step=0.1) as device:
        assert device.grip_step == 0.1
