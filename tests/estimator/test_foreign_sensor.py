"""A lab's own sensor, end to end with no code change: a GelSight Mini calibrated with
``estimator calibrate`` into a file of its own, grasp records of that sensor (``model = "mini"``,
the calibration named by an absolute path) and ``estimator evaluate`` on them.

The records carry their sensor's settings (a flat 640 x 480 px sensor at 0.0295 mm/px: no warp,
so the Wedge mirror corners it keeps by default are never read); ``--settings`` carries the finger
stiffness of the gripper (the records carry none).
"""

from __future__ import annotations

import csv
import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest

from estimator.analytical import METHODS
from estimator.cli import main
from teleop.catalogue import ObjectSpec
from teleop.record import read_record, write_record
from teleop.settings import (
    CONFIG_DIR,
    GripperSettings,
    SensorSettings,
    default_settings_path,
    load_settings,
)
from teleop.sim.grasp import simulate_grasp

# One worker builds the module's lab (calibration, records) once: its tests need not wait for it twice.
# Slow: building the lab calibrates a Mini on real presses (seconds).
pytestmark = [pytest.mark.xdist_group("foreign_sensor_lab"), pytest.mark.slow]

PITCH_M = 2.95e-5  # taxim's GelSight Mini: 0.0295 mm per raw px
# The lab's fingers, softer than the shipped settings' (what --settings tells evaluate).
FINGERS_N_PER_M = 8.0e4
OBJECTS = (
    ObjectSpec(name="rubber_ball", shape="sphere", material="rubber", modulus_pa=8.0e5, size_m=(0.02,) * 3),
    ObjectSpec(name="foam_block", shape="box", material="foam", modulus_pa=1.0e5, size_m=(0.03, 0.03, 0.03)),
)
PER_METHOD = ("n", "log10_error", "within_10x", "felt_log10_error", "felt_within_2x", "dangerous_misses",
              "interval_coverage", "states")

# The lab's description of its sensor: a flat GelSight Mini; nothing about a warp.
LAB_SENSORS = """
[sensors.left]
model = "mini"
raw_width_px = 640
raw_height_px = 480
pixel_pitch_m = 2.95e-5

[sensors.right]
model = "mini"
raw_width_px = 640
raw_height_px = 480
pixel_pitch_m = 2.95e-5
"""


def run_json(capsys, *argv: str) -> dict:
    code = main([*argv, "--json"])
    out, err = capsys.readouterr()
    assert code == 0, err
    return json.loads(out.strip().splitlines()[-1])


@pytest.fixture(scope="module")
def lab(tmp_path_factory, taxim_calib_dir, missing_data) -> dict[str, Path]:
    """The lab's files: its calibration (``estimator calibrate`` on taxim's real GelSight Mini presses,
    the sensor described by a settings file), its records and its evaluation settings."""
    pack = taxim_calib_dir / "gelsight_mini" / "dataPack.npz"
    if not pack.is_file():
        missing_data(f"{pack} not found")
    root = tmp_path_factory.mktemp("lab")
    sensor_toml = root / "mini.toml"
    sensor_toml.write_text(LAB_SENSORS)
    calibration = root / "cal" / "gelsight-mini-left.npz"
    calibration.parent.mkdir()
    assert main(["calibrate", "--presses", str(pack), "--ball-radius-mm", "2", "--settings", str(sensor_toml),
                 "--finger", "left", "--out", str(calibration), "--json"]) == 0

    # Grasps simulated through the GelSight Mini optics (measured colour tables of the same real sensor)
    # on a rig with the lab's fingers; the raw frame is the image (identity warp, no crop).
    rig = load_settings(CONFIG_DIR / "rigs" / "gelsight_mini.toml")
    rig = dataclasses.replace(
        rig, sensors=tuple(dataclasses.replace(s, model="mini", crop_px=0) for s in rig.sensors),
        gripper=dataclasses.replace(rig.gripper, finger_stiffness_n_per_m=FINGERS_N_PER_M))
    records = root / "records"
    records.mkdir()
    for i, obj in enumerate(OBJECTS):
        record, _ = simulate_grasp(obj, settings=rig, rng=np.random.default_rng(30 + i), seed=30 + i)
        # As the lab records them: its sensor's settings, the calibration by absolute path, no gripper.
        sensors = tuple(SensorSettings(finger=s.finger, model="mini", serial=f"lab-mini-{s.finger}",
                                       calibration=str(calibration.resolve()), raw_width_px=640,
                                       raw_height_px=480, pixel_pitch_m=PITCH_M, gel_modulus_pa=s.gel_modulus_pa,
                                       gel_thickness_m=s.gel_thickness_m)
                        for s in record.sensors)
        write_record(dataclasses.replace(record, sensors=sensors, gripper=None), records / f"{obj.name}.grasp")

    settings = root / "settings.toml"
    shipped = default_settings_path().read_text()
    line = f"finger_stiffness_n_per_m = {GripperSettings().finger_stiffness_n_per_m}"
    assert line in shipped
    settings.write_text(shipped.replace(line, f"finger_stiffness_n_per_m = {FINGERS_N_PER_M}"))
    return {"calibration": calibration, "records": records, "settings": settings, "root": root}


