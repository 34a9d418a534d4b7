"""Labels: the Shore hardness model (Gent's relation, the A/00 table), label builders, the console syntax."""

from __future__ import annotations

import pytest

from teleop.catalogue import load_catalogue
from teleop.labels import (
    LABEL_SOURCES,
    LabelError,
    ObjectLabel,
    catalogue_label,
    describe_label,
    gent_modulus_pa,
    label_from_fields,
    modulus_label,
    parse_label,
    shore_00_to_a,
    shore_label,
    shore_to_modulus_pa,
)


@pytest.fixture(scope="module")
def catalogue():
    return load_catalogue()


@pytest.mark.parametrize(
    ("shore_a", "modulus_pa"),
    [
        # worked by hand from E = 0.0981 (56 + 7.62336 S) / (0.137505 (254 - 2.54 S)) MPa
        (10, 0.41268e6),
        (40, 1.68964e6),  # the catalogue's rubber_band_ball, "Shore A 40 (Gent relation)"
        (50, 2.45581e6),  # vinyl_eraser, Shore A 50
        (80, 9.35137e6),  # bouncy_ball
        (90, 20.8440e6),  # the end of the range
    ],
)
def test_gent_relation_gives_the_published_values(shore_a, modulus_pa):
    assert gent_modulus_pa(shore_a) == pytest.approx(modulus_pa, rel=1e-4)
    assert shore_to_modulus_pa(shore_a, "A") == gent_modulus_pa(shore_a)


def test_the_catalogues_gent_rubbers_agree(catalogue):
    by_name = {spec.name: spec for spec in catalogue}
    assert gent_modulus_pa(40) == pytest.approx(by_name["rubber_band_ball"].modulus_pa, rel=2e-3)
    assert gent_modulus_pa(50) == pytest.approx(by_name["vinyl_eraser"].modulus_pa, rel=2e-3)


def test_shore_00_goes_through_the_comparison_table():
    # table points: 00 45 = A 5, 00 70 = A 20, 00 86 = A 40, 00 90 = A 50
    assert shore_00_to_a(45) == 5.0 and shore_00_to_a(70) == 20.0 and shore_00_to_a(86) == 40.0
    assert shore_00_to_a(90) == 50.0
    assert shore_00_to_a(66) == pytest.approx(15 + 5 * 4 / 8)  # between 00 62 (A 15) and 00 70 (A 20)
    assert shore_to_modulus_pa(86, "00") == pytest.approx(gent_modulus_pa(40))
    assert shore_to_modulus_pa(45, "OO") == pytest.approx(0.27827e6, rel=1e-4)  # A 5, below A's own range
    moduli = [shore_to_modulus_pa(s, "00") for s in range(45, 91)]
    assert moduli == sorted(moduli)  # monotone


@pytest.mark.parametrize(
    ("value", "scale", "says"),
    [
        (9.5, "A", "Shore A 9.5 is outside 10 to 90"),
        (5, "A", "measure it on the Shore 00 scale"),
        (95, "A", "Shore D"),
        (30, "00", "Shore 00 30 is outside 45 to 90"),
        (30, "00", "give the maker's modulus"),
        (95, "00", "measure it on the Shore A scale"),
        ("soft", "A", "Shore A 'soft' is not a number"),
        (float("nan"), "A", "not a finite number"),
        (40, "D", "Shore scale 'D': expected A or 00"),
    ],
)
def test_readings_outside_the_model_are_refused_clearly(value, scale, says):
    with pytest.raises(LabelError) as info:
        shore_to_modulus_pa(value, scale)
    assert says in str(info.value)


def test_labels_from_the_catalogue_a_reading_or_a_modulus(catalogue):
    label = catalogue_label("stress_ball", catalogue, where="objects.toml")
    assert label == ObjectLabel("stress_ball", 4.0e4, "catalogue", label.detail)
    assert label.detail.startswith("objects.toml: foam, E 40000 Pa")
    label = shore_label("gel pad", 70, "00")
    assert label.source == "durometer" and label.modulus_pa == pytest.approx(gent_modulus_pa(20))
    assert "Shore 00 70 = Shore A 20" in label.detail and "Gent" in label.detail
    assert modulus_label("cork", 1.2e7).source == "datasheet"
    assert modulus_label("cork", 1.2e7, "measured").detail == "measured: E 1.2e+07 Pa"
    assert label.body("g1") == {"grasp_id": "g1", "object_name": "gel pad", "modulus_pa": label.modulus_pa,
                                "source": "durometer", "detail": label.detail}
    assert describe_label(catalogue_label("stress_ball", catalogue)) == "stress_ball  E 40 kPa  (catalogue)"
    assert describe_label(modulus_label("pad", 999_600.0)) == "pad  E 1 MPa  (datasheet)"  # not "1e+03 kPa"
    assert set(LABEL_SOURCES) == {"catalogue", "durometer", "datasheet", "measured"}
    with pytest.raises(LabelError, match="'stres_ball' is not in objects.toml \\(did you mean stress_ball"):
        catalogue_label("stres_ball", catalogue, where="objects.toml")
    with pytest.raises(LabelError, match="expected a finite number > 0"):
        ObjectLabel("x", -1.0, "datasheet")
    with pytest.raises(LabelError, match="label source 'guess'"):
        ObjectLabel("x", 1.0, "guess")
    # A typo'd exponent ("1e30 MPa") would go into the log as the grasp's truth, and into retraining.
    for absurd in (1e36, 2e12, 0.1):
        with pytest.raises(LabelError, match="expected 1 to 1e\\+12 Pa \\(diamond's modulus at most\\)"):
            modulus_label("cork mat", absurd)
    assert modulus_label("steel", 2e11).modulus_pa == 2e11 and modulus_label("hydrogel", 500.0).modulus_pa == 500.0


