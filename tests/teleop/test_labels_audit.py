"""Labels: the edges the other label tests leave open (names, detail lengths, scales as typed, bus bodies)."""

from __future__ import annotations

from types import SimpleNamespace

import pytest

from teleop.labels import (
    MAX_OBJECT_NAME_CHARS,
    LabelError,
    ObjectLabel,
    catalogue_label,
    gent_modulus_pa,
    label_from_fields,
    modulus_label,
    parse_label,
    shore_label,
    shore_to_modulus_pa,
)


def spec(name="gel", material="silicone", modulus_pa=5e4, source=""):
    return SimpleNamespace(name=name, material=material, modulus_pa=modulus_pa, source=source)


@pytest.mark.parametrize("name", ["", "   ", "\t"])
def test_a_blank_object_name_is_refused(name):
    with pytest.raises(LabelError, match="expected 1 to 128 characters"):
        ObjectLabel(name, None, "catalogue")


def test_an_object_name_of_128_characters_is_the_longest_kept():
    assert ObjectLabel("x" * MAX_OBJECT_NAME_CHARS, None, "catalogue").object_name == "x" * 128
    with pytest.raises(LabelError, match="expected 1 to 128 characters"):
        ObjectLabel("x" * (MAX_OBJECT_NAME_CHARS + 1), None, "catalogue")


@pytest.mark.parametrize("modulus", ["5e4", b"5", [5e4]])
def test_a_modulus_that_is_not_a_number_is_refused_as_a_label_error(modulus):
    with pytest.raises(LabelError, match="expected a finite number > 0"):
        ObjectLabel("foam", modulus, "datasheet")


def test_the_bus_body_carries_the_modulus_as_a_float_and_the_grasp_given():
    body = ObjectLabel("foam", 50_000, "datasheet").body("grasp-7")
    assert body["grasp_id"] == "grasp-7" and body["object_name"] == "foam"
    assert type(body["modulus_pa"]) is float and body["modulus_pa"] == 5e4
    assert ObjectLabel("foam", None, "catalogue").body("g")["modulus_pa"] is None


def test_a_catalogue_label_names_the_entrys_source_and_is_cut_to_1024_characters():
    label = catalogue_label("gel", [spec(source="maker's sheet 12")], where="objects.toml")
    assert label.detail == "objects.toml: silicone, E 50000 Pa; maker's sheet 12"
    long = catalogue_label("gel", [spec(source="s" * 2000)])
    assert len(long.detail) == 1024 and long.detail.startswith("the catalogue: silicone, E 50000 Pa; sss")


def test_a_detail_given_in_the_fields_is_cut_to_1024_characters():
    label = label_from_fields("pad", modulus_pa="2e6", detail="d" * 1500)
    assert label.detail == "d" * 1024


def test_a_stated_modulus_keeps_the_detail_given():
    assert modulus_label("pad", 2e6, "measured", "tensile test 3").detail == "tensile test 3"


@pytest.mark.parametrize("source", ["catalogue", "durometer", "guess"])
def test_a_stated_modulus_with_another_source_is_refused(source):
    with pytest.raises(LabelError, match="source datasheet or measured"):
        modulus_label("pad", 2e6, source)


@pytest.mark.parametrize("modulus", [0.0, -5.0])
def test_a_stated_modulus_not_above_zero_is_refused_as_such(modulus):
    with pytest.raises(LabelError, match="expected a number > 0"):
        modulus_label("pad", modulus)


def test_the_stated_modulus_range_includes_its_ends():
    assert modulus_label("gel", 1.0).modulus_pa == 1.0
    assert modulus_label("diamond", 1e12).modulus_pa == 1e12


@pytest.mark.parametrize("scale", [" a ", "a", "00 ", " oo", "Oo"])
def test_a_scale_is_read_whatever_its_case_and_surrounding_spaces(scale):
    value = 40 if scale.strip().lower() == "a" else 86
    assert shore_to_modulus_pa(value, scale) == pytest.approx(gent_modulus_pa(40))
    assert shore_label("pad", value, scale).modulus_pa == pytest.approx(gent_modulus_pa(40))


@pytest.mark.parametrize("value", ["hard", None, float("inf")])
def test_a_shore_reading_that_is_not_a_finite_number_is_refused_as_a_label_error(value):
    with pytest.raises(LabelError, match="not a"):
        shore_label("pad", value, "A")


def test_a_shore_00_field_is_read_on_the_00_scale():
    label = label_from_fields("pad", shore_00="70")
    assert label.modulus_pa == pytest.approx(gent_modulus_pa(20)) and "Shore 00 70" in label.detail
    assert label_from_fields("pad", shore_a="70").modulus_pa == pytest.approx(gent_modulus_pa(70))


def test_blank_fields_count_as_absent():
    label = label_from_fields(" gel ", catalogue=[spec()], modulus_pa=" ", shore_a="", source=" ")
    assert (label.object_name, label.source, label.modulus_pa) == ("gel", "catalogue", 5e4)
    assert label_from_fields("pad", modulus_pa="3e5", shore_00="  ", source=" measured ").source == "measured"


def test_all_three_readings_at_once_are_refused():
    with pytest.raises(LabelError, match="modulus_pa and shore_a and shore_00 are both given"):
        label_from_fields("pad", modulus_pa="2e6", shore_a="40", shore_00="60")


def test_a_modulus_field_with_source_durometer_is_refused():
    with pytest.raises(LabelError, match="source durometer takes its modulus from a Shore reading"):
        label_from_fields("pad", modulus_pa="2e6", source="durometer")


def test_typed_text_with_runs_of_spaces_is_read_as_single_spaces():
    label = parse_label("blue   gel  pad   12  MPa", [spec()])
    assert (label.object_name, label.modulus_pa) == ("blue gel pad", 1.2e7)
    assert parse_label("gel\t", [spec()]).source == "catalogue"


def test_a_catalogue_name_that_reads_as_a_hardness_is_the_catalogue_entry():
    # "stopper a 40" is a catalogue object here: its entry wins over the Shore syntax.
    label = parse_label("stopper a 40", [spec(name="stopper a 40", modulus_pa=3e6)])
    assert (label.source, label.modulus_pa) == ("catalogue", 3e6)


def test_a_typed_source_is_read_whatever_its_case():
    assert parse_label("cork 12 MPa MEASURED").source == "measured"
    assert parse_label("cork 12 MPa Datasheet").source == "datasheet"


def test_a_typed_modulus_in_gpa_and_with_a_negative_exponent():
    assert parse_label("steel 200 GPa").modulus_pa == pytest.approx(2e11)
    assert parse_label("gel 5e-1 kPa").modulus_pa == pytest.approx(500.0)


def test_a_typed_name_keeps_a_trailing_word_that_looks_like_a_scale():
    # The shortest name before the scale: "pad a" reading 00 60, not a name "pad a 00" and a reading A 60.
    label = parse_label("pad a 00 60")
    assert label.object_name == "pad a" and "Shore 00 60" in label.detail


def test_typed_text_with_words_after_the_modulus_is_not_a_label():
    with pytest.raises(LabelError, match="is not in the catalogue"):
        parse_label("cork 12 MPa guessed")


def test_an_unknown_typed_name_suggests_the_close_ones():
    with pytest.raises(LabelError, match="did you mean gel"):
        parse_label("gell", [spec()])
