"""``teleop doctor``'s calibration lines: a calibration made for another sensor (the line says which, in the
table and the JSON), the ages of calibrations and models, and a copied settings file's missing ones."""

from __future__ import annotations

import dataclasses
import json
import os
import shutil
import time
from datetime import UTC, datetime, timedelta

import pytest
from support.rig_settings import rig_settings

from estimator.perception.calibration import load_calibration
from teleop.cli import main
from teleop.settings import config_dir, default_settings_path, load_settings
from teleop.system.doctor import check_calibrations


def _file(finger):
    return str(config_dir() / "calibration" / f"sim-wedge-{finger}.npz")


@pytest.mark.slow
def test_swapped_calibrations_are_named_and_the_estimators_finger_is_not_ready(tmp_path, capsys):
    path = rig_settings(tmp_path, {"sensors.left.calibration": _file("right"), "sensors.right.calibration": _file("left")})
    checks = {c.name: c for c in check_calibrations(load_settings(path), path)}
    left, right = checks["calibration left"], checks["calibration right"]
    # the estimator's finger reads with the right sensor's colours: wrong slopes, so not ready
    assert not left.ok
    assert "serial 'sim-wedge-right' (this sensor: 'sim-wedge-left')" in left.problem
    assert "it is [sensors.right]'s" in left.problem
    # the other finger's swap is named, but nothing estimates from it
    assert right.ok and right.problem is None
    assert "serial 'sim-wedge-left' (this sensor: 'sim-wedge-right')" in right.warning

    assert main(["doctor", "--settings", str(path), "--duration-s", "0.3"]) == 1
    rows = {line[:18].strip(): line for line in capsys.readouterr().out.splitlines()}
    assert rows["calibration left"].split()[2] == "NO" and "it is [sensors.right]'s" in rows["calibration left"]
    assert rows["calibration right"].split()[2] == "warn" and "'sim-wedge-left'" in rows["calibration right"]


@pytest.mark.slow
def test_another_sensors_calibration_is_a_warning_in_the_table_and_the_json(tmp_path, capsys):
    # Made for a sensor not in these settings (its twin, say): the estimator runs on it, warning.
    path = rig_settings(tmp_path, {"sensors.left.calibration": _file("right"),
                           "sensors.right.serial": "twin-right", "sensors.right.calibration": ""})
    assert main(["doctor", "--json", "--settings", str(path), "--duration-s", "0.3"]) in (0, 1)
    report = json.loads(capsys.readouterr().out)
    left = {c["name"]: c for c in report["calibrations"]}["calibration left"]
    assert left["ok"] and left["problem"] is None
    assert left["warning"].startswith("the calibration was made for another sensor than wedge 'sim-wedge-left': ")
    assert "serial 'sim-wedge-right' (this sensor: 'sim-wedge-left')" in left["warning"]
    assert left["warning"].endswith("name this sensor's own file in [sensors.left] calibration")

    main(["doctor", "--settings", str(path), "--duration-s", "0.3"])
    out = capsys.readouterr().out
    row = next(line for line in out.splitlines() if line.startswith("calibration left"))
    assert row.split()[2] == "warn" and "serial 'sim-wedge-right'" in row
    if report["ok"]:  # the bus ports are free unless something on this machine holds them
        assert out.rstrip().endswith("ready for a session; see the lines marked warn")


# --------------------------------------------------------------------------- ages


DAY_S = 86400.0


def _days_ago(days):
    return (datetime.now(UTC) - timedelta(days=days)).isoformat(timespec="seconds")


def _calibration_copy(tmp_path, finger, created_utc):
    """The shipped calibration of ``finger`` saved anew (its file written now) with ``created_utc``
    as its recorded creation time (None: none recorded)."""
    calibration = load_calibration(_file(finger))
    provenance = {k: v for k, v in calibration.provenance.items() if k != "created_utc"}
    if created_utc is not None:
        provenance["created_utc"] = created_utc
    return str(dataclasses.replace(calibration, provenance=provenance).save(tmp_path / f"{finger}.npz"))


def _ages(path):
    return {c.name: c.detail.get("age_days") for c in check_calibrations(load_settings(path), path)}


def test_a_calibrations_age_is_its_recorded_creation_not_its_files(tmp_path):
    # An installed wheel's (or a copied) calibration was "0 days old": the file's time is the copy's.
    path = rig_settings(tmp_path, {"sensors.left.calibration": _calibration_copy(tmp_path, "left", _days_ago(30)),
                           "sensors.right.calibration": _calibration_copy(tmp_path, "right", None)})
    old = time.time() - 10 * DAY_S
    os.utime(tmp_path / "right.npz", (old, old))
    ages = _ages(path)
    assert ages["calibration left"] == pytest.approx(30.0, abs=0.11)
    assert ages["calibration right"] == pytest.approx(10.0, abs=0.11)  # none recorded: the file's time


@pytest.mark.parametrize(("metadata", "days"), [({"created_utc": _days_ago(20)}, 20.0), ({}, 5.0)])
def test_a_models_age_is_its_recorded_creation_else_its_files(tmp_path, metadata, days):
    model = tmp_path / "model"
    model.mkdir()
    (model / "model.onnx").write_bytes(b"")
    (model / "metadata.json").write_text(json.dumps(metadata))
    old = time.time() - 5 * DAY_S
    os.utime(model / "model.onnx", (old, old))
    path = rig_settings(tmp_path, {"estimator.model_path": str(model)})
    assert _ages(path)["model"] == pytest.approx(days, abs=0.11)


def test_a_model_whose_metadata_is_not_json_is_a_problem_naming_it(tmp_path):
    model = tmp_path / "model"
    model.mkdir()
    (model / "model.onnx").write_bytes(b"")
    (model / "metadata.json").write_text("{not json")
    path = rig_settings(tmp_path, {"estimator.model_path": str(model)})
    check = {c.name: c for c in check_calibrations(load_settings(path), path)}["model"]
    assert not check.ok
    assert f"{model / 'metadata.json'}: not a readable model metadata file" in check.problem


# --------------------------------------------------------------------------- a copied settings file


def test_a_copied_settings_file_is_pointed_at_the_shipped_calibrations(tmp_path):
    # Its relative calibration paths resolve against the copy's folder: doctor said to capture anew,
    # for a simulated sensor whose calibration is shipped.
    path = tmp_path / "rig.toml"
    shutil.copy(default_settings_path(), path)
    checks = {c.name: c for c in check_calibrations(load_settings(path), path)}
    for finger in ("left", "right"):
        problem = checks[f"calibration {finger}"].problem
        assert str(tmp_path / "calibration" / f"sim-wedge-{finger}.npz") in problem
        assert (f"the shipped one is {_file(finger)}: point [sensors.{finger}] calibration at it, or make your "
                "own: run `estimator calibrate") in problem, problem


def test_a_missing_calibration_no_shipped_one_is_named_as_is_not_pointed_at_one(tmp_path):
    path = rig_settings(tmp_path, {"sensors.left.calibration": "calibration/absent.npz"})
    problem = {c.name: c for c in check_calibrations(load_settings(path), path)}["calibration left"].problem
    assert "shipped" not in problem and "run `estimator calibrate" in problem
