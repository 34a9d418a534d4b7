"""``estimator evaluate`` on a few simulated records: the felt figures, the table and ``--rows``."""

from __future__ import annotations

import csv
import json
import math

import numpy as np
import pytest

from estimator.cli import main
from estimator.evaluation.evaluate_cli import ROW_COLUMNS
from estimator.evaluation.metrics import felt_pa
from haptics.settings import display_settings
from teleop.settings import load_settings

OBJECTS = ("stress_ball", "rubber_duck", "steel_ball_bearing")


@pytest.fixture(scope="module")
def records(tmp_path_factory):
    """Simulated grasps of a soft, a medium and a rigid catalogue object, and one unlabelled record."""
    from teleop.catalogue import load_catalogue
    from teleop.record import write_record
    from teleop.settings import CONFIG_DIR
    from teleop.sim.grasp import simulate_grasp

    out = tmp_path_factory.mktemp("records")
    settings = load_settings()
    catalogue = {o.name: o for o in load_catalogue(CONFIG_DIR / "objects.toml")}
    for i, name in enumerate(OBJECTS):
        record, _ = simulate_grasp(catalogue[name], settings=settings, rng=np.random.default_rng(10 + i), seed=10 + i)
        write_record(record, out / f"{name}.grasp")
    return out


def last_json(capsys) -> dict:
    return json.loads(capsys.readouterr().out.strip().splitlines()[-1])


@pytest.mark.slow
def test_evaluate_writes_rows_and_scores_what_the_display_renders(records, tmp_path, capsys):
    csv_path = tmp_path / "rows.csv"
    assert main(["evaluate", str(records), "--methods", "no_tactile", "--rows", str(csv_path), "--json"]) == 0
    result = last_json(capsys)
    display = display_settings(load_settings())
    assert result["display_range_pa"] == [display.e_soft_pa, display.e_rigid_pa]
    assert display.e_rigid_pa < 1e8  # resolved to the sensor's limit, not left at 0
    m = result["methods"]["no_tactile"]
    for key in ("felt_log10_error", "felt_within_2x", "dangerous_misses", "interval_level", "interval_coverage",
                "interval_width_decades_median", "soft_interval_width_decades_median", "soft_felt_log10_error",
                "soft_felt_within_2x", "soft_interval_coverage", "soft_n", "soft_refused"):
        assert key in m
    assert m["interval_level"] is None

    with open(csv_path, newline="") as handle:
        table = list(csv.DictReader(handle))
    assert tuple(table[0]) == ROW_COLUMNS
    assert sorted(r["object"] for r in table) == sorted(OBJECTS) and {r["method"] for r in table} == {"no_tactile"}
    assert all(r["record"].endswith(".grasp") for r in table)

    def number(cell):
        return None if cell == "" else float(cell)

    counted, errors, misses, soft, rigid = 0, [], 0, display.e_soft_pa, display.e_rigid_pa
    for r in table:
        felt = number(r["felt_pa"])
        if r["state"] == "insufficient_data":
            assert felt is None and r["e_pa"] == ""
            continue
        counted += 1
        parsed = {"state": r["state"], "e_pa": float(r["e_pa"]), "low_pa": number(r["low_pa"]),
                  "high_pa": number(r["high_pa"])}
        assert felt == pytest.approx(felt_pa(parsed, display_range_pa=(soft, rigid)))
        assert soft <= felt <= rigid
        truth = float(r["truth_pa"])
        errors.append(abs(math.log10(felt) - math.log10(min(rigid, max(soft, truth)))))
        misses += (truth >= 1e8 and felt < 1e6) or (truth <= 1e6 and felt >= min(1e7, rigid))
    assert m["n"] == counted
    if counted:
        assert m["felt_log10_error"] == pytest.approx(sum(errors) / counted)
        assert m["dangerous_misses"] == misses
    else:
        assert m["felt_log10_error"] is None


def test_the_table_shows_the_felt_block(records, capsys):
    assert main(["evaluate", str(records), "--methods", "no_tactile", "hertz"]) == 0
    lines = capsys.readouterr().out.splitlines()
    headers = [i for i, line in enumerate(lines) if line.startswith("method")]
    assert len(headers) == 2
    first, second = lines[headers[0]], lines[headers[1]]
    assert "paper" in first and "2.13/18.2%" in lines[headers[0] + 1]  # the paper's figures stay
    for column in ("felt err", "felt2x", "danger", "level", "coverage", "width", "soft n"):
        assert column in second
    # The soft objects' block repeats the display's figures after the bar.
    assert second.split("|")[1].split() == ["soft", "n", "refused", "felt", "err", "felt2x", "coverage", "width"]
    assert lines[headers[1] + 1].startswith("no_tactile") and lines[headers[1] + 2].startswith("hertz")
    assert any("on the display" in line for line in lines)


def test_rows_option_is_explained():
    import argparse

    from estimator.evaluation import evaluate_cli

    parser = argparse.ArgumentParser()
    evaluate_cli.add_arguments(parser)
    action = next(a for a in parser._actions if "--rows" in a.option_strings)
    assert "felt_pa" in action.help and "CSV" in action.help


