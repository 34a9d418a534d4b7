"""Object catalogues: tables that would silently lose objects, extents, materials and moduli the
simulator would ignore or choke on, and the listing's count of unlabelled rows."""

from __future__ import annotations

import json

import pytest

from teleop import cli
from teleop.catalogue import ObjectSpec, load_catalogue, read_object_table, read_toml_catalogue
from teleop.errors import SettingsError

# teleop.catalogue.MATERIALS and MODULUS_RANGE_PA, spelt out: the errors must list them.
MATERIALS = ("rubber", "foam", "plastic", "wood", "metal", "glass", "food", "ceramic", "paper")
MODULUS_RANGE_PA = (1.0, 1e12)


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


def _one_object(tmp_path, *, material="rubber", modulus="1e5", shape="sphere", size="[0.03, 0.03, 0.03]",
                extra=""):
    path = tmp_path / "objects.toml"
    path.write_text(f'[[objects]]\nname = "ball"\nshape = "{shape}"\nmaterial = "{material}"\n'
                    f"modulus_pa = {modulus}\nsize_m = {size}\n{extra}", encoding="utf-8")
    return path


@pytest.mark.parametrize("material", ["fome", "rubber ball", "", "cork"])
def test_a_material_the_simulator_does_not_know_is_refused(tmp_path, material):
    path = _one_object(tmp_path, material=material)
    with pytest.raises(SettingsError) as info:
        read_toml_catalogue(path)
    text = str(info.value)
    assert f"{path}: objects[0] (ball): material {material!r} is not one of " in text, text
    assert all(m in text for m in MATERIALS), text


def test_a_padded_or_capitalised_material_is_read_as_the_known_one(tmp_path):
    (obj,) = read_toml_catalogue(_one_object(tmp_path, material=" Foam "))
    assert obj.material == "foam"


def test_the_materials_cover_the_simulator_and_the_published_table(object_table):
    from teleop import catalogue
    from teleop.sim.grasp import DENSIFICATION_STRAIN
    from teleop.sim.shapes import TEXTURE_BY_MATERIAL_M

    assert catalogue.MATERIALS == MATERIALS and catalogue.MODULUS_RANGE_PA == MODULUS_RANGE_PA
    assert set(TEXTURE_BY_MATERIAL_M) == set(MATERIALS)  # every material has its own texture
    assert set(DENSIFICATION_STRAIN) <= set(MATERIALS)
    assert {o.material for o in read_object_table(object_table)} <= set(MATERIALS)
    assert {o.material for o in load_catalogue()} <= set(MATERIALS)


def test_an_unknown_top_level_table_is_refused(tmp_path):
    path = _one_object(tmp_path, extra='\n[[object]]\nname = "lost"\nshape = "box"\nmaterial = "wood"\n'
                                         "modulus_pa = 1e10\n")
    with pytest.raises(SettingsError, match=r"objects.toml: unknown top-level key or table 'object'"):
        read_toml_catalogue(path)
    path.write_text('title = "mine"\n' + path.read_text(encoding="utf-8").split("\n[[object]]")[0], encoding="utf-8")
    with pytest.raises(SettingsError, match=r"objects.toml: unknown top-level key or table 'title'"):
        read_toml_catalogue(path)


@pytest.mark.parametrize("modulus", ["1e-20", "0.5", "2e12"])
def test_an_implausible_modulus_is_refused(tmp_path, modulus):
    path = _one_object(tmp_path, modulus=modulus)
    with pytest.raises(SettingsError) as info:
        read_toml_catalogue(path)
    text = str(info.value)
    assert f"{path}: objects[0] (ball)" in text and "modulus_pa" in text, text
    assert f"outside the plausible range {MODULUS_RANGE_PA[0]:g} to {MODULUS_RANGE_PA[1]:g} Pa" in text, text


def test_an_implausible_table_modulus_is_refused(tmp_path):
    path = tmp_path / "t.csv"
    path.write_text("Label,Shape,Material,Modulus [Pa]\nA,Sphere,Rubber,1e6\nB,Box,Foam,1e-20\n")
    with pytest.raises(SettingsError, match=r"t.csv:3: object 'B': Modulus \[Pa\] '1e-20' is outside the plausible"):
        read_object_table(path)


def test_the_shipped_moduli_are_plausible(object_table):
    low, high = MODULUS_RANGE_PA
    for obj in (*load_catalogue(), *read_object_table(object_table)):
        assert low <= obj.modulus_pa <= high, obj.name


def test_a_sphere_whose_extents_differ_is_refused(tmp_path):
    path = _one_object(tmp_path, size="[0.02, 0.06, 0.06]")
    with pytest.raises(SettingsError) as info:
        read_toml_catalogue(path)
    text = str(info.value)
    assert f"{path}: objects[0] (ball): size_m [0.02, 0.06, 0.06]: a sphere's three extents are its diameter" in text
    assert "expected [0.02, 0.02, 0.02] m" in text, text
    # Rounded to 0.1 mm, within SECTION_TOLERANCE: read.
    (obj,) = read_toml_catalogue(_one_object(tmp_path, size="[0.0300, 0.0301, 0.0299]"))
    assert obj.size_m == (0.03, 0.0301, 0.0299)


def test_an_incompressible_object_with_poisson_half_is_accepted():
    """Rubbers and gels are close to incompressible: Poisson's ratio 0.5 is inside [0, 0.5]."""
    assert ObjectSpec("gel", "sphere", "silicone", 5e4, poisson=0.5).poisson == 0.5


@pytest.mark.parametrize("poisson", [-0.01, 0.51])
def test_a_poisson_ratio_outside_0_to_half_is_refused(poisson):
    with pytest.raises(ValueError, match="poisson must be in"):
        ObjectSpec("gel", "sphere", "silicone", 5e4, poisson=poisson)


@pytest.mark.parametrize("size_m", [(0.0, 0.02, 0.02), (0.02, -0.01, 0.02), (0.02, 0.02, 1.0)])
def test_an_extent_not_inside_0_to_1_m_is_refused(size_m):
    with pytest.raises(ValueError, match="size_m must be three extents"):
        ObjectSpec("block", "box", "foam", 5e4, size_m=size_m)


def test_a_table_radius_becomes_the_diameter_of_spheres_and_cylinders(tmp_path):
    path = tmp_path / "objects.csv"
    path.write_text("Label,Shape,Material,Modulus [Pa],Radius [m]\n"
                    "ball,sphere,foam,50000,0.01\nrod,cylinder,rubber,1000000,0.005\n", encoding="utf-8")
    ball, rod = read_object_table(path)
    assert ball.size_m == pytest.approx((0.02, 0.02, 0.02))
    assert rod.size_m == pytest.approx((0.01, 0.01, 0.01))
