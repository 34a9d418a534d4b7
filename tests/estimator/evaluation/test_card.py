"""``estimator card``: the model card's figures table is written from evaluate's JSON and checked against it."""

from __future__ import annotations

import errno
import json
import re
from pathlib import Path

import pytest

from estimator.cli import main
from estimator.evaluation.card_cli import BEGIN, COLUMNS, END, SHIPPED_CARD, recorded_sources
from estimator.evaluation.metrics import summarise

DISPLAY = (5e3, 6.75e6)


def _row(method: str, truth_pa: float, e_pa: float, state: str = "ok", spread: float = 2.0) -> dict:
    return {"path": f"{method}-{truth_pa:g}-{e_pa:g}.grasp", "object": f"o{truth_pa:g}", "material": "rubber",
            "shape": "sphere", "truth_pa": truth_pa, "method": method, "state": state, "e_pa": e_pa,
            "low_pa": e_pa / spread, "high_pa": None if state == "lower_bound" else e_pa * spread, "reason": ""}


def evaluate_output(tmp_path, *, name: str = "figures.json", shift: float = 1.0) -> tuple:
    """An ``estimator evaluate --json`` output, its figures made by the real metrics from a few scored rows."""
    rows = [_row("hybrid", 2e4, 2.5e4 * shift), _row("hybrid", 3e5, 9e5), _row("hybrid", 2e11, 6.75e6, "lower_bound"),
            _row("series", 2e4, 1e5), _row("series", 3e5, 3e5), _row("series", 2e11, 1e6)]
    methods = summarise(rows, ["series", "hybrid"], display_range_pa=DISPLAY, interval_levels={"hybrid": 0.9})
    methods["hybrid"]["model"] = "estimator/models/default"
    result = {"command": "estimator evaluate runs/x/records --json", "dir": "runs/x/records", "records": 3,
              "labelled": 3, "display_range_pa": list(DISPLAY), "methods": methods}
    path = tmp_path / name
    path.write_text("progress line\n" + json.dumps(result) + "\n")  # as evaluate prints it: the JSON last
    return path, methods


@pytest.fixture
def card(tmp_path):
    path = tmp_path / "MODEL_CARD.md"
    path.write_text(f"# A card\n\nBefore.\n\n{BEGIN}\n{END}\n\nAfter.\n")
    return path


def test_the_table_is_written_from_the_json_soft_objects_first(tmp_path, card, capsys):
    source, methods = evaluate_output(tmp_path)
    assert main(["card", str(card), "--figures", f"Nominal={source}"]) == 0
    text = card.read_text()
    assert text.startswith("# A card\n\nBefore.\n\n") and text.endswith("\nAfter.\n")
    header = next(line for line in text.splitlines() if line.startswith("| figures |"))
    headings = [c.strip() for c in header.strip("|").split("|")]
    assert headings.index("soft felt err") < headings.index("felt err")
    assert headings.index("soft within 2x") < headings.index("within 2x")
    hybrid = next(line for line in text.splitlines() if line.startswith("| Nominal | hybrid (default) |"))
    cells = [c.strip() for c in hybrid.strip("|").split("|")]
    m = methods["hybrid"]
    assert cells[headings.index("felt err")] == f"{m['felt_log10_error']:.3f}"
    assert cells[headings.index("soft felt err")] == f"{m['soft_felt_log10_error']:.3f}"
    assert cells[headings.index("within 2x")] == f"{100 * m['felt_within_2x']:.1f} %"
    assert cells[headings.index("coverage (stated)")] == f"{100 * m['interval_coverage']:.1f} % (90 %)"
    assert cells[headings.index("dangerous")] == str(m["dangerous_misses"])
    assert "| Nominal | series |" in text
    assert "made by `estimator evaluate runs/x/records --json`" in text
    assert len(headings) == 2 + len(COLUMNS)
    assert main(["card", str(card), "--check"]) == 0  # from the sources the block records


def test_check_fails_naming_the_figure_that_moved(tmp_path, card, capsys):
    source, _ = evaluate_output(tmp_path)
    assert main(["card", str(card), "--figures", f"Nominal={source}", "--methods", "hybrid"]) == 0
    written = card.read_text()
    assert "| Nominal | series |" not in written
    capsys.readouterr()
    evaluate_output(tmp_path, shift=3.0)  # the JSON changes under the card: the soft object felt elsewhere
    assert main(["card", str(card), "--check"]) == 1
    err = capsys.readouterr().err
    assert "Nominal / hybrid (default) / felt err: card says" in err
    assert "Nominal / hybrid (default) / soft felt err" in err
    assert card.read_text() == written  # --check writes nothing

    source, _ = evaluate_output(tmp_path)  # back as it was: the card matches again
    assert main(["card", str(card), "--check"]) == 0
    card.write_text(written.replace("| Nominal | hybrid (default) | 2 |", "| Nominal | hybrid (default) | 7 |"))
    assert main(["card", str(card), "--check"]) == 1
    assert "Nominal / hybrid (default) / soft n: card says 7, the JSON gives 2" in capsys.readouterr().err


