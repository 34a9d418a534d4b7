"""``estimator evaluate`` and ``compare`` on records whose calibration file is gone: skipped and named, not fatal.

A simulated record holds the absolute path of the settings' calibration; once that file is gone (a
recreated venv, records shared with a colleague), the record is skipped like an unreadable one.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
from support.gone_calibration import records_with_a_gone_calibration

from estimator.cli import main
from estimator.evaluation.compare import NothingToCompare, compare_models
from teleop.settings import load_settings

DEFAULT_MODEL = Path(__file__).resolve().parents[3] / "estimator" / "models" / "default"


@pytest.fixture(scope="module")
def folder(tmp_path_factory) -> tuple[Path, Path]:
    """(records folder, the missing calibration): a good record and one naming a calibration that is gone.

    Objects are renamed so that the shipped model did not train on them (``compare`` scores them).
    """
    return records_with_a_gone_calibration(tmp_path_factory.mktemp("calibration_gone"), seed=20, rename=True)


def last_json(capsys) -> dict:
    return json.loads(capsys.readouterr().out.strip().splitlines()[-1])


@pytest.mark.slow
def test_evaluate_skips_a_record_whose_calibration_is_gone_and_scores_the_rest(folder, tmp_path, capsys):
    records, missing = folder
    moved = str(records / "moved.grasp")
    assert main(["evaluate", str(records), "--methods", "elastic", "--json"]) == 0
    result = last_json(capsys)
    assert result["records"] == 2 and result["labelled"] == 1
    assert result["skipped"] == {"calibration missing": 1}
    assert sum(result["methods"]["elastic"]["states"].values()) == 1
    [skipped] = result["skipped_records"]
    assert skipped["path"] == moved
    assert str(missing) in skipped["cause"] and "does not exist" in skipped["cause"]
    assert "--calibration CAL" in skipped["cause"]

    assert main(["evaluate", str(records), "--methods", "elastic"]) == 0
    out = capsys.readouterr().out
    assert "scored 1 records of 2" in out and f"{moved}: calibration missing: it names calibration {missing}" in out

    # Only that record: the error says why, naming it.
    alone = tmp_path / "alone"
    alone.mkdir()
    shutil.copy(moved, alone / "moved.grasp")
    assert main(["evaluate", str(alone), "--methods", "elastic"]) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err and "no record scored, all 1 skipped (1 calibration missing" in err
    assert f"{alone / 'moved.grasp'}: calibration missing: it names calibration {missing}" in err


def test_a_calibration_given_for_every_record_still_stops_the_run_when_it_is_gone(folder, tmp_path, capsys):
    records, _ = folder
    assert main(["evaluate", str(records), "--methods", "elastic", "--calibration", str(tmp_path / "no.npz")]) == 2
    assert f"calibration file {tmp_path / 'no.npz'} does not exist" in capsys.readouterr().err


@pytest.mark.slow
def test_compare_skips_a_record_whose_calibration_is_gone_and_compares_on_the_rest(folder, tmp_path, capsys):
    records, missing = folder
    candidate = tmp_path / "candidate"
    shutil.copytree(DEFAULT_MODEL, candidate)
    result = compare_models(DEFAULT_MODEL, candidate, records, settings=load_settings(), progress=False)
    assert result["records"] == 2 and result["scored"] == 1 and result["objects"] == ["unseen_kept"]
    [skipped] = result["skipped"]
    assert skipped["path"] == str(records / "moved.grasp")
    assert skipped["cause"].startswith(f"calibration missing: it names calibration {missing}")
    assert "--calibration CAL" in skipped["cause"]

    argv = ["compare", str(records), "--base", str(DEFAULT_MODEL), "--candidate", str(candidate)]
    assert main(argv) == 0
    assert f"{records / 'moved.grasp'}: calibration missing: " in capsys.readouterr().out

    alone = tmp_path / "alone"
    alone.mkdir()
    shutil.copy(records / "moved.grasp", alone / "moved.grasp")
    with pytest.raises(NothingToCompare, match=r"\(1 records: 1 calibration missing\)"):
        compare_models(DEFAULT_MODEL, candidate, alone, settings=load_settings(), progress=False)
    assert main(["compare", str(alone), "--base", str(DEFAULT_MODEL), "--candidate", str(candidate)]) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err and f"{alone / 'moved.grasp'}: calibration missing: " in err


def test_bench_skips_a_record_whose_calibration_is_gone_and_benches_the_rest(folder, capsys):
    records, missing = folder
    assert main(["bench", str(records), "--repeats", "1", "--json"]) == 0
    result = last_json(capsys)
    assert result["records"] == 2 and result["labelled"] == 1
    assert result["skipped"] == {"calibration missing": 1}
    (entry,) = result["skipped_records"]
    assert entry["path"] == str(records / "moved.grasp") and str(missing) in entry["cause"]
    assert "--calibration CAL" in entry["cause"]
