"""Object catalogues, audited by mutation: the boundaries of the plausible ranges, the extents the
simulator would misread, and the table cells that are read only in some cases."""

from __future__ import annotations

import pytest

from teleop.catalogue import (
    MODULUS_RANGE_PA,
    ObjectSpec,
    load_catalogue,
    read_object_table,
    read_toml_catalogue,
)
from tests.support.catalogue_toml import object_toml, settings_refusal, toml_file


def _catalogue(tmp_path, text: str):
    return toml_file(tmp_path, "objects.toml", text)


def _refusal(path) -> str:
    return settings_refusal(lambda: read_toml_catalogue(path))


def test_an_object_built_in_code_with_an_unknown_shape_is_refused():
    with pytest.raises(ValueError, match=r"object 'ring': shape 'torus' is not one of"):
        ObjectSpec("ring", "torus", "rubber", 1e5)


@pytest.mark.parametrize("modulus", MODULUS_RANGE_PA)
def test_the_ends_of_the_plausible_modulus_range_are_accepted(modulus):
    assert ObjectSpec("edge", "sphere", "rubber", modulus).modulus_pa == modulus


def test_a_table_modulus_at_the_stiffness_of_diamond_is_read(tmp_path):
    path = tmp_path / "t.csv"
    path.write_text("Label,Shape,Material,Modulus [Pa]\ngem,Box,Ceramic,1e12\nsoft,Box,Foam,1\n", encoding="utf-8")
    assert [o.modulus_pa for o in read_object_table(path)] == [1e12, 1.0]


@pytest.mark.parametrize("texture_m", [1e-3, -1e-6])
def test_a_texture_outside_0_to_1_mm_is_refused(texture_m):
    with pytest.raises(ValueError, match=r"texture_m must be in \[0, 1e-3\) m"):
        ObjectSpec("rough", "box", "wood", 1e10, texture_m=texture_m)


def test_a_padded_capitalised_toml_shape_is_read_and_its_section_checked(tmp_path):
    text = object_toml("ball", " Sphere ", "rubber", 1e5, size_m=[0.03, 0.03, 0.03])
    (ball,) = read_toml_catalogue(_catalogue(tmp_path, text))
    assert ball.shape == "sphere"
    text = object_toml("rod", " Cylinder", "metal", 1e11, size_m=[0.02, 0.03, 0.1])
    assert "a cylinder is round" in _refusal(_catalogue(tmp_path, text))


def test_an_empty_objects_array_is_refused(tmp_path):
    path = _catalogue(tmp_path, "objects = []\n")
    assert f"{path}: expected one or more [[objects]] tables" in _refusal(path)


def test_an_empty_size_array_is_refused_not_read_as_unknown(tmp_path):
    path = _catalogue(tmp_path, object_toml("block", "box", "wood", 1e10, size_m=[]))
    assert "objects[0] (block): object 'block': size_m must be three extents" in _refusal(path)


def test_a_boolean_extent_is_refused_as_no_number(tmp_path):
    path = _catalogue(tmp_path, object_toml("block", "box", "wood", 1e10).replace(
        "modulus_pa", "size_m = [0.02, true, 0.03]\nmodulus_pa"))
    assert "objects[0] (block): size_m must hold numbers (m), got [0.02, True, 0.03]" in _refusal(path)


def test_a_negative_sphere_extent_is_refused_as_out_of_range_not_as_unequal(tmp_path):
    path = _catalogue(tmp_path, object_toml("ball", "sphere", "rubber", 1e5, size_m=[-0.03, -0.03, -0.03]))
    assert "size_m must be three extents in (0, 1) m" in _refusal(path)


@pytest.mark.parametrize("size_m", [
    [0.03, 0.035, 0.03],  # 17 % apart though only 5 mm
    [0.03, 0.03, 0.05],  # the z extent differs
])
def test_a_sphere_whose_extents_differ_beyond_the_tolerance_is_refused(tmp_path, size_m):
    path = _catalogue(tmp_path, object_toml("ball", "sphere", "rubber", 1e5, size_m=size_m))
    assert "a sphere's three extents are its diameter" in _refusal(path)