def test_keep_writes_small_copies_the_card_points_at(tmp_path, card):
    source, _ = evaluate_output(tmp_path)
    keep = tmp_path / "figures"
    assert main(["card", str(card), "--figures", f"Soft gel rig={source}", "--methods", "hybrid",
                 "--keep", str(keep)]) == 0
    kept = json.loads((keep / "soft-gel-rig.json").read_text())
    assert list(kept["methods"]) == ["hybrid"] and kept["command"] == "estimator evaluate runs/x/records --json"
    assert "per_material" not in kept["methods"]["hybrid"]
    (sources, methods) = recorded_sources(card.read_text(), card)
    assert sources == [("Soft gel rig", card.parent / "figures/soft-gel-rig.json")] and methods == ["hybrid"]
    source.unlink()  # the card no longer needs the original
    assert main(["card", str(card), "--check"]) == 0


def test_keep_naming_a_file_is_refused_by_name(tmp_path, card, capsys):
    source, _ = evaluate_output(tmp_path)
    keep = tmp_path / "notes.txt"
    keep.write_text("mine")
    before = card.read_text()
    assert main(["card", str(card), "--figures", f"A={source}", "--keep", str(keep)]) == 2
    assert f"--keep {keep}: exists and is not a folder" in capsys.readouterr().err
    assert keep.read_text() == "mine" and card.read_text() == before


def test_a_source_path_may_hold_an_equals_sign_a_label_may_not(tmp_path, card, capsys):
    folder = tmp_path / "grasp=1"
    folder.mkdir()
    source, _ = evaluate_output(folder)
    assert main(["card", str(card), "--figures", f"Nominal={source}"]) == 0
    assert "| Nominal | hybrid (default) |" in card.read_text()
    before = card.read_text()
    # the label ends at the first '=': the rest is a path, and one that is not there is named
    assert main(["card", str(card), "--figures", f"E=3 MPa={source}"]) == 2
    assert f"3 MPa={source}: not an estimator evaluate --json output" in capsys.readouterr().err
    assert card.read_text() == before


def test_a_method_in_none_of_the_sources_is_refused_by_name(tmp_path, card, capsys):
    source, _ = evaluate_output(tmp_path)
    other, _ = evaluate_output(tmp_path, name="other.json")
    before = card.read_text()
    assert main(["card", str(card), "--figures", f"A={source}", "--figures", f"B={other}",
                 "--methods", "hybrid", "nosuch"]) == 2
    assert "--methods nosuch: in none of the sources (they have series, hybrid)" in capsys.readouterr().err
    assert card.read_text() == before


def test_a_method_some_sources_lack_is_shown_for_those_that_have_it(tmp_path, card):
    source, _ = evaluate_output(tmp_path)
    only_hybrid = tmp_path / "hybrid.json"
    result = json.loads(source.read_text().splitlines()[-1])
    del result["methods"]["series"]
    only_hybrid.write_text(json.dumps(result) + "\n")
    assert main(["card", str(card), "--figures", f"A={source}", "--figures", f"B={only_hybrid}",
                 "--methods", "hybrid", "series"]) == 0
    text = card.read_text()
    assert "| A | series |" in text and "| B | series |" not in text and "| B | hybrid (default) |" in text


def test_a_card_without_markers_is_refused(tmp_path, capsys):
    source, _ = evaluate_output(tmp_path)
    card = tmp_path / "card.md"
    card.write_text("# no markers\n")
    assert main(["card", str(card), "--figures", f"A={source}"]) == 2
    assert "figures:begin" in capsys.readouterr().err


def test_the_shipped_card_matches_the_json_it_came_from(capsys):
    assert main(["card", str(SHIPPED_CARD), "--check"]) == 0, capsys.readouterr().err
    sources, _ = recorded_sources(SHIPPED_CARD.read_text(), SHIPPED_CARD)
    assert sources and all(path.is_file() and path.stat().st_size < 16_000 for _, path in sources)

