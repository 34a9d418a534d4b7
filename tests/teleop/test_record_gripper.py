"""The record's optional gripper settings: round trip, records without them, invalid ones."""

from __future__ import annotations

import dataclasses
import json
import zipfile

import numpy as np
import pytest

from teleop.errors import RecordError
from teleop.record import FrameStream, GraspRecord, Provenance, Samples, read_record, write_record
from teleop.settings import GripperSettings, load_settings


def make_record(gripper: GripperSettings | None = None) -> GraspRecord:
    rng = np.random.default_rng(3)
    sensors = load_settings().sensors
    frames = tuple(FrameStream.from_frames(s.finger, [0.0, 0.033], rng.integers(0, 256, (2, 8, 8, 3), dtype=np.uint8))
                   for s in sensors)
    return GraspRecord(sensors=sensors, frames=frames, force_n=Samples([0.0, 0.1], [0.0, 1.0]),
                       width_m=Samples([0.0, 0.1], [0.05, 0.049]), provenance=Provenance(source="simulated"),
                       gripper=gripper)


def header(path) -> dict:
    with zipfile.ZipFile(path) as zf:
        return json.loads(zf.read("record.json"))


def rewrite_header(path, out, change) -> None:
    with zipfile.ZipFile(path) as zin, zipfile.ZipFile(out, "w") as zout:
        for info in zin.infolist():
            data = zin.read(info.filename)
            if info.filename == "record.json":
                data = json.dumps(change(json.loads(data))).encode()
            zout.writestr(info, data)


def test_the_gripper_round_trips(tmp_path):
    gripper = GripperSettings(finger_stiffness_n_per_m=5.0e4, closing_speed_m_s=0.06, target_force_n=12.5)
    path = write_record(make_record(gripper), tmp_path / "g.grasp")
    assert header(path)["gripper"]["finger_stiffness_n_per_m"] == 5.0e4
    assert read_record(path).gripper == gripper


def test_a_record_without_one_has_no_key_and_reads_none(tmp_path):
    path = write_record(make_record(), tmp_path / "plain.grasp")
    assert "gripper" not in header(path)
    assert read_record(path).gripper is None
    # An explicit null (a writer that always writes the key) reads the same.
    rewrite_header(path, tmp_path / "null.grasp", lambda h: {**h, "gripper": None})
    assert read_record(tmp_path / "null.grasp").gripper is None


def test_a_partial_gripper_takes_the_defaults_for_the_rest(tmp_path):
    path = write_record(make_record(), tmp_path / "plain.grasp")
    rewrite_header(path, tmp_path / "partial.grasp", lambda h: {**h, "gripper": {"finger_stiffness_n_per_m": 7e4}})
    assert read_record(tmp_path / "partial.grasp").gripper == dataclasses.replace(
        GripperSettings(), finger_stiffness_n_per_m=7e4)


@pytest.mark.parametrize("table, message", [
    ({"finger_stiffness_n_per_m": -1.0}, "finger_stiffness_n_per_m"),
    ({"closing_speed": 0.05}, "unknown key"),
    ([1, 2], "gripper"),
])
def test_an_invalid_gripper_is_a_record_error_naming_it(tmp_path, table, message):
    path = write_record(make_record(), tmp_path / "plain.grasp")
    bad = tmp_path / "bad.grasp"
    rewrite_header(path, bad, lambda h: {**h, "gripper": table})
    with pytest.raises(RecordError, match="gripper") as info:
        read_record(bad)
    assert message in str(info.value) and str(bad) in str(info.value)
