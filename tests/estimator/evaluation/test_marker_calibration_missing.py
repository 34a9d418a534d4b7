"""``estimator evaluate`` and ``bench`` with a model that reads the marker finger, on records whose
marker finger's calibration file is gone: skipped as "calibration missing", naming that file, not fatal.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
from support.gone_calibration import records_with_a_gone_calibration

from estimator.cli import main
from estimator.evaluation.bench import bench, configurations
from estimator.measurements import calibration_path, calibration_problem
from teleop.record import read_record
from teleop.settings import load_settings


@pytest.fixture(scope="module")
def marker_model(synthetic_dataset, synthetic, tmp_path_factory) -> Path:
    """A hybrid model of a variant with markers, trained for a few epochs (a few seconds)."""
    from estimator.inference.inputs import Variant
    from estimator.training.recipe import TrainConfig
    from estimator.training.train import train_model

    out = tmp_path_factory.mktemp("marker_model")
    variant = Variant.parse("depth+markers+fw+analytical", n_frames=synthetic.N_FRAMES, size_px=synthetic.SIZE)
    train_model(synthetic_dataset, out, variant=variant,
                config=TrainConfig(epochs=2, patience=2, batch_size=8, seed=1), progress=False)
    return out


@pytest.fixture(scope="module")
def folder(tmp_path_factory) -> tuple[Path, Path]:
    """(records folder, the missing calibration): a good record and one whose marker finger names a
    calibration that is gone (the estimating finger's is there)."""
    return records_with_a_gone_calibration(tmp_path_factory.mktemp("marker_calibration_gone"), seed=30,
                                           sensors=lambda s: s.markers)


def marker_finger(record) -> str:
    return next(s.finger for s in record.sensors if s.markers)


@pytest.mark.slow
def test_the_marker_finger_calibration_counts_only_where_markers_are_read(folder):
    records, missing = folder
    record = read_record(records / "moved.grasp")
    finger = load_settings().sensing.finger
    assert finger != marker_finger(record)
    assert calibration_problem(record, finger, None, "--calibration") is None
    problem = calibration_problem(record, finger, None, "--calibration", markers=True)
    assert problem.startswith(f"it names calibration {missing} for finger {marker_finger(record)!r}, "
                              "which does not exist")
    assert "--calibration" not in problem  # it does not serve the marker finger
    assert calibration_problem(record, finger, None, "--calibration", markers=True,
                               marker_override="given.npz") is None
    kept = read_record(records / "kept.grasp")
    assert calibration_problem(kept, finger, None, "--calibration", markers=True) is None


def test_evaluate_says_the_marker_finger_calibration_is_missing_naming_it(folder, marker_model, capsys):
    records, missing = folder
    argv = ["evaluate", str(records), "--methods", "elastic", "hybrid", "--model", str(marker_model), "--json"]
    assert main(argv) == 0
    result = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert result["records"] == 2 and result["skipped"] == {"calibration missing": 1}
    [skipped] = result["skipped_records"]
    assert skipped["path"] == str(records / "moved.grasp")
    assert skipped["cause"].startswith(f"calibration missing: it names calibration {missing} for finger ")


def test_evaluate_with_a_calibration_for_every_record_still_skips_a_record_whose_marker_file_is_gone(
        folder, marker_model, capsys):
    records, missing = folder
    settings = load_settings()
    given = calibration_path(settings.sensor(settings.sensing.finger))
    argv = ["evaluate", str(records), "--methods", "hybrid", "--model", str(marker_model), "--calibration",
            str(given), "--json"]
    assert main(argv) == 0
    result = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert result["skipped"] == {"calibration missing": 1}
    assert str(missing) in result["skipped_records"][0]["cause"]


def test_bench_skips_a_record_whose_marker_calibration_is_gone_and_benches_the_rest(folder, marker_model,
                                                                                      tmp_path, capsys):
    records, missing = folder
    assert main(["bench", str(records), "--models", str(marker_model), "--repeats", "1", "--json"]) == 0
    result = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert result["records"] == 2 and result["labelled"] == 1
    assert result["skipped"] == {"calibration missing": 1}
    [entry] = result["skipped_records"]
    assert entry["path"] == str(records / "moved.grasp")
    assert entry["cause"].startswith(f"calibration missing: it names calibration {missing} for finger ")

    # Without a model reading the marker finger, that record is benched.
    settings = load_settings()
    configs = configurations(settings=settings, calibration=None, frames=(), models=())
    alone = tmp_path / "alone"
    alone.mkdir()
    shutil.copy(records / "moved.grasp", alone / "moved.grasp")
    assert bench([alone / "moved.grasp"], settings=settings, configs=configs, repeats=1,
                 progress=False)["labelled"] == 1

    # Only that record, read with the marker model: refused, saying why.
    assert main(["bench", str(alone), "--models", str(marker_model), "--repeats", "1"]) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err and "1 of 1 records skipped (1 calibration missing)" in err
    assert str(missing) in err
