"""``estimator estimate`` on records whose calibration file is gone (an exported folder moved, a
recreated venv): each such record is named with what to do, as ``estimator evaluate`` says it, and
the others are still estimated."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from estimator.cli import main
from teleop.settings import load_settings


@pytest.fixture(scope="module")
def folder(tmp_path_factory) -> tuple[Path, Path]:
    """(records folder, the missing calibration): a good record, and the same grasp naming a calibration
    that is gone."""
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
    moved = replace(record, sensors=tuple(replace(s, calibration=str(missing)) for s in record.sensors))
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