def test_a_cylinder_a_few_percent_out_of_round_is_refused(tmp_path):
    path = _catalogue(tmp_path, object_toml("rod", "cylinder", "metal", 1e11, size_m=[0.02, 0.0215, 0.1]))
    assert "a cylinder is round" in _refusal(path)


def test_a_hex_prism_within_the_tolerance_of_its_across_corners_width_is_read(tmp_path):
    across_corners = 0.02 / 0.8660254037844386 * 1.019  # 1.9 % over, inside SECTION_TOLERANCE
    path = _catalogue(tmp_path, object_toml("nut", "hex", "metal", 1e11, size_m=[0.02, across_corners, 0.01]))
    assert read_toml_catalogue(path)[0].size_m == (0.02, across_corners, 0.01)


def test_a_table_radius_gives_no_size_to_a_box_or_an_irregular_object(tmp_path):
    path = tmp_path / "t.csv"
    path.write_text("Label,Shape,Material,Modulus [Pa],Radius [m]\n"
                    "brick,Rectangular,Ceramic,1e10,0.02\nnut,Irregular,Rubber,5e5,0.01\n", encoding="utf-8")
    assert [o.size_m for o in read_object_table(path)] == [None, None]


def test_a_table_notes_cell_is_the_objects_source(tmp_path):
    path = tmp_path / "t.csv"
    path.write_text("Label,Shape,Material,Modulus [Pa],Notes\nball,Sphere,Rubber,1e5, Shore A 40 \n", encoding="utf-8")
    assert read_object_table(path)[0].source == "Shore A 40"


def test_the_format_is_chosen_by_a_suffix_in_any_case(tmp_path):
    table = tmp_path / "T.CSV"
    table.write_text("Label,Shape,Material,Modulus [Pa]\nball,Sphere,Rubber,1e5\nbare,Box,Foam,0\n", encoding="utf-8")
    unlabelled: list[str] = []
    assert [o.name for o in load_catalogue(table, unlabelled=unlabelled)] == ["ball"] and unlabelled == ["bare"]
    toml = tmp_path / "OBJECTS.TOML"
    toml.write_text(object_toml("duck", "irregular", "rubber", 3.6e6), encoding="utf-8")
    assert [o.name for o in load_catalogue(toml)] == ["duck"]



HUGE = 10**400  # a TOML integer (a typo'd exponent) past the largest float


@pytest.mark.parametrize(("key", "modulus", "fields", "what"), [
    ("modulus_pa", HUGE, {}, "a number (Pa)"),
    ("poisson", 1e5, {"poisson": HUGE}, "a number"),
    ("texture_m", 1e5, {"texture_m": HUGE}, "a number (m)"),
    ("size_m", 1e5, {"size_m": [HUGE, 1, 1]}, "numbers (m)"),
], ids=["modulus_pa", "poisson", "texture_m", "size_m"])
def test_an_integer_too_large_for_a_float_is_refused_naming_the_key(tmp_path, key, modulus, fields, what):
    path = _catalogue(tmp_path, object_toml("ball", "sphere", "rubber", modulus, **fields))
    message = _refusal(path)
    assert message.startswith(f"{path}: objects[0] (ball): {key} ") and what in message, message
    assert str(HUGE) not in message  # not 401 digits in an error line


def test_unnamed_spare_columns_and_cells_past_the_header_are_ignored(tmp_path):
    """A spreadsheet export often ends its header with empty column names and its rows with spare cells."""
    path = tmp_path / "t.csv"
    path.write_text("Label,Shape,Material,Modulus [Pa],,\nball,Sphere,Rubber,1e5,,\nrod,Cylinder,Metal,2e11,,,x,y\n",
                    encoding="utf-8")
    assert [(o.name, o.modulus_pa) for o in read_object_table(path)] == [("ball", 1e5), ("rod", 2e11)]
