"""Object names a catalogue accepts are those every later step (bus messages, labels, record files)
takes; a byte-order mark does not stop a catalogue being read."""

from __future__ import annotations

import pytest

from teleop.bus.messages import SCHEMAS
from teleop.catalogue import (
    MAX_NAME_CHARS,
    ObjectSpec,
    load_catalogue,
    read_object_table,
    read_toml_catalogue,
)
from teleop.cli import main
from teleop.errors import SettingsError
from teleop.sim import simulate_cli


def _toml(name: str) -> str:
    return f'[[objects]]\nname = "{name}"\nshape = "sphere"\nmaterial = "rubber"\nmodulus_pa = 1e5\n'


def test_the_name_limit_is_the_smallest_of_the_bus_messages_that_carry_it():
    limits = [SCHEMAS[kind].fields["object_name"].max_chars for kind in ("grasp_event", "label")]
    assert MAX_NAME_CHARS == min(limits) == 128


@pytest.mark.parametrize(("name", "said"), [
    ("", "object name is empty: expected 1 to 128 characters"),
    (" padded ", "object ' padded ': the name starts or ends with whitespace"),
    ("tab\t", "object 'tab\\t': the name starts or ends with whitespace"),
    ("x" * 129, "the name has 129 characters, at most 128 (the bus's label message"),
    ("x" * 295, "the name has 295 characters, at most 128"),
])
def test_object_spec_refuses_names_later_steps_cannot_carry(name, said):
    with pytest.raises(ValueError, match="object") as info:
        ObjectSpec(name=name, shape="sphere", material="rubber", modulus_pa=1e5)
    assert said in str(info.value)


@pytest.mark.parametrize("name", ["x" * 129, " padded ", ""])
def test_the_toml_catalogue_refuses_them_naming_file_and_object(tmp_path, name):
    path = tmp_path / "objects.toml"
    path.write_text(_toml(name))
    with pytest.raises(SettingsError) as info:
        read_toml_catalogue(path)
    assert f"{path}: objects[0]" in str(info.value) and "name" in str(info.value)


def test_the_longest_name_still_goes_through(tmp_path):
    path = tmp_path / "objects.toml"
    path.write_text(_toml("y" * MAX_NAME_CHARS))
    assert read_toml_catalogue(path)[0].name == "y" * MAX_NAME_CHARS


def test_the_csv_table_refuses_a_name_over_the_limit(tmp_path):
    path = tmp_path / "objects.csv"
    path.write_text(f"Label,Shape,Material,Modulus [Pa]\n{'z' * 200},sphere,rubber,1e5\n")
    with pytest.raises(SettingsError, match=rf"{path.name}:2: object 'z+'\.\.\.: the name has 200 characters"):
        read_object_table(path)


def test_the_shipped_catalogue_and_the_published_table_still_load(object_table):
    assert len(load_catalogue()) >= 40
    assert len(read_object_table(object_table)) > 100


def test_a_csv_table_with_a_byte_order_mark_is_read(tmp_path):
    path = tmp_path / "t.csv"
    path.write_bytes(b"\xef\xbb\xbfLabel,Shape,Material,Modulus [Pa]\r\nbomobj,sphere,rubber,1e5\r\n")
    (obj,) = read_object_table(path)
    assert (obj.name, obj.modulus_pa) == ("bomobj", 1e5)


def test_a_toml_catalogue_with_a_byte_order_mark_is_read(tmp_path):
    path = tmp_path / "t.toml"
    path.write_bytes(b"\xef\xbb\xbf" + _toml("bomobj").encode())
    assert [o.name for o in read_toml_catalogue(path)] == ["bomobj"]


def test_simulate_says_which_record_name_the_out_directory_refuses(tmp_path, monkeypatch, capsys):
    """A file name the file system refuses (here over its 255-byte limit) is an error naming it,
    not a traceback."""
    catalogue = tmp_path / "objects.toml"
    catalogue.write_text(_toml("ball"))
    monkeypatch.setattr(simulate_cli, "grasp_filename", lambda obj, index: f"{'n' * 300}_g{index:03d}.grasp")
    code = main(["simulate", "--objects", str(catalogue), "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err
    assert code == 2, err
    assert f"--out {tmp_path / 'o'}: cannot use the record file name 'nnn" in err
    assert "File name too long" in err and f"shorten the object's name in {catalogue}" in err
    assert "Traceback" not in err
