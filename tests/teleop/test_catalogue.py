"""Object catalogues: the shipped TOML, the published CSV table, malformed inputs."""

from __future__ import annotations

import json
import math
from collections import Counter

import pytest

from teleop import cli
from teleop.catalogue import (
    SHAPES,
    ObjectSpec,
    default_catalogue_path,
    load_catalogue,
    read_object_table,
    read_toml_catalogue,
)
from teleop.errors import SettingsError
from teleop.settings import load_settings

MATERIALS = ("rubber", "foam", "plastic", "wood", "metal", "glass", "food")


def test_default_catalogue_covers_materials_shapes_and_moduli():
    objects = load_catalogue()
    assert objects == read_toml_catalogue(default_catalogue_path())
    assert len(objects) >= 40
    assert set(Counter(o.material for o in objects)) == set(MATERIALS)
    assert set(Counter(o.shape for o in objects)) == set(SHAPES)
    moduli = [o.modulus_pa for o in objects]
    assert min(moduli) == pytest.approx(5e3) and max(moduli) == pytest.approx(2e11)
    # Every decade from 10 kPa to 100 GPa holds at least one object.
    decades = {math.floor(math.log10(e)) for e in moduli}
    assert set(range(4, 12)) <= decades


def test_default_catalogue_objects_fit_the_gripper_and_cite_sources():
    objects = load_catalogue()
    gripper = load_settings().gripper
    pad_rows_m, pad_cols_m = load_settings().sensor("left").pad_size_m
    for obj in objects:
        assert obj.size_m is not None, obj.name
        assert obj.size_m[0] < gripper.max_width_m, obj.name  # x lies along the squeeze axis
        assert obj.source, obj.name
    larger_than_pad = [o for o in objects if max(o.size_m[1:]) > max(pad_rows_m, pad_cols_m)]
    within_pad = [o for o in objects if max(o.size_m[1:]) < min(pad_rows_m, pad_cols_m)]
    assert len(larger_than_pad) >= 10 and within_pad
    # Rubbers are nearly incompressible, foams are not.
    assert all(o.poisson >= 0.45 for o in objects if o.material == "rubber")
    assert all(o.poisson <= 0.3 for o in objects if o.material == "foam")
    assert any(o.texture_m > 1e-4 for o in objects if o.material == "foam")


def test_published_table_reads_286_labelled_objects(object_table):
    objects = load_catalogue(object_table)
    assert objects == read_object_table(object_table)
    assert len(objects) == 286
    by_name = {o.name: o for o in objects}
    assert "racquet_ball" not in by_name  # modulus 0: unlabelled
    apple = by_name["apple"]
    assert (apple.shape, apple.material, apple.modulus_pa) == ("sphere", "food", 3.25e6)
    assert by_name["orange_elastic_ball"].size_m == pytest.approx((0.05, 0.05, 0.05))
    shapes = Counter(o.shape for o in objects)
    assert shapes["hex_prism"] == 6 and shapes["box"] == 44  # "Hex" and "Rectangular" normalised
    assert all(o.modulus_pa > 0 and math.isfinite(o.modulus_pa) for o in objects)
    assert min(o.modulus_pa for o in objects) == 5e3


def test_unlabelled_row_is_an_error_when_not_skipped(object_table):
    with pytest.raises(SettingsError, match=rf"{object_table}:257: object 'racquet_ball' has no usable"):
        read_object_table(object_table, skip_unlabelled=False)


def write(tmp_path, name, text):
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    return path


GOOD = """
[[objects]]
name = "duck"
shape = "irregular"
material = "Rubber"
modulus_pa = 3.6e6
poisson = 0.47
size_m = [0.06, 0.08, 0.075]
texture_m = 1e-6
source = "PVC Shore A 60"

[[objects]]
name = "block"
shape = "rectangular"
material = "wood"
modulus_pa = 12300000000
"""