def test_the_shipped_cards_validation_coverage_is_the_one_its_metadata_records():
    text = " ".join(SHIPPED_CARD.read_text(encoding="utf-8").split())
    recorded = json.loads((SHIPPED_CARD.parent / "metadata.json").read_text())["metrics"]["val"]["hybrid"]
    stated = re.findall(r"on the validation objects, (\d+\.\d) %", text)
    assert stated == [f"{100 * recorded['interval_coverage']:.1f}"], stated


def test_keep_refuses_to_replace_another_cards_copy_unless_overwrite(tmp_path, card, capsys):
    # Two cards keeping into one folder under one label: the second must not change what the first points at.
    first_source, _ = evaluate_output(tmp_path, name="a.json")
    second_source, _ = evaluate_output(tmp_path, name="b.json", shift=3.0)
    other = tmp_path / "other.md"
    other.write_text(f"# other\n{BEGIN}\n{END}\n")
    keep = tmp_path / "kept"
    assert main(["card", str(card), "--figures", f"Sim={first_source}", "--keep", str(keep)]) == 0
    kept = (keep / "sim.json").read_bytes()
    assert main(["card", str(other), "--figures", f"Sim={second_source}", "--keep", str(keep)]) == 2
    err = capsys.readouterr().err
    assert f"{keep / 'sim.json'} exists" in err and "--overwrite" in err
    assert (keep / "sim.json").read_bytes() == kept and BEGIN + "\n" + END in other.read_text()
    assert main(["card", str(card), "--check"]) == 0
    # The same copy again is no change; the card's own copy may be written again; --overwrite replaces.
    assert main(["card", str(other), "--figures", f"Sim={first_source}", "--keep", str(keep)]) == 0
    assert main(["card", str(card), "--keep", str(keep)]) == 0
    assert main(["card", str(other), "--figures", f"Sim={second_source}", "--keep", str(keep), "--overwrite"]) == 0
    assert (keep / "sim.json").read_bytes() != kept
    assert main(["card", str(card), "--overwrite"]) == 2
    assert "--overwrite: replaces files --keep DIR would write" in capsys.readouterr().err


def test_a_write_that_fails_midway_leaves_the_card_whole(tmp_path, card, capsys, monkeypatch):
    source, _ = evaluate_output(tmp_path)
    card.write_text(card.read_text() + "Padding.\n" * 4000)  # a card long enough to be cut short
    before = card.read_bytes()
    real_write_text = Path.write_text

    def write_half_then_fail(self, data, *args, **kwargs):  # as a full disk or `ulimit -f` does
        real_write_text(self, data[: len(data) // 2], *args, **kwargs)
        raise OSError(errno.EFBIG, "File too large", str(self))

    monkeypatch.setattr(Path, "write_text", write_half_then_fail)
    assert main(["card", str(card), "--figures", f"A={source}"]) == 2
    monkeypatch.undo()
    assert f"{card}: cannot write the model card" in capsys.readouterr().err
    assert card.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["MODEL_CARD.md", "figures.json"]  # no temporary left


@pytest.mark.parametrize("corrupt", [
    lambda data: data.replace(b'<!-- figures:sources {"figures": [[', b'<!-- figures:sources {"figures": [[['),
    lambda data: data.replace(b'<!-- figures:sources {"figures"', b'<!-- figures:sources {"figurez"'),
    lambda data: data + b"\xff",
], ids=["broken-json", "missing-key", "not-utf8"])
def test_check_on_a_malformed_card_is_an_error_naming_it_not_a_difference(tmp_path, card, capsys, corrupt):
    source, _ = evaluate_output(tmp_path)
    assert main(["card", str(card), "--figures", f"A={source}"]) == 0
    broken = corrupt(card.read_bytes())
    assert broken != card.read_bytes()
    card.write_bytes(broken)
    capsys.readouterr()
    assert main(["card", str(card), "--check"]) == 2  # an error (2), not "the table differs" (1)
    assert f"{card}: " in capsys.readouterr().err
    assert card.read_bytes() == broken


def test_keep_writes_nothing_when_a_source_has_none_of_the_methods(tmp_path, card, capsys):
    source, _ = evaluate_output(tmp_path)
    only_hybrid = tmp_path / "hybrid.json"
    result = json.loads(source.read_text().splitlines()[-1])
    del result["methods"]["series"]
    only_hybrid.write_text(json.dumps(result) + "\n")
    keep = tmp_path / "kept"
    before = card.read_bytes()
    assert main(["card", str(card), "--figures", f"A={source}", "--figures", f"B={only_hybrid}",
                 "--methods", "series", "--keep", str(keep)]) == 2
    err = capsys.readouterr().err
    assert f"{only_hybrid}: none of the methods series" in err and str(keep) not in err  # the user's file, not a copy
    assert not keep.exists() and card.read_bytes() == before
