"""build-dataset skips a record whose marker finger's calibration is gone, saying which file and what to do."""

from __future__ import annotations

import dataclasses
import json
import shutil
from pathlib import Path

from estimator.cli import main
from teleop.record import read_record, write_record


def test_a_record_whose_marker_finger_calibration_is_gone_is_skipped_naming_the_file(sim_grasps, tmp_path, capsys):
    records, calibration = sim_grasps
    good_path = sorted(records.glob("*.grasp"))[0]
    good = read_record(good_path)
    marker_fingers = [s.finger for s in good.sensors if s.markers]
    assert len(marker_fingers) == 1, "the simulated rig has one finger with markers"
    folder = tmp_path / "recs"
    folder.mkdir()
    shutil.copy(good_path, folder / "good.grasp")
    gone = tmp_path / "gone" / "cal.npz"
    sensors = tuple(dataclasses.replace(s, calibration=str(gone)) if s.markers else s for s in good.sensors)
    write_record(dataclasses.replace(good, sensors=sensors), folder / "moved_marker_calibration.grasp")
    argv = ["build-dataset", "--records", str(folder), "--out", str(tmp_path / "ds"), "--calibration",
            str(calibration), "--markers", "--size", "32x44", "--shifts", "1", "--json"]
    assert main(argv) == 0
    manifest = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert [Path(u["path"]).name for u in manifest["used"]] == ["good.grasp"]
    [skipped] = manifest["skipped"]
    assert Path(skipped["path"]).name == "moved_marker_calibration.grasp"
    assert skipped["cause"] == "calibration missing"
    assert skipped["reason"].startswith(
        f"it names calibration {gone} for finger {marker_fingers[0]!r}, which does not exist (the file of the "
        "settings it was simulated with): pass --marker-calibration CAL, put the file there, or simulate it again")
