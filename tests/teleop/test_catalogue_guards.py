"""Object catalogues: tables that would silently lose objects, extents the simulator would ignore,
and the listing's count of unlabelled rows."""

from __future__ import annotations

import json

import pytest

from teleop import cli
from teleop.catalogue import load_catalogue, read_object_table, read_toml_catalogue
from teleop.errors import SettingsError


def test_a_column_named_twice_is_refused(tmp_path):
    path = tmp_path / "dup.csv"
    path.write_text("Label,Shape,Material,Modulus [Pa],Modulus [Pa]\nA,Sphere,Rubber,1e6,\n")
    with pytest.raises(SettingsError, match=r"dup.csv: the CSV header names column 'Modulus \[Pa\]' 2 times"):
        read_object_table(path)


def test_a_table_of_unlabelled_rows_only_is_an_error_naming_it(tmp_path):
    path = tmp_path / "none.csv"
    path.write_text("Label,Shape,Material,Modulus [Pa]\nA,Sphere,Rubber,0\nB,Box,Foam,\n")
    with pytest.raises(SettingsError, match=r"none.csv: every one of its 2 rows is unlabelled"):
        load_catalogue(path)


def test_a_semicolon_table_is_told_the_delimiter(tmp_path):
    path = tmp_path / "semi.csv"
    path.write_text("Label;Shape;Material;Modulus [Pa]\nA;Sphere;Rubber;1e6\n")
    with pytest.raises(SettingsError, match="missing Label, .*the header holds ';': expected a comma-separated"):
        read_object_table(path)


def test_unlabelled_rows_are_collected_when_asked(tmp_path):
    path = tmp_path / "some.csv"
    path.write_text("Label,Shape,Material,Modulus [Pa]\nA,Sphere,Rubber,1e6\nB,Box,Foam,0\n")
    unlabelled: list[str] = []
    assert [o.name for o in load_catalogue(path, unlabelled=unlabelled)] == ["A"]
    assert unlabelled == ["B"]


def test_the_listing_says_how_many_rows_were_skipped(object_table, capsys):
    assert cli.main(["catalogue", str(object_table)]) == 0
    last = capsys.readouterr().out.strip().splitlines()[-1]
    assert last.endswith("; 1 row skipped as unlabelled (no modulus: racquet_ball)"), last
    assert cli.main(["catalogue", str(object_table), "--json"]) == 0
    assert json.loads(capsys.readouterr().out.strip().splitlines()[-1])["unlabelled"] == ["racquet_ball"]


@pytest.mark.parametrize("shape, size, message", [
    ("cylinder", [0.02, 0.03, 0.05], "a cylinder is round: size_m[1] is its diameter, as size_m[0], expected 0.02 m"),
    ("hex_prism", [0.02, 0.02, 0.04], "a hex prism is regular: size_m[1] is its width across corners, "
                                      "size_m[0] / cos 30, expected 0.02309 m"),
])
def test_a_cross_section_the_simulator_would_ignore_is_refused(tmp_path, shape, size, message):
    path = tmp_path / "objects.toml"
    path.write_text(f'[[objects]]\nname = "x"\nshape = "{shape}"\nmaterial = "plastic"\nmodulus_pa = 1e9\n'
                    f"size_m = {size}\n")
    with pytest.raises(SettingsError) as info:
        read_toml_catalogue(path)
    assert message in str(info.value) and "objects[0] (x)" in str(info.value)


def test_consistent_cross_sections_are_read(tmp_path):
    path = tmp_path / "objects.toml"
    path.write_text('[[objects]]\nname = "rod"\nshape = "cylinder"\nmaterial = "metal"\nmodulus_pa = 1e11\n'
                    "size_m = [0.02, 0.02, 0.1]\n"
                    '[[objects]]\nname = "nut"\nshape = "hex"\nmaterial = "metal"\nmodulus_pa = 1e11\n'
                    "size_m = [0.019, 0.0219, 0.04]\n")
    assert [o.size_m for o in read_toml_catalogue(path)] == [(0.02, 0.02, 0.1), (0.019, 0.0219, 0.04)]


def test_catalogue_help_tells_how_sizes_are_read(capsys):
    with pytest.raises(SystemExit):
        cli.main(["catalogue", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "a cylinder's diameter and length alike (d, d, d)" in text and "rows of a CSV table" in text