@pytest.mark.slow
def test_skipped_records_are_named_with_their_cause_and_nothing_scored_fails(records, tmp_path, capsys):
    from dataclasses import replace

    from teleop.record import read_record, write_record

    folder = tmp_path / "mixed"
    folder.mkdir()
    rigid = read_record(records / "steel_ball_bearing.grasp")
    write_record(rigid, folder / "labelled.grasp")
    write_record(replace(rigid, label=None), folder / "unlabelled.grasp")
    (folder / "broken.grasp").write_bytes(b"not a zip")
    assert main(["evaluate", str(folder), "--methods", "no_tactile"]) == 0
    out = capsys.readouterr().out
    assert "scored 1 records of 3" in out and "skipped 2 of 3 records:" in out
    assert f"{folder / 'broken.grasp'}: unreadable: " in out and f"{folder / 'unlabelled.grasp'}: unlabelled" in out
    assert main(["evaluate", str(folder), "--methods", "no_tactile", "--json"]) == 0
    result = last_json(capsys)
    assert result["skipped"] == {"unreadable": 1, "unlabelled": 1}
    assert [s["path"] for s in result["skipped_records"]] == [str(folder / "broken.grasp"),
                                                              str(folder / "unlabelled.grasp")]

    (folder / "labelled.grasp").unlink()
    assert main(["evaluate", str(folder), "--methods", "no_tactile", "--json"]) == 2
    captured = capsys.readouterr()
    assert captured.out == "" and "Traceback" not in captured.err
    assert "no record scored, all 2 skipped (1 unreadable, 1 unlabelled" in captured.err
    assert "broken.grasp: unreadable" in captured.err


def test_a_record_whose_frames_do_not_decode_is_skipped_and_named(records, tmp_path, capsys):
    from dataclasses import replace

    from teleop.record import read_record, write_record

    folder = tmp_path / "frames"
    folder.mkdir()
    good = read_record(records / "stress_ball.grasp")
    write_record(good, folder / "good.grasp")
    garbled = tuple(replace(s, encoded=(b"x",) * len(s)) for s in good.frames)
    write_record(replace(good, frames=garbled), folder / "garbled.grasp")
    assert main(["evaluate", str(folder), "--methods", "elastic", "--json"]) == 0
    result = last_json(capsys)
    assert result["skipped"] == {"unreadable": 1} and sum(result["methods"]["elastic"]["states"].values()) == 1
    skipped = result["skipped_records"][0]
    assert skipped["path"] == str(folder / "garbled.grasp") and "does not decode" in skipped["cause"]


def test_output_paths_are_checked_before_scoring(records, tmp_path, capsys):
    # A wrong --plot or --rows used to end a whole evaluation in a traceback, its figures lost.
    (tmp_path / "taken").mkdir()
    for option, value, said in (("--plot", "p.xyz", "expected a name ending in .png, .pdf, .svg"),
                                ("--rows", "rows.txt", "expected a name ending in .csv"),
                                ("--plot", str(tmp_path / "taken"), "is a folder")):
        assert main(["evaluate", str(records), "--methods", "no_tactile", option, value, "--json"]) == 2
        captured = capsys.readouterr()
        assert said in captured.err and "Traceback" not in captured.err and captured.out == ""
    plot, rows = tmp_path / "new" / "p.png", tmp_path / "new" / "rows.csv"  # folders made as needed
    assert main(["evaluate", str(records), "--methods", "no_tactile", "--plot", str(plot), "--rows", str(rows),
                 "--json"]) == 0
    assert plot.stat().st_size > 0 and rows.read_text().startswith("record,")


def test_a_learned_method_no_loaded_model_has_names_the_models_loaded(tmp_path, capsys):
    # Without --model the shipped default is loaded: the error said "models: none".
    from estimator.inference.infer import CompliancePredictor, default_model_dir

    (tmp_path / "found.grasp").write_bytes(b"")  # the models are checked before any record is read
    assert main(["evaluate", str(tmp_path), "--methods", "cnn"]) == 2
    err = capsys.readouterr().err
    variant = CompliancePredictor(default_model_dir()).variant
    assert variant.method != "cnn" and "models: none" not in err
    assert f"models: {variant.name} ({variant.method}) in {default_model_dir()}" in err


@pytest.mark.slow
def test_an_interrupted_evaluate_keeps_the_earlier_rows_and_plot(records, tmp_path, capsys, monkeypatch):
    import estimator.evaluation.evaluate_cli as evaluate_cli

    rows, png = tmp_path / "rows.csv", tmp_path / "p.png"
    options = ["evaluate", str(records), "--methods", "no_tactile", "--rows", str(rows), "--plot", str(png)]
    assert main(options) == 0
    before = rows.read_bytes(), png.read_bytes()
    capsys.readouterr()

    def interrupted(*args, **kwargs):  # Ctrl-C while the rows are written, after the plot
        raise KeyboardInterrupt

    monkeypatch.setattr(evaluate_cli, "write_rows", interrupted)
    assert main(options) == 130
    assert (rows.read_bytes(), png.read_bytes()) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["p.png", "rows.csv"]  # no temporary left
