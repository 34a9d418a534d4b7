"""A record written from a sensor read over a URL with a password stores the URL without it."""

from __future__ import annotations

import dataclasses
import json
import zipfile

import numpy as np

from teleop.record import FrameStream, GraspRecord, Provenance, Samples, read_record, write_record
from teleop.settings import load_settings

URL = "http://admin:Hunter2Pass@127.0.0.1:9/?action=stream"
SHOWN = "http://admin:***@127.0.0.1:9/?action=stream"


def test_a_written_records_camera_source_hides_the_password(tmp_path):
    sensors = tuple(dataclasses.replace(s, camera_backend="opencv", camera_source=URL) for s in load_settings().sensors)
    frames = tuple(FrameStream.from_frames(s.finger, np.array([0.0]), np.zeros((1, 8, 8, 3), np.uint8), encoding="png")
                   for s in sensors)
    record = GraspRecord(sensors=sensors, frames=frames, force_n=Samples(np.array([0.0]), np.array([1.0])),
                         width_m=Samples(np.array([0.0]), np.array([0.05])),
                         provenance=Provenance(source="hardware", seed=None, model="test",
                                               created_utc="2025-01-01T00:00:00+00:00"))
    path = write_record(record, tmp_path / "r.grasp")
    with zipfile.ZipFile(path) as zf:
        text = zf.read("record.json").decode("utf-8")
    assert "Hunter2Pass" not in text
    assert [s["camera_source"] for s in json.loads(text)["sensors"]] == [SHOWN, SHOWN]
    assert [s.camera_source for s in read_record(path).sensors] == [SHOWN, SHOWN]
