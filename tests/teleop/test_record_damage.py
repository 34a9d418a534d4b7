"""A grasp record cut short is called truncated, not a record missing its header: its last member
is an uncompressed calibration .npz, whose own end-of-archive record zipfile would otherwise open."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from estimator.perception import Calibration
from teleop.errors import RecordError
from teleop.record import FrameStream, GraspRecord, Provenance, Samples, read_record, write_record
from teleop.settings import load_settings


@pytest.fixture
def record_path(tmp_path):
    sensors = load_settings().sensors
    frames = tuple(FrameStream.from_frames(s.finger, np.array([0.0, 0.033]), np.zeros((2, 24, 32, 3), np.uint8))
                   for s in sensors)
    calibration = Calibration(lut=np.zeros((1, 1, 4, 4, 4, 2), np.float32), image_shape=(24, 32),
                              pixel_pitch_m=3e-5, ball_radius_m=2e-3, provenance={}).save(tmp_path / "cal.npz")
    record = GraspRecord(sensors=sensors, frames=frames, force_n=Samples(np.array([0.0, 1.0]), np.array([0.0, 5.0])),
                         width_m=Samples(np.array([0.0, 1.0]), np.array([0.05, 0.04])),
                         provenance=Provenance(source="simulated", seed=1, model="test",
                                               created_utc="2025-01-01T00:00:00+00:00"))
    record = dataclasses.replace(record, calibration_files={sensors[0].finger: calibration.read_bytes()})
    return write_record(record, tmp_path / "good.grasp")


@pytest.mark.parametrize("cut", [22, 100])
def test_a_record_cut_at_its_end_is_called_truncated(tmp_path, record_path, cut):
    read_record(record_path)  # whole, it reads
    data = record_path.read_bytes()
    cut_path = tmp_path / "trunc_end.grasp"
    cut_path.write_bytes(data[:-cut])
    with pytest.raises(RecordError, match=f"{cut_path}: .*truncated or damaged") as caught:
        read_record(cut_path)
    assert "record.json" not in str(caught.value)
