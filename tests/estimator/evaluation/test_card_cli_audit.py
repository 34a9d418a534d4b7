"""``estimator card`` at its edges: labels, sources, the block's markers, --check's findings, --keep's files."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

import teleop.staging as staging
from estimator.cli import main
from estimator.errors import EstimatorError
from estimator.evaluation import card_cli
from estimator.evaluation.card_cli import (
    BEGIN,
    COLUMNS,
    END,
    Source,
    check_block,
    load_source,
    recorded_sources,
    render_block,
    table_rows,
)

HEADINGS = [heading for heading, _ in COLUMNS]
FIGURES = {"n": 4, "felt_log10_error": 0.25, "felt_within_2x": 0.5, "dangerous_misses": 0, "shown_unknown": 1,
           "rigid_shown_rigid": 1.0, "interval_level": 0.9, "interval_coverage": 0.75, "soft_n": 2,
           "soft_felt_log10_error": 0.5, "soft_felt_within_2x": 0.0, "soft_interval_coverage": 0.0,
           "soft_interval_width_decades_median": 1.5, "per_material": {"rubber": {"n": 4}}}


def result(methods=None, **fields) -> dict:
    return {"command": "estimator evaluate runs/r --json", "dir": "runs/r", "records": 4, "labelled": 4,
            "display_range_pa": [5e3, 6.75e6], "methods": {"series": dict(FIGURES)} if methods is None else methods,
            **fields}


def write(path: Path, content: dict | str) -> Path:
    path.write_text(content if isinstance(content, str) else "progress\n" + json.dumps(content) + "\n")
    return path


def cells_of(rows, method: str = "series") -> dict[str, str]:
    return dict(zip(HEADINGS, next(cells for _, name, cells in rows if name == method), strict=True))


@pytest.fixture
def card(tmp_path):
    path = tmp_path / "CARD.md"
    path.write_text(f"# Card\n\n{BEGIN}\n{END}\n\nTail.\n")
    return path


# --------------------------------------------------------------------------- figures as cells


def test_a_share_or_coverage_of_zero_is_written_as_zero_not_as_missing(tmp_path):
    cells = cells_of(table_rows([Source("A", tmp_path / "a.json", result())]))
    assert cells["soft within 2x"] == "0.0 %"
    assert cells["soft coverage (stated)"] == "0.0 % (90 %)"
    assert cells["dangerous"] == "0"
    assert cells["coverage (stated)"] == "75.0 % (90 %)" and cells["rigid shown rigid"] == "100.0 %"


def test_a_coverage_without_its_level_is_written_with_a_dash_for_the_level(tmp_path):
    figures = {k: v for k, v in FIGURES.items() if k != "interval_level"}
    cells = cells_of(table_rows([Source("A", tmp_path / "a.json", result({"series": figures}))]))
    assert cells["coverage (stated)"] == "75.0 % (-)"


def test_a_figure_of_the_wrong_type_is_an_error_naming_the_file_method_and_column(tmp_path, card, capsys):
    source = write(tmp_path / "bad.json", result({"series": {**FIGURES, "soft_n": 2.5}}))
    before = card.read_text()
    assert main(["card", str(card), "--figures", f"A={source}"]) == 2
    err = capsys.readouterr().err
    assert str(source) in err and "series" in err and "soft n" in err
    assert card.read_text() == before


def test_a_method_that_is_not_an_object_of_figures_is_an_error_naming_it(tmp_path, card, capsys):
    source = write(tmp_path / "bad.json", result({"series": 3}))
    assert main(["card", str(card), "--figures", f"A={source}"]) == 2
    err = capsys.readouterr().err
    assert str(source) in err and "'series'" in err


def test_a_model_that_is_not_a_folder_name_is_an_error_naming_it(tmp_path, card, capsys):
    source = write(tmp_path / "bad.json", result({"hybrid": {**FIGURES, "model": 7}}))
    assert main(["card", str(card), "--figures", f"A={source}"]) == 2
    assert f"{source}: method 'hybrid', model: expected a folder name or null, got 7" in capsys.readouterr().err


def test_a_malformed_display_range_is_an_error_naming_it(tmp_path, card, capsys):
    source = write(tmp_path / "bad.json", result(display_range_pa=[5e3]))
    assert main(["card", str(card), "--figures", f"A={source}"]) == 2
    assert f"{source}: display_range_pa" in capsys.readouterr().err


def test_a_source_holding_nan_is_refused_by_name_before_keep_writes_anything(tmp_path, card, capsys):
    source = write(tmp_path / "nan.json", "progress\n" + json.dumps(result()).replace("0.25", "NaN") + "\n")
    keep = tmp_path / "kept"
    assert main(["card", str(card), "--figures", f"A={source}", "--keep", str(keep)]) == 2
    assert f"{source}: not an estimator evaluate --json output" in capsys.readouterr().err
    assert not keep.exists()


def test_an_empty_display_range_and_a_missing_command_write_neither(tmp_path, card):
    source = Source("A", tmp_path / "a.json", {**result(display_range_pa=[]), "command": None})
    block = render_block([source], card=card)
    assert "display" not in block and "made by" not in block
    assert "- A: `a.json`, 4 grasps scored of 4 records." in block


# --------------------------------------------------------------------------- labels and sources


@pytest.mark.parametrize("label", ["a|b", "a -- b", "a\nb", "   ", "E=3"])
def test_a_label_that_would_break_the_table_is_refused_with_it(tmp_path, label):
    path = write(tmp_path / "a.json", result())
    with pytest.raises(EstimatorError, match="figures label"):
        load_source(label, path)


def test_a_label_is_stripped_of_surrounding_spaces(tmp_path):
    assert load_source("  Sim rig  ", write(tmp_path / "a.json", result())).label == "Sim rig"


def test_the_json_on_the_last_non_empty_line_is_read(tmp_path):
    path = write(tmp_path / "a.json", "progress\n" + json.dumps(result()) + "\n\n  \n")
    assert load_source("A", path).result["records"] == 4


@pytest.mark.parametrize("content", ["", '{"methods": ["series"]}\n', "[1, 2]\n"], ids=["empty", "list", "not-object"])
def test_a_file_that_is_no_evaluate_output_is_refused_naming_it(tmp_path, content):
    path = write(tmp_path / "a.json", content)
    with pytest.raises(EstimatorError, match=f"{path}: not an estimator evaluate --json output"):
        load_source("A", path)


@pytest.mark.parametrize("spec", ["=a.json", "A=", "  =a.json", "no-equals"])
def test_a_figures_spec_without_label_or_path_is_refused_with_it(tmp_path, card, capsys, spec):
    assert main(["card", str(card), "--figures", spec]) == 2
    assert f"--figures {spec!r}: expected LABEL=PATH" in capsys.readouterr().err


# --------------------------------------------------------------------------- methods


def test_a_method_name_picks_its_variants_only_and_each_once(tmp_path):
    methods = {"hybrid": dict(FIGURES), "hybrid[depth]": dict(FIGURES), "hybridx": dict(FIGURES)}
    source = Source("A", tmp_path / "a.json", result(methods))
    assert [name for _, name, _ in table_rows([source], ["hybrid"])] == ["hybrid", "hybrid[depth]"]
    assert [name for _, name, _ in table_rows([source], ["hybrid", "hybrid[depth]"])] == ["hybrid", "hybrid[depth]"]


def test_a_learned_method_is_named_by_its_model_folder_without_its_variant(tmp_path):
    methods = {"hybrid[depth]": {**FIGURES, "model": "runs/models/small/"}}
    rows = table_rows([Source("A", tmp_path / "a.json", result(methods))])
    assert [name for _, name, _ in rows] == ["hybrid (small)"]


def test_methods_given_without_figures_replace_the_recorded_ones(tmp_path, card):
    source = write(tmp_path / "a.json", result({"series": dict(FIGURES), "hybrid": dict(FIGURES)}))
    assert main(["card", str(card), "--figures", f"A={source}", "--methods", "hybrid"]) == 0
    assert main(["card", str(card), "--methods", "series"]) == 0
    text = card.read_text()
    assert "| A | series |" in text and "| A | hybrid |" not in text
    assert recorded_sources(text, card)[1] == ["series"]


def test_recorded_methods_that_are_not_a_list_of_names_are_an_error_naming_the_line(tmp_path, card, capsys):
    source = write(tmp_path / "a.json", result())
    assert main(["card", str(card), "--figures", f"A={source}", "--methods", "series"]) == 0
    card.write_text(card.read_text().replace('"methods": ["series"]', '"methods": "series"'))
    assert main(["card", str(card), "--check"]) == 2
    assert "'methods' is not a list of names" in capsys.readouterr().err


# --------------------------------------------------------------------------- the block's markers


@pytest.mark.parametrize("text", [f"{END}\n{BEGIN}\n", f"{BEGIN}\n{BEGIN}\n{END}\n", f"{BEGIN}\n{END}\n{END}\n"],
                         ids=["end-first", "two-begins", "two-ends"])
def test_markers_out_of_order_or_repeated_are_refused_and_nothing_is_written(tmp_path, text, capsys):
    source = write(tmp_path / "a.json", result())
    card = tmp_path / "c.md"
    card.write_text(text)
    assert main(["card", str(card), "--figures", f"A={source}"]) == 2
    assert "expected one '<!-- figures:begin -->' line" in capsys.readouterr().err
    assert card.read_text() == text


def test_indented_marker_and_sources_lines_are_still_found(tmp_path, card):
    source = write(tmp_path / "a.json", result())
    assert main(["card", str(card), "--figures", f"A={source}"]) == 0
    indented = "\n".join("  " + line if line.startswith("<!--") else line for line in card.read_text().splitlines())
    card.write_text(indented + "\n")
    assert recorded_sources(card.read_text(), card)[0] == [("A", card.parent / "a.json")]
    assert main(["card", str(card)]) == 0


def test_the_text_after_the_block_keeps_its_own_line(tmp_path):
    card = tmp_path / "c.md"
    card.write_text(f"Head\n{BEGIN}\nold\n{END}\nTail\n")
    assert card_cli.replace_block(card.read_text(), f"{BEGIN}\nnew\n{END}", card=card) == \
        f"Head\n{BEGIN}\nnew\n{END}\nTail\n"


# --------------------------------------------------------------------------- --check's findings


def _block(tmp_path, card, methods=None, **fields) -> str:
    return render_block([Source("A", tmp_path / "a.json", result(methods, **fields))], card=card)


def test_check_names_a_row_missing_from_the_card_and_one_the_jsons_lack(tmp_path, card):
    both = _block(tmp_path, card, {"series": dict(FIGURES), "hybrid": dict(FIGURES)})
    one = _block(tmp_path, card, {"series": dict(FIGURES)})
    assert check_block(one, both) == ["A / hybrid: row missing from the card"]
    assert check_block(both, one) == ["A / hybrid: row in the card, not in the JSONs"]


def test_check_names_a_cell_the_card_lacks(tmp_path, card):
    expected = _block(tmp_path, card)
    row = next(line for line in expected.splitlines() if line.startswith("| A | series |"))
    current = expected.replace(row, row.rsplit(" | ", 1)[0] + " |")  # the last cell cut off
    assert check_block(current, expected) == [f"A / series / {HEADINGS[-1]}: card says (nothing), the JSON gives "
                                              "75.0 % (90 %)"]


def test_check_fails_when_only_a_command_or_the_header_differs(tmp_path, card, capsys):
    expected = _block(tmp_path, card)
    other_lines = "the block's other lines (sources, commands) differ from what the JSONs give"
    assert check_block(expected.replace("runs/r --json", "runs/s --json"), expected) == [other_lines]
    assert check_block(expected.replace("| soft n |", "| soft count |"), expected) == [other_lines]
    source = write(tmp_path / "a.json", result())
    assert main(["card", str(card), "--figures", f"A={source}"]) == 0
    write(source, result(command="estimator evaluate runs/other --json"))
    capsys.readouterr()
    assert main(["card", str(card), "--check"]) == 1
    assert other_lines in capsys.readouterr().err


def test_check_with_keep_writes_nothing_and_checks_the_recorded_sources(tmp_path, card):
    source = write(tmp_path / "a.json", result())
    assert main(["card", str(card), "--figures", f"A={source}"]) == 0
    before = card.read_bytes()
    keep = tmp_path / "kept"
    assert main(["card", str(card), "--check", "--keep", str(keep)]) == 0
    assert not keep.exists() and card.read_bytes() == before


# --------------------------------------------------------------------------- --keep's files


def test_kept_copies_are_named_by_a_trimmed_slug_and_record_their_origin(tmp_path, card):
    source = write(tmp_path / "a.json", result())
    keep = tmp_path / "deep" / "er" / "kept"  # parents made too
    assert main(["card", str(card), "--figures", f"(Sim rig)={source}", "--keep", str(keep)]) == 0
    kept = json.loads((keep / "sim-rig.json").read_text())
    assert kept["kept_from"] == str(source) and kept["label"] == "(Sim rig)"
    assert set(kept["methods"]["series"]) == set(FIGURES) - {"per_material"}


def test_two_labels_giving_one_file_name_are_refused_before_anything_is_written(tmp_path, card, capsys):
    source = write(tmp_path / "a.json", result())
    keep = tmp_path / "kept"
    before = card.read_bytes()
    assert main(["card", str(card), "--figures", f"Sim rig={source}", "--figures", f"sim-rig={source}",
                 "--keep", str(keep)]) == 2
    assert "--keep: two labels give one file name (sim-rig, sim-rig)" in capsys.readouterr().err
    assert not keep.exists() and card.read_bytes() == before


def test_keep_refuses_an_unreadable_file_in_the_way_and_overwrite_replaces_it(tmp_path, card, capsys):
    source = write(tmp_path / "a.json", result())
    keep = tmp_path / "kept"
    keep.mkdir()
    (keep / "a.json").write_bytes(b"\xff\xfe not text")
    assert main(["card", str(card), "--figures", f"A={source}", "--keep", str(keep)]) == 2
    assert f"{keep / 'a.json'} exists" in capsys.readouterr().err
    assert (keep / "a.json").read_bytes() == b"\xff\xfe not text"
    assert main(["card", str(card), "--figures", f"A={source}", "--keep", str(keep), "--overwrite"]) == 0
    assert json.loads((keep / "a.json").read_text())["kept_from"] == str(source)


def test_the_card_is_renamed_into_place_after_its_copies(tmp_path, card, monkeypatch):
    source = write(tmp_path / "a.json", result())
    moved = []
    real_replace = staging.os.replace
    monkeypatch.setattr(staging.os, "replace", lambda src, dst: (moved.append(Path(dst)), real_replace(src, dst)))
    assert main(["card", str(card), "--figures", f"A={source}", "--keep", str(tmp_path / "kept")]) == 0
    assert moved == [tmp_path / "kept" / "a.json", card]
