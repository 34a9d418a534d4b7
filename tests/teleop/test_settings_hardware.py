"""Hardware addresses and codes in the settings: refused as the file loads, by `teleop settings` too,
not first when `teleop doctor`, `teleop node` or `haptics operate` opens the device."""

from __future__ import annotations

import sys

import pytest

from haptics.settings import OperatorSettings
from teleop.cli import main
from teleop.errors import SettingsError
from teleop.settings import GripperSettings, LoadCellSettings


@pytest.mark.parametrize(("text", "expected"), [
    ('[load_cell]\naddress = "127.0.0.1:5601"\n', "[load_cell] LoadCellSettings.address = '127.0.0.1:5601': "
                                                   "expected tcp://HOST:PORT with a port in 1..65535"),
    ('[load_cell]\naddress = "tcp://127.0.0.1:99999"\n', "LoadCellSettings.address = 'tcp://127.0.0.1:99999': "
                                                         "expected tcp://HOST:PORT with a port in 1..65535"),
    ('[load_cell]\naddress = "tcp://:5601"\n', "LoadCellSettings.address = 'tcp://:5601': expected tcp://HOST:PORT"),
    ('[load_cell]\naddress = "udp://127.0.0.1:5601"\n', "LoadCellSettings.address = 'udp://127.0.0.1:5601': "
                                                         "expected tcp://HOST:PORT"),
    ('[gripper]\nhost = ""\n', "[gripper] GripperSettings.host = '': expected the robot controller's host name or "
                               "IP address"),
    ('[gripper]\nhost = "tcp://172.16.0.2"\n', "GripperSettings.host = 'tcp://172.16.0.2': expected"),
    ('[gripper]\nconnect_timeout_s = 0\n', "GripperSettings.connect_timeout_s = 0.0: expected a value in (0.0, 60.0]"),
    ('[operator]\ngamepad_trigger = "ABS_NOPE"\n', "[operator] OperatorSettings.gamepad_trigger = 'ABS_NOPE': "
                                                   "evdev knows no such code"),
    ('[operator]\ngamepad_grasp = "BTN_NOPE"\n', "OperatorSettings.gamepad_grasp = 'BTN_NOPE': evdev knows no such code"),
])
def test_teleop_settings_refuses_hardware_values_that_could_only_fail_later(tmp_path, capsys, text, expected):
    path = tmp_path / "rig.toml"
    path.write_text(text, encoding="utf-8")
    assert main(["settings", str(path)]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"teleop settings: error: {path}: ") and expected in err, err


@pytest.mark.parametrize("address", ["tcp://127.0.0.1:5601", "tcp://pi.local:1", "tcp://[::1]:65535"])
def test_bridge_addresses_load(address):
    assert LoadCellSettings(backend="tcp", address=address).address == address


@pytest.mark.parametrize("host", ["172.16.0.2", "panda.local", "fe80::1%eth0", "127.0.0.1"])
def test_robot_hosts_load(host):
    assert GripperSettings(backend="franky", host=host).host == host


def test_without_evdev_gamepad_codes_are_left_to_the_backend(monkeypatch):
    monkeypatch.setitem(sys.modules, "evdev", None)  # `import evdev` raises ImportError, as when not installed
    assert OperatorSettings(gamepad_trigger="ABS_NOPE").gamepad_trigger == "ABS_NOPE"
    with pytest.raises(SettingsError, match="expected an absolute axis"):  # what needs no table still is checked
        OperatorSettings(gamepad_trigger="RZ")
