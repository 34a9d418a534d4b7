"""The field checks every settings table is built with (teleop.settings_fields): bounds, the keys a
file may set, and the bridge address form."""

from __future__ import annotations

import pytest

from teleop.errors import SettingsError
from teleop.settings import LoadCellSettings, load_settings, settings_from_mapping
from teleop.settings_fields import tcp_host_port


@pytest.mark.parametrize(("table", "key"), [("load_cell", "baud"), ("simulation", "jpeg_quality"),
                                            ("bus", "max_message_bytes")])
def test_an_integer_too_large_for_a_float_is_refused_naming_the_key_not_crashing(tmp_path, table, key):
    path = tmp_path / "rig.toml"
    path.write_text(f"[{table}]\n{key} = 1{'0' * 400}\n", encoding="utf-8")
    with pytest.raises(SettingsError) as info:
        load_settings(path)
    message = str(info.value)
    assert str(path) in message and f"{key} = 1000" in message and "expected a value in" in message, message


def test_an_integer_too_large_for_a_float_is_refused_when_built_in_code_too():
    with pytest.raises(SettingsError, match="LoadCellSettings.tare_counts"):
        LoadCellSettings(tare_counts=-(10**400))


@pytest.mark.parametrize("address", ["tcp://127.0.0.1", "tcp://127.0.0.1:0", "tcp://pi.local"])
def test_a_bridge_address_without_a_usable_port_is_refused(address):
    assert tcp_host_port(address) is None
    with pytest.raises(SettingsError, match="expected tcp://HOST:PORT with a port in 1..65535"):
        LoadCellSettings(backend="tcp", address=address)


def test_a_bridge_address_gives_its_host_and_port():
    assert tcp_host_port("tcp://pi.local:5601") == ("pi.local", 5601)


@pytest.mark.parametrize("key", ["tables", "source"])
def test_the_fields_a_file_cannot_set_are_unknown_keys_and_not_offered(key):
    with pytest.raises(SettingsError) as info:
        settings_from_mapping({key: "x"}, source="rig.toml")
    message = str(info.value)
    assert f"unknown key {key!r} in top level" in message, message
    allowed = message.split("allowed keys: ")[1].split(", ")
    assert "tables" not in allowed and "source" not in allowed and "gripper" in allowed
