"""``estimator estimate`` on records whose calibration file is gone (an exported folder moved, a
recreated venv, settings copied away from the shipped calibrations): each such record is named with
what to do, as ``estimator evaluate`` says it (an exported record: export it again; a simulated one:
give it a calibration or simulate it again), and the others are still estimated."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from estimator.cli import main
from teleop.cli import main as teleop_main
from teleop.settings import load_settings


@pytest.fixture(scope="module")
def folder(tmp_path_factory) -> tuple[Path, Path]:
    """(records folder, the missing calibration): a good record, and the same grasp naming a calibration
    that is gone as an exported (hardware) record."""
    from teleop.catalogue import load_catalogue
    from teleop.record import write_record
    from teleop.settings import CONFIG_DIR
    from teleop.sim.grasp import simulate_grasp

    out = tmp_path_factory.mktemp("estimate_calibration_gone")
    settings = load_settings()
    stress_ball = next(o for o in load_catalogue(CONFIG_DIR / "objects.toml") if o.name == "stress_ball")
    record, _ = simulate_grasp(stress_ball, settings=settings, rng=np.random.default_rng(40), seed=40)
    missing = out / "gone" / "calibration.npz"
    (out / "records").mkdir()
    write_record(record, out / "records" / "kept.grasp")
    moved = replace(record, sensors=tuple(replace(s, calibration=str(missing)) for s in record.sensors),
                    provenance=replace(record.provenance, source="hardware"))
    write_record(moved, out / "records" / "moved.grasp")
    return out / "records", missing


@pytest.mark.parametrize("method", ["elastic", "auto"])
def test_estimate_names_a_record_whose_calibration_is_gone_with_what_to_do(folder, method, capsys):
    records, missing = folder
    moved = records / "moved.grasp"
    assert main(["estimate", str(records), "--method", method]) == 2
    captured = capsys.readouterr()
    assert f"estimator estimate: error: {moved}: calibration missing: it names calibration {missing} " in captured.err
    assert "`teleop export`" in captured.err and "--calibration CAL" in captured.err
    assert "Traceback" not in captured.err
    assert f"{records / 'kept.grasp'}\n{method}: " in captured.out  # the other record is still estimated

    assert main(["estimate", str(moved), "--method", method, "--json"]) == 2
    [line] = capsys.readouterr().out.splitlines()
    assert json.loads(line)["error"].startswith(f"calibration missing: it names calibration {missing}")


def test_a_simulated_record_whose_calibration_is_gone_is_told_to_take_one_or_be_simulated_again(tmp_path, capsys):
    """The shipped settings copied elsewhere name calibrations beside the copy: the records simulated
    with them are pointed at the shipped files, never at `teleop export`."""
    from teleop.settings import default_settings_path

    settings = tmp_path / "mysettings.toml"
    settings.write_text(default_settings_path().read_text())
    assert teleop_main(["simulate", "--only", "stress_ball", "--seed", "40", "--out", str(tmp_path / "sim"),
                        "--settings", str(settings)]) == 0
    (record,) = (tmp_path / "sim").glob("*.grasp")
    capsys.readouterr()
    assert main(["estimate", str(record), "--method", "elastic"]) == 2
    err = capsys.readouterr().err
    shipped = default_settings_path().parent / "calibration" / "sim-wedge-left.npz"
    assert (f"estimator estimate: error: {record}: calibration missing: it names calibration "
            f"{tmp_path / 'calibration' / 'sim-wedge-left.npz'} for finger 'left', which does not exist (the file "
            "of the settings it was simulated with): pass --calibration CAL, put the file there, or simulate it "
            "again (`teleop simulate`) with settings that name one: the shipped one is "
            f"{shipped}: point [sensors.left] calibration at it\n") in err
    assert "teleop export" not in err and "Traceback" not in err
    assert main(["estimate", str(record), "--method", "elastic", "--calibration", str(shipped)]) == 0


@pytest.mark.parametrize(("source", "model"), [("simulated", "wedge"), ("hardware", "session"),
                                               ("simulated", "session")])  # the last: a simulated session's export
def test_without_an_option_a_record_is_told_what_fits_its_source(folder, source, model):
    from estimator.measurements import calibration_problem
    from teleop.record import read_record

    records, missing = folder
    gone = read_record(records / "moved.grasp")
    gone = replace(gone, provenance=replace(gone.provenance, source=source, model=model))
    unnamed = replace(gone, sensors=tuple(replace(s, calibration="") for s in gone.sensors))
    problem, none_named = calibration_problem(gone, "left", None, None), calibration_problem(unnamed, "left", None, None)
    assert problem.startswith(f"it names calibration {missing} for finger 'left', which does not exist")
    if model != "session":
        assert problem.endswith(": put the file there, or simulate it again (`teleop simulate`) with settings that "
                                "name one: make one with `estimator calibrate` and name it in [sensors.left] "
                                "calibration")
        assert none_named.endswith(": simulate it again (`teleop simulate`) with settings that name one for that "
                                   "finger")
    else:
        assert problem.endswith("`teleop export` (exported records carry their calibration inside), or put the "
                                "file there")
        assert none_named.endswith(": export its session again with `teleop export` and settings that name one "
                                   "for that finger")