def test_toml_catalogue_fields_and_defaults(tmp_path):
    duck, block = read_toml_catalogue(write(tmp_path, "c.toml", GOOD))
    assert duck == ObjectSpec("duck", "irregular", "rubber", 3.6e6, 0.47, (0.06, 0.08, 0.075), 1e-6, "PVC Shore A 60")
    assert (block.shape, block.modulus_pa, block.poisson, block.size_m, block.texture_m) == (
        "box", 1.23e10, 0.4, None, 0.0)


@pytest.mark.parametrize(
    ("edit", "expected"),
    [
        (('name = "duck"', ""), "key 'name' is missing"),
        (('source = "PVC Shore A 60"', 'source = "x"\ncolour = "yellow"'), "unknown key 'colour'"),
        (("modulus_pa = 3.6e6", 'modulus_pa = "stiff"'), "modulus_pa must be a number (Pa)"),
        (("modulus_pa = 3.6e6", "modulus_pa = true"), "modulus_pa must be a number (Pa)"),
        (("modulus_pa = 3.6e6", "modulus_pa = -1.0"), "modulus_pa must be finite and > 0"),
        (("modulus_pa = 3.6e6", "modulus_pa = nan"), "modulus_pa must be finite and > 0"),
        (('shape = "irregular"', 'shape = "torus"'), "shape 'torus' is not one of"),
        (('shape = "irregular"', "shape = 3"), "shape must be a string"),
        (("poisson = 0.47", "poisson = 0.7"), "poisson must be in [0, 0.5]"),
        (("size_m = [0.06, 0.08, 0.075]", "size_m = [0.06, 0.08]"), "size_m must be three extents"),
        (("size_m = [0.06, 0.08, 0.075]", 'size_m = [0.06, "big", 0.075]'), "size_m must hold numbers"),
        (("size_m = [0.06, 0.08, 0.075]", "size_m = 0.06"), "size_m must be an array"),
        (("texture_m = 1e-6", "texture_m = 0.01"), "texture_m must be in [0, 1e-3)"),
        (('name = "duck"', 'name = "block"'), "object name 'block' appears twice"),
    ],
)
def test_malformed_toml_catalogue_names_file_and_object(tmp_path, edit, expected):
    old, new = edit
    assert old in GOOD
    path = write(tmp_path, "bad.toml", GOOD.replace(old, new, 1))
    with pytest.raises(SettingsError) as info:
        read_toml_catalogue(path)
    assert str(path) in str(info.value) and expected in str(info.value), str(info.value)


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("", "expected one or more [[objects]] tables"),
        ("objects = [1, 2]\n", "objects[0]: expected an [[objects]] table"),
        ("[[objects]\nname = 1\n", "not valid TOML"),
    ],
)
def test_toml_catalogue_structure_errors(tmp_path, text, expected):
    path = write(tmp_path, "bad.toml", text)
    with pytest.raises(SettingsError, match=rf"{path}.*{expected.replace('[', '.').replace(']', '.')}"):
        read_toml_catalogue(path)


HEADER = "n,Label,Shape,Material,Modulus [Pa],Radius [m],Notes\n"


@pytest.mark.parametrize(
    ("rows", "expected"),
    [
        ("1,ball,Sphere,Rubber,abc,,\n", ":2: Modulus [Pa] 'abc' is not a number"),
        ("1,ball,Sphere,Rubber,1e5,,\n2,ball,Sphere,Rubber,2e5,,\n", "object name 'ball' appears twice"),
        ("1,ball,Sphere,Rubber,1e5,wide,\n", ":2: Radius [m] 'wide' is not a number"),
        ("1,,Sphere,Rubber,1e5,,\n", ":2: the Label column is empty"),
        ("1,ball,Torus,Rubber,1e5,,\n", ":2: shape 'Torus' is not one of"),
        ("1,ball,,Rubber,1e5\n", ":2: shape '' is not one of"),
        ("", "has a header but no rows"),
    ],
)
def test_malformed_object_table(tmp_path, rows, expected):
    path = write(tmp_path, "table.csv", HEADER + rows)
    with pytest.raises(SettingsError) as info:
        read_object_table(path)
    assert str(path) in str(info.value) and expected in str(info.value), str(info.value)