def test_calibrating_a_mini_with_its_settings_keeps_the_raw_frame(lab, taxim_calib_dir, capsys):
    """A flat sensor's raw frame is its image: described by a settings file or not, the same table."""
    plain = lab["root"] / "plain.npz"
    summary = run_json(capsys, "calibrate", "--presses", str(taxim_calib_dir / "gelsight_mini" / "dataPack.npz"),
                       "--ball-radius-mm", "2", "--mm-per-px", "0.0295", "--out", str(plain))
    assert summary["image_shape"] == [480, 640]
    with np.load(plain) as a, np.load(lab["calibration"]) as b:
        assert np.array_equal(a["lut"], b["lut"])
        assert json.loads(str(b["meta"]))["provenance"]["sensor"]["model"] == "mini"


def test_evaluate_runs_on_the_records_of_a_calibrated_mini(lab, capsys):
    for path in sorted(lab["records"].glob("*.grasp")):
        record = read_record(path)
        sensor = record.sensor("left")
        assert sensor.model == "mini" and sensor.image_shape == (480, 640) and record.gripper is None
        assert Path(sensor.calibration).is_absolute()
    rows = lab["root"] / "rows.csv"
    result = run_json(capsys, "evaluate", str(lab["records"]), "--settings", str(lab["settings"]),
                      "--rows", str(rows))
    assert result["labelled"] == len(OBJECTS) and result["skipped"] == {}
    methods = result["methods"]
    # Every analytical method, and the shipped default model's.
    assert set(METHODS) <= set(methods) and {"hybrid", "auto"} <= set(methods)
    assert [Path(m).parts[-3:] for m in result["models"]] == [("estimator", "models", "default")]
    for name, m in methods.items():
        assert set(PER_METHOD) <= set(m), name
        assert m["n"] == len(OBJECTS), name
        assert m["dangerous_misses"] is not None and m["interval_coverage"] is not None, name
    with open(rows, newline="") as handle:
        table = list(csv.DictReader(handle))
    # Depth was measured on every grasp with the lab's calibration: no method was refused.
    assert len(table) == len(OBJECTS) * len(methods)
    assert all(r["state"] != "insufficient_data" for r in table), table


def test_the_calibration_the_record_names_is_the_one_read(lab, tmp_path, capsys):
    """A record naming a missing absolute calibration fails naming it (no fallback to a shipped one)."""
    missing = tmp_path / "gone" / "gelsight-mini-left.npz"
    record = read_record(next(lab["records"].glob("*.grasp")))
    sensors = tuple(dataclasses.replace(s, calibration=str(missing)) for s in record.sensors)
    (tmp_path / "records").mkdir()
    write_record(dataclasses.replace(record, sensors=sensors), tmp_path / "records" / "r.grasp")
    assert main(["evaluate", str(tmp_path / "records"), "--settings", str(lab["settings"]),
                 "--methods", "series", "--json"]) == 2
    err = capsys.readouterr().err
    assert str(missing) in err and "does not exist" in err


def no_tactile_e_pa(capsys, records: Path, settings: Path, rows: Path) -> dict[str, float]:
    run_json(capsys, "evaluate", str(records), "--settings", str(settings), "--methods", "no_tactile",
             "--rows", str(rows))
    with open(rows, newline="") as handle:
        return {r["object"]: float(r["e_pa"]) for r in csv.DictReader(handle)}


def test_the_finger_stiffness_comes_from_the_settings_or_the_record(lab, tmp_path, capsys):
    told = no_tactile_e_pa(capsys, lab["records"], lab["settings"], tmp_path / "told.csv")
    shipped = no_tactile_e_pa(capsys, lab["records"], default_settings_path(), tmp_path / "shipped.csv")
    # Told the fingers are stiffer than they are, the estimator puts their bending on the object: softer.
    assert told.keys() == shipped.keys() == {o.name for o in OBJECTS}
    assert all(shipped[name] < told[name] for name in told)
    # A record that carries its gripper is read with that gripper's stiffness, whatever the settings say.
    carried = tmp_path / "carried"
    carried.mkdir()
    for path in lab["records"].glob("*.grasp"):
        record = read_record(path)
        write_record(dataclasses.replace(record, gripper=GripperSettings(finger_stiffness_n_per_m=FINGERS_N_PER_M)),
                     carried / path.name)
    assert no_tactile_e_pa(capsys, carried, default_settings_path(), tmp_path / "carried.csv") == told
