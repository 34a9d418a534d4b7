"""Simulated sensor streams (teleop.sim.sensors): rates, noise, quantisation, latency, clocks."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from teleop.settings import GripperSettings, LoadCellSettings, SensorSettings, SimulationSettings
from teleop.sim.sensors import camera_times, gripper_width_readings, load_cell_readings

T = np.arange(-1.0, 11.0, 1e-3)
SIM = SimulationSettings()


def readings(force: np.ndarray, *, seed: int = 0, cell: LoadCellSettings | None = None, sim=SIM):
    return load_cell_readings(T, force, load_cell=cell or LoadCellSettings(), sim=sim,
                              rng=np.random.default_rng(seed), start_s=0.0, end_s=10.0)


def test_load_cell_rate_noise_and_tare_residual():
    samples = readings(np.zeros_like(T))
    assert np.median(np.diff(samples.t_s)) == pytest.approx(1 / 80.0, rel=0.02)
    assert samples.t_s.min() >= 0.0 and samples.t_s.max() <= 10.0 and np.all(np.diff(samples.t_s) > 0)
    assert np.std(samples.value) == pytest.approx(SIM.force_noise_n, rel=0.15)
    offsets = [abs(np.mean(readings(np.zeros_like(T), seed=s).value[:40])) for s in range(20)]
    assert 0 < np.median(offsets) < SIM.force_noise_n  # tared by the host, not exactly
    slow = readings(np.zeros_like(T), cell=LoadCellSettings(sample_rate_hz=10.0))
    assert np.median(np.diff(slow.t_s)) == pytest.approx(0.1, rel=0.02)


def test_load_cell_counts_are_quantised_and_clipped_at_24_bits():
    cell = LoadCellSettings(counts_per_n=1000.0)
    quiet = dataclasses.replace(SIM, force_noise_n=0.0)
    samples = readings(np.full_like(T, 3.0), cell=cell, sim=quiet)
    counts = samples.value * cell.counts_per_n
    np.testing.assert_allclose(counts, np.rint(counts), atol=1e-6)  # whole counts about the host's zero
    assert np.median(samples.value) == pytest.approx(3.0, rel=0.05)  # gain error ~1 %
    huge = readings(np.full_like(T, 1e5), cell=cell, sim=quiet)
    assert np.ptp(huge.value) < 0.01 and huge.value.max() < 2**23 / cell.counts_per_n + 10  # saturated


def test_load_cell_follows_the_force_with_its_own_timestamps():
    force = np.clip((T - 2.0) * 10.0, 0.0, 20.0)
    samples = readings(force)
    ramp = (samples.t_s > 2.2) & (samples.t_s < 3.8)
    slope, intercept = np.polyfit(samples.t_s[ramp], samples.value[ramp], 1)  # value = g 10 (t - 2 - lag)
    assert slope == pytest.approx(10.0, rel=0.05)  # the scale factor's small error
    assert 0.0 < -intercept / slope - 2.0 < 0.006  # transport delay of a few ms, no more


def test_width_reads_arrive_late_by_about_the_read_latency():
    speed = 0.0375
    width = 0.08 - speed * np.clip(T, 0.0, None)
    samples = gripper_width_readings(T, width, gripper=GripperSettings(), sim=SIM,
                                     rng=np.random.default_rng(1), start_s=0.0, end_s=1.5)
    assert np.median(np.diff(samples.t_s)) == pytest.approx(SIM.width_latency_s, rel=0.2)
    lag = np.median((samples.value - (0.08 - speed * samples.t_s)) / speed)
    assert 0.8 * SIM.width_latency_s < lag < 1.1 * SIM.width_latency_s
    still = gripper_width_readings(T, np.full_like(T, 0.03), gripper=GripperSettings(), sim=SIM,
                                   rng=np.random.default_rng(2), start_s=0.0, end_s=10.0)
    assert np.std(still.value) == pytest.approx(SIM.width_noise_m, rel=0.3)
    fast = gripper_width_readings(T, width, gripper=GripperSettings(width_read_hz=2.0), sim=SIM,
                                  rng=np.random.default_rng(1), start_s=0.0, end_s=5.0)
    assert np.median(np.diff(fast.t_s)) == pytest.approx(0.5, rel=0.05)  # the read rate caps it


def test_camera_frames_at_its_rate_with_its_clock_offset():
    sensor = SensorSettings(camera_hz=30.0)
    capture, stamps = camera_times(sensor=sensor, sim=SIM, rng=np.random.default_rng(0), start_s=0.0, end_s=3.0)
    assert np.all(np.diff(stamps) > 0) and np.all(np.diff(capture) > 0)
    assert stamps.min() >= 0.0 and stamps.max() <= 3.0 and len(stamps) == pytest.approx(90, abs=2)
    assert np.median(np.diff(capture)) == pytest.approx(1 / 30.0, rel=1e-3)
    assert np.mean(stamps - capture) == pytest.approx(SIM.camera_offset_s, abs=1e-3)
    assert np.std(stamps - capture) > 0  # jitter
    other = camera_times(sensor=sensor, sim=SIM, rng=np.random.default_rng(1), start_s=0.0, end_s=3.0)[0]
    assert abs(other[0] - capture[0]) > 1e-4  # each camera has its own phase