def test_object_table_short_rows_and_unlabelled_rows(tmp_path):
    # A short row (no Radius, no Notes) is fine; one with an empty or zero modulus is unlabelled.
    path = write(tmp_path, "table.csv", HEADER + "1,ball,Sphere,Rubber,1e5\n2,cup,Cylinder,Plastic,\n3,mug,Box,Glass,0\n")
    (ball,) = read_object_table(path)
    assert (ball.name, ball.modulus_pa, ball.size_m, ball.source) == ("ball", 1e5, None, "")
    with pytest.raises(SettingsError, match=r":3: object 'cup' has no usable Modulus"):
        read_object_table(path, skip_unlabelled=False)


@pytest.mark.parametrize(
    ("row", "expected"),
    [
        ("2,obj2,Sphere,Rubber,-5.6E+05,,\n", ":3: object 'obj2': Modulus [Pa] '-5.6E+05' is not a modulus; expected a finite number > 0"),
        ("2,obj2,Sphere,Rubber,nan,,\n", ":3: object 'obj2': Modulus [Pa] 'nan' is not a modulus"),
        ("2,obj2,Sphere,Rubber,-inf,,\n", ":3: object 'obj2': Modulus [Pa] '-inf' is not a modulus"),
        ("2,obj2,Sphere\n", ":3: the row ends before column 'Material'; expected cells for Label, Shape, Material, Modulus [Pa]"),
        ("2,obj2,Sphere,Rubber\n", ":3: the row ends before column 'Modulus [Pa]'"),
    ],
)
def test_a_bad_modulus_or_a_cut_row_is_refused_not_skipped_as_unlabelled(tmp_path, row, expected):
    path = write(tmp_path, "table.csv", HEADER + "1,ball,Sphere,Rubber,1e5,,\n" + row)
    with pytest.raises(SettingsError) as info:
        read_object_table(path)
    assert str(path) + expected in str(info.value), str(info.value)


def test_object_table_file_errors(tmp_path):
    path = write(tmp_path, "cols.csv", "Label,Shape\nball,Sphere\n")
    with pytest.raises(SettingsError, match="missing Material, Modulus"):
        read_object_table(path)
    latin1 = tmp_path / "latin1.csv"
    latin1.write_bytes(HEADER.encode() + b"1,b\xe9ll,Sphere,Rubber,1e5,,\n")
    with pytest.raises(SettingsError, match="not a readable UTF-8 CSV"):
        read_object_table(latin1)
    with pytest.raises(SettingsError, match="cannot read object table"):
        read_object_table(tmp_path / "absent.csv")
    with pytest.raises(SettingsError, match="cannot read catalogue"):
        load_catalogue(tmp_path / "absent.toml")
    with pytest.raises(SettingsError, match="unknown catalogue format"):
        load_catalogue(tmp_path / "objects.json")


def test_catalogue_command_json(tmp_path, capsys):
    path = write(tmp_path, "c.toml", GOOD)
    assert cli.main(["catalogue", str(path), "--json"]) == 0
    listing = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert [o["name"] for o in listing["objects"]] == ["duck", "block"]
    assert listing["objects"][0]["size_m"] == [0.06, 0.08, 0.075]
    assert cli.main(["catalogue", str(path)]) == 0
    table = capsys.readouterr().out.splitlines()
    assert table[0].split() == ["object", "shape", "material", "E"] and table[1].startswith("duck ")
    assert table[-1] == f"2 objects in {path}"
    assert cli.main(["catalogue", str(tmp_path / "absent.toml")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "cannot read catalogue" in err
