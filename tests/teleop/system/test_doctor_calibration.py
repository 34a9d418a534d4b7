"""``teleop doctor`` on a calibration made for another sensor: the line says which, in the table and the JSON."""

from __future__ import annotations

import json
import shutil

import pytest

from teleop.cli import main
from teleop.settings import config_dir, default_settings_path, load_settings
from teleop.settings_edit import update_settings_file
from teleop.system.doctor import check_calibrations


def _rig(tmp_path, changes):
    path = tmp_path / "rig.toml"
    shutil.copy(default_settings_path(), path)
    update_settings_file(path, changes)
    return path


def _file(finger):
    return str(config_dir() / "calibration" / f"sim-wedge-{finger}.npz")


def test_swapped_calibrations_are_named_and_the_estimators_finger_is_not_ready(tmp_path, capsys):
    path = _rig(tmp_path, {"sensors.left.calibration": _file("right"), "sensors.right.calibration": _file("left")})
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
    path = _rig(tmp_path, {"sensors.left.calibration": _file("right"),
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