def test_csv_fields_choose_the_source_and_refuse_conflicts(catalogue):
    assert label_from_fields("stress_ball", catalogue=catalogue).source == "catalogue"
    assert label_from_fields("pad", modulus_pa="2e6").source == "datasheet"
    assert label_from_fields("pad", modulus_pa="2e6", source="measured").source == "measured"
    assert label_from_fields("pad", shore_a="40").modulus_pa == pytest.approx(gent_modulus_pa(40))
    assert label_from_fields("pad", shore_00="86", source="durometer").source == "durometer"
    # a Shore reading of a catalogue object: the reading wins
    assert label_from_fields("stress_ball", catalogue=catalogue, shore_00="60").source == "durometer"
    assert label_from_fields("pad", modulus_pa="2e6", detail="lab sheet 7").detail == "lab sheet 7"
    for fields, says in [
        ({"modulus_pa": "2e6", "shore_a": "40"}, "modulus_pa and shore_a are both given"),
        ({"modulus_pa": "two"}, "modulus_pa 'two' is not a number"),
        ({"modulus_pa": "-3"}, "expected a number > 0"),
        ({"modulus_pa": "2e6", "source": "catalogue"}, "leave modulus_pa empty"),
        ({"shore_a": "40", "source": "datasheet"}, "does not fit"),
        ({"source": "durometer"}, "needs a Shore hardness"),
        ({"source": "wild guess"}, "source 'wild guess'"),
        ({}, "'pad' is not in the catalogue"),
    ]:
        with pytest.raises(LabelError) as info:
            label_from_fields("pad", catalogue=catalogue, **fields)
        assert says in str(info.value), (fields, str(info.value))
    with pytest.raises(LabelError, match="the object is empty"):
        label_from_fields("  ")


def test_what_an_operator_types(catalogue):
    assert parse_label("stress_ball", catalogue).source == "catalogue"
    assert parse_label("  Stress_Ball ", catalogue).object_name == "stress_ball"
    for text, scale, value in [("blue gel shore 00 60", "00", 60), ("pad shore A 40", "A", 40), ("pad A40", "A", 40),
                               ("pad 00-86", "00", 86), ("pad OO 86", "00", 86), ("Pad SHORE a 55.5", "A", 55.5)]:
        label = parse_label(text, catalogue)
        assert label.source == "durometer" and label.modulus_pa == pytest.approx(shore_to_modulus_pa(value, scale))
    assert parse_label("blue gel shore 00 60", catalogue).object_name == "blue gel"
    cork = parse_label("cork mat 12 MPa", catalogue)
    assert (cork.object_name, cork.modulus_pa, cork.source) == ("cork mat", 1.2e7, "datasheet")
    assert parse_label("cork 120 kPa measured", catalogue).source == "measured"
    assert parse_label("cork 1.5e5 pa", catalogue).modulus_pa == 1.5e5
    with pytest.raises(LabelError, match="did you mean stress_ball"):
        parse_label("stress ball", catalogue)
    with pytest.raises(LabelError, match="Shore 00 20 is outside"):
        parse_label("gel shore 00 20", catalogue)
    with pytest.raises(LabelError, match="type the object's name"):
        parse_label("   ", catalogue)


@pytest.mark.parametrize("modulus", [0, 0.0, -1.0, float("nan"), float("inf")])
def test_a_label_with_a_modulus_not_above_zero_or_not_finite_is_refused(modulus):
    with pytest.raises(LabelError, match="expected a finite number > 0"):
        ObjectLabel("foam", modulus, "datasheet")


def test_a_label_is_made_with_a_positive_modulus_or_none():
    assert ObjectLabel("foam", 5e4, "datasheet").modulus_pa == 5e4
    assert ObjectLabel("foam", None, "catalogue").modulus_pa is None


@pytest.mark.parametrize("typed, modulus_pa", [("foam 120 kPa", 120e3), ("foam 120 Pa", 120.0),
                                               ("rubber 2 MPa", 2e6), ("foam E=1.5e2 kpa measured", 150e3)])
def test_a_typed_modulus_is_read_in_its_unit(typed, modulus_pa):
    assert parse_label(typed).modulus_pa == pytest.approx(modulus_pa)
