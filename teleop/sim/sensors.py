"""Simulated sensor streams: what the host records of a simulated grasp.

Each function samples a true trajectory (a fine time grid of force or motor
width) the way one device delivers it, and returns what the host would store:
values in SI units and the host's own timestamps (one clock, seconds). The
devices' errors are part of the model:

* Load cell (HX711 behind a bridge): conversions at 10 or 80 Hz from its own
  oscillator (rate off by up to a few parts per thousand), a 24-bit signed ADC
  (counts clipped to [-2^23, 2^23 - 1]), white noise, a gain error of the scale
  factor, a tare taken by the host from no-load readings (so a small residual
  offset remains) that drifts slowly; the host converts counts to newtons with
  the configured ``counts_per_n`` and stamps each reading on arrival.
* Gripper width (franky): each read blocks for about ``width_latency_s``; the
  value is the motor's width when the controller sampled it, early in the
  call, and the host stamps it when the call returns, so widths arrive late
  by about one read latency. Reads are issued back to back, at most
  ``width_read_hz`` per second. Noise ``width_noise_m``.
* Tactile cameras: frames at ``camera_hz`` of their own clock (a few ppm off),
  random phase, stamped at capture plus ``camera_offset_s`` (camera clock minus
  robot clock) plus jitter.
"""

from __future__ import annotations

import numpy as np

from teleop.record import Samples
from teleop.settings import GripperSettings, LoadCellSettings, SensorSettings, SimulationSettings

__all__ = ["camera_times", "gripper_width_readings", "load_cell_readings"]

ADC_MIN_COUNTS, ADC_MAX_COUNTS = -(2**23), 2**23 - 1
LOAD_CELL_RATE_TOLERANCE = 0.003  # HX711 internal oscillator, relative s.d.
LOAD_CELL_GAIN_SD = 0.01  # residual error of the calibrated scale factor
LOAD_CELL_DRIFT_SD_N_PER_S = 0.003
LOAD_CELL_TARE_READINGS = 32  # no-load readings the host averages to tare
LOAD_CELL_TRANSPORT_S = (0.001, 0.004)  # bridge to host, uniform range
WIDTH_READ_SPREAD = 0.15  # each read's duration: latency times 1 +- this
WIDTH_SAMPLE_FRACTION = 0.1  # the controller samples the width within this first part of a read
CAMERA_RATE_TOLERANCE = 5e-5
CAMERA_JITTER_S = 0.002


def _window(t_s: np.ndarray, start_s: float, end_s: float) -> np.ndarray:
    return (t_s >= start_s) & (t_s <= end_s)


def load_cell_readings(truth_t_s: np.ndarray, truth_force_n: np.ndarray, *, load_cell: LoadCellSettings,
                       sim: SimulationSettings, rng: np.random.Generator, start_s: float,
                       end_s: float) -> Samples:
    """Host-side load-cell readings (N) of a true force trajectory.

    Parameters
    ----------
    truth_t_s, truth_force_n : ndarray
        True normal force (N) on a fine time grid (s), interpolated linearly.
    load_cell : LoadCellSettings
        ``sample_rate_hz``, ``counts_per_n``, ``tare_counts`` (the ADC's nominal zero).
    sim : SimulationSettings
        ``force_noise_n``: s.d. of the conversion noise (N).
    rng : Generator
    start_s, end_s : float
        The host keeps readings stamped in this window.

    Returns
    -------
    Samples
        Host stamps (s) and forces (N) as the host converts the counts.
    """
    period = 1.0 / (load_cell.sample_rate_hz * (1.0 + rng.normal(0.0, LOAD_CELL_RATE_TOLERANCE)))
    first = start_s - LOAD_CELL_TRANSPORT_S[1] - rng.uniform(0.0, period)
    conversions = first + period * np.arange(int((end_s - first) / period) + 1)
    counts_per_n = load_cell.counts_per_n
    noise_counts = sim.force_noise_n * counts_per_n
    zero_counts = load_cell.tare_counts + rng.normal(0.0, 2000.0)  # the ADC's offset today
    # The host tared on no-load readings before the grasp: its zero misses by their mean noise.
    host_zero = np.rint(zero_counts + rng.normal(0.0, noise_counts / np.sqrt(LOAD_CELL_TARE_READINGS)))
    drift_counts = rng.normal(0.0, LOAD_CELL_DRIFT_SD_N_PER_S) * counts_per_n * (conversions - first)
    force = np.interp(conversions, truth_t_s, truth_force_n)
    gain = 1.0 + rng.normal(0.0, LOAD_CELL_GAIN_SD)
    counts = np.rint(zero_counts + drift_counts + gain * counts_per_n * force
                     + rng.normal(0.0, noise_counts, conversions.shape))
    counts = np.clip(counts, ADC_MIN_COUNTS, ADC_MAX_COUNTS)
    stamps = conversions + rng.uniform(*LOAD_CELL_TRANSPORT_S, conversions.shape)
    keep = _window(stamps, start_s, end_s)
    return Samples(stamps[keep], (counts[keep] - host_zero) / counts_per_n)


def gripper_width_readings(truth_t_s: np.ndarray, truth_width_m: np.ndarray, *, gripper: GripperSettings,
                           sim: SimulationSettings, rng: np.random.Generator, start_s: float,
                           end_s: float) -> Samples:
    """Host-side gripper width reads (m) of the true motor width.

    A read issued at t_req returns at t_req + d (d about ``sim.width_latency_s``)
    with the width the controller sampled shortly after t_req; the host stamps
    the return.
    """
    min_period = 1.0 / gripper.width_read_hz
    mean_duration = max(sim.width_latency_s, 1e-3)
    n = int((end_s - start_s) / max(min(min_period, mean_duration), 1e-3)) + 3
    durations = mean_duration * rng.uniform(1.0 - WIDTH_READ_SPREAD, 1.0 + WIDTH_READ_SPREAD, n)
    # The next read starts when the last returned, but no sooner than the read rate allows.
    steps = np.maximum(durations, min_period)
    requests = start_s - rng.uniform(0.0, steps[0]) + np.concatenate([[0.0], np.cumsum(steps[:-1])])
    returns = requests + durations
    sampled = requests + rng.uniform(0.0, WIDTH_SAMPLE_FRACTION, n) * durations
    width = np.interp(sampled, truth_t_s, truth_width_m) + rng.normal(0.0, sim.width_noise_m, n)
    keep = _window(returns, start_s, end_s)
    return Samples(returns[keep], width[keep])


def camera_times(*, sensor: SensorSettings, sim: SimulationSettings, rng: np.random.Generator,
                 start_s: float, end_s: float) -> tuple[np.ndarray, np.ndarray]:
    """Capture times (true, robot clock) and host stamps of one tactile camera's frames.

    Returns
    -------
    capture_s, stamp_s : ndarray
        The instant each frame images the gel, and the time the record gives it
        (capture + ``sim.camera_offset_s`` + jitter), both strictly increasing,
        stamps within [start_s, end_s].
    """
    period = 1.0 / (sensor.camera_hz * (1.0 + rng.normal(0.0, CAMERA_RATE_TOLERANCE)))
    first = start_s - sim.camera_offset_s - 2 * period - rng.uniform(0.0, period)
    capture = first + period * np.arange(int((end_s - first) / period) + 4)
    jitter = np.clip(rng.normal(0.0, CAMERA_JITTER_S, capture.shape), -0.2 * period, 0.2 * period)
    stamps = capture + sim.camera_offset_s + jitter
    keep = _window(stamps, start_s, end_s)
    return capture[keep], stamps[keep]
