"""``teleop doctor`` on a calibration or model stamped later than this host's clock: a warning that the
clock or the file's stamp is wrong, not a negative age."""

from __future__ import annotations

import dataclasses
import json
import os
import time
from datetime import UTC, datetime, timedelta

import pytest
from support.rig_settings import rig_settings

from estimator.perception.calibration import load_calibration
from teleop.settings import config_dir, load_settings
from teleop.system.doctor import _table, check_calibrations

DAY_S = 86400.0
FUTURE = (datetime.now(UTC) + timedelta(days=400)).isoformat(timespec="seconds")


def _calibration_stamped(tmp_path, finger, created_utc):
    calibration = load_calibration(config_dir() / "calibration" / f"sim-wedge-{finger}.npz")
    provenance = {**calibration.provenance, "created_utc": created_utc}
    return str(dataclasses.replace(calibration, provenance=provenance).save(tmp_path / f"{finger}.npz"))


def _checks(path):
    return {c.name: c for c in check_calibrations(load_settings(path), path)}


def _assert_future(check, stamp):
    assert check.ok and check.problem is None
    assert "age_days" not in check.detail
    assert check.warning.startswith("stamped in the future (") and stamp in check.warning
    assert check.warning.endswith("the clock or the file's stamp is wrong")


def test_a_calibration_created_in_the_future_is_a_warning_not_a_negative_age(tmp_path):
    path = rig_settings(tmp_path, {"sensors.left.calibration": _calibration_stamped(tmp_path, "left", FUTURE),
                           "sensors.right.calibration": str(config_dir() / "calibration" / "sim-wedge-right.npz")})
    checks = _checks(path)
    _assert_future(checks["calibration left"], f"created_utc {FUTURE}")
    assert checks["calibration right"].detail["age_days"] >= 0 and checks["calibration right"].warning is None
    report = {"ok": True, "devices": [], "endpoints": [], "calibrations": [dataclasses.asdict(c) for c in checks.values()]}
    row = next(line for line in _table(report).splitlines() if line.startswith("calibration left"))
    assert row.split()[2] == "warn" and "stamped in the future" in row and "days old" not in row


@pytest.mark.parametrize("metadata", [{"created_utc": FUTURE}, {}])
def test_a_model_stamped_in_the_future_is_a_warning_not_a_negative_age(tmp_path, metadata):
    model = tmp_path / "model"
    model.mkdir()
    (model / "model.onnx").write_bytes(b"")
    (model / "metadata.json").write_text(json.dumps(metadata))
    later = time.time() + 3 * DAY_S  # the file's time, where no creation is recorded
    os.utime(model / "model.onnx", (later, later))
    check = _checks(rig_settings(tmp_path, {"estimator.model_path": str(model)}))["model"]
    _assert_future(check, f"created_utc {FUTURE}" if metadata else "its file time")


def test_a_stamp_within_a_minute_ahead_is_age_zero(tmp_path):
    soon = (datetime.now(UTC) + timedelta(seconds=20)).isoformat(timespec="seconds")
    path = rig_settings(tmp_path, {"sensors.left.calibration": _calibration_stamped(tmp_path, "left", soon)})
    left = _checks(path)["calibration left"]
    assert left.detail["age_days"] == 0.0 and left.warning is None

