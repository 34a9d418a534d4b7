"""The ``[operator]`` table (haptics.settings.OperatorSettings) and the OperatorInput reading."""

from __future__ import annotations

import math

import pytest

from haptics.errors import OperatorInputError
from haptics.inputs import OperatorInput, make_input
from haptics.inputs.keyboard import KeyboardInput
from haptics.settings import OperatorSettings, operator_settings
from teleop.errors import SettingsError
from teleop.settings import load_settings


def test_without_a_table_the_defaults_apply(settings):
    assert operator_settings(settings) == OperatorSettings()
    defaults = OperatorSettings()
    assert (defaults.input, defaults.gamepad_path, defaults.gamepad_trigger, defaults.gamepad_enable) == (
        "keyboard", "", "ABS_RZ", "BTN_TR")
    assert (defaults.keyboard_grip_step, defaults.sim_seed) == (0.05, 0)
    assert defaults.gamepad_buttons() == {"enable": "BTN_TR", "grasp": "BTN_SOUTH", "release": "BTN_EAST",
                                          "stop": "BTN_WEST", "next": "BTN_NORTH", "quit": "BTN_SELECT"}
    assert isinstance(make_input(None, settings), KeyboardInput)


def test_the_input_named_in_the_settings_is_opened(with_operator):
    assert make_input(None, with_operator(input="sim", sim_seed=4)).seed == 4


@pytest.mark.parametrize(("keys", "match"), [
    ({"input": "mouse"}, r"OperatorSettings.input = 'mouse': expected one of 'keyboard', 'gamepad'"),
    ({"gamepad_trigger": "BTN_TL"}, r"gamepad_trigger = 'BTN_TL': expected an absolute axis"),
    ({"gamepad_enable": ""}, r"gamepad_enable = '': .*cannot be left unmapped"),
    ({"gamepad_grasp": "ABS_X"}, r"gamepad_grasp = 'ABS_X': expected a button name"),
    ({"gamepad_next": "BTN_TR"}, r"gamepad_next = 'BTN_TR': already gamepad_enable"),
    # names evdev does not know: refused as the settings load, not first when the pad opens
    ({"gamepad_trigger": "ABS_NOPE"}, r"gamepad_trigger = 'ABS_NOPE': evdev knows no such code"),
    ({"gamepad_grasp": "BTN_NOPE"}, r"gamepad_grasp = 'BTN_NOPE': evdev knows no such code"),
    ({"gamepad_enable": "KEY_NOPE"}, r"gamepad_enable = 'KEY_NOPE': evdev knows no such code"),
    ({"keyboard_grip_step": 0.0}, r"keyboard_grip_step = 0.0: expected a value in \[0.001, 1.0\]"),
    ({"keyboard_grip_step": 1e-10}, r"keyboard_grip_step = 1e-10: expected a value in \[0.001, 1.0\]"),
    ({"keyboard_grip_step": 1.5}, r"keyboard_grip_step"),
    ({"sim_seed": -1}, r"sim_seed = -1"),
])
def test_bad_values_are_named(keys, match):
    with pytest.raises(SettingsError, match=match):
        OperatorSettings(**keys)


@pytest.mark.parametrize(("keys", "match"), [
    # BTN_Y is BTN_WEST (308, the stop button); BTN_A is BTN_SOUTH (304, grasp); KEY_ and BTN_ share codes
    ({"gamepad_enable": "BTN_Y"},
     r"gamepad_stop = 'BTN_WEST': the same evdev code 308 as gamepad_enable = 'BTN_Y'"),
    ({"gamepad_next": "BTN_A"},
     r"gamepad_next = 'BTN_A': the same evdev code 304 as gamepad_grasp = 'BTN_SOUTH'"),
    ({"gamepad_quit": "BTN_GAMEPAD"},
     r"gamepad_quit = 'BTN_GAMEPAD': the same evdev code 304 as gamepad_grasp = 'BTN_SOUTH'"),
])
def test_two_names_of_one_button_code_are_refused(keys, match):
    with pytest.raises(SettingsError, match=match):
        OperatorSettings(**keys)


def test_aliases_of_unmapped_or_distinct_buttons_are_accepted():
    # BTN_Y (308) is fine once BTN_WEST is not mapped elsewhere
    assert OperatorSettings(gamepad_enable="BTN_Y", gamepad_stop="").gamepad_buttons()["enable"] == "BTN_Y"
    assert OperatorSettings(gamepad_grasp="BTN_A", gamepad_next="BTN_Y", gamepad_stop="BTN_X").gamepad_stop == "BTN_X"


def test_an_unmapped_button_is_left_out():
    assert "quit" not in OperatorSettings(gamepad_quit="").gamepad_buttons()


def test_an_operator_table_in_a_file_is_read_and_checked_naming_the_file(tmp_path):
    path = tmp_path / "settings.toml"
    path.write_text('[operator]\ninput = "gamepad"\ngamepad_path = "/dev/input/event4"\n')
    table = operator_settings(load_settings(path))
    assert (table.input, table.gamepad_path, table.gamepad_trigger) == ("gamepad", "/dev/input/event4", "ABS_RZ")
    path.write_text('[operator]\ngamepad_trigger = "RZ"\n')
    with pytest.raises(SettingsError, match=r"settings.toml: \[operator\] .*gamepad_trigger = 'RZ'"):
        operator_settings(load_settings(path))
    path.write_text('[operator]\ngamepad_triger = "ABS_RZ"\n')
    with pytest.raises(SettingsError, match="gamepad_triger"):
        operator_settings(load_settings(path))


# ------------------------------------------------------------------ OperatorInput


def test_a_reading_checks_its_fields():
    reading = OperatorInput(t_s=1.0, grip=1.0, enable=True, force_n=2.0, buttons=frozenset({"grasp"}))
    assert reading.buttons == {"grasp"}
    assert OperatorInput(t_s=0.0, grip=0.0, enable=False).buttons == frozenset()
    for fields, match in [
        ({"grip": 1.01}, "grip"), ({"grip": -0.1}, "grip"), ({"grip": math.nan}, "grip"),
        ({"t_s": math.inf}, "t_s"), ({"enable": 1}, "enable"), ({"force_n": math.nan}, "force_n"),
        ({"buttons": {"grasp"}}, "frozenset"), ({"buttons": frozenset({"jump"})}, "'jump'"),
    ]:
        with pytest.raises(OperatorInputError, match=match):
            OperatorInput(**{"t_s": 1.0, "grip": 0.5, "enable": False, **fields})
