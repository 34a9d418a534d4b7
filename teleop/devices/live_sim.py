"""The simulated devices' live mode: an operator-driven grasp simulated as it happens.

A :class:`LiveGrasp` holds one prepared object (:class:`~teleop.sim.live.LiveObject`) and the
fingers' :class:`~teleop.sim.live.Motor`, and samples them the way the devices deliver data
(the models of :mod:`teleop.sim.sensors`, drawn per sample in real time):

* the load cell converts at ``load_cell.sample_rate_hz`` of its own oscillator (off by a few
  parts per thousand), with a per-grasp gain error and tare residual, white noise of
  ``simulation.force_noise_n``, the ADC's quantisation, and a transport delay to the host,
  which stamps each reading on arrival;
* a width read returns about ``simulation.width_latency_s`` after it was issued with the motor's
  width early in the read, plus ``simulation.width_noise_m`` of noise; the host stamps the return;
* each camera captures at ``camera_hz`` of its own clock from a random phase, imaging the gel at
  the force of the capture instant; the host stamps it ``simulation.camera_offset_s`` later,
  with jitter. Like a real camera's driver, which keeps only the newest frames, a camera that
  gets to a capture slot more than a period late (a renderer slower than ``camera_hz``) drops
  the slots overdue and takes the newest one due: a slow renderer lowers the frame rate (the
  frame index jumps, :meth:`LiveGrasp.frames_dropped` counts) instead of adding latency.

One live grasp is shared by the rig's three ``sim`` devices (``live()`` on each switches them to
it, as ``replay()`` does to a recorded grasp): the gripper's commands drive the motor; the load
cell, the width reader and the cameras sample it.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable

import numpy as np

from teleop.devices.camera import CameraFrame
from teleop.record import Samples
from teleop.settings import Settings
from teleop.sim.live import LiveObject, Motor
from teleop.sim.sensors import (
    CAMERA_JITTER_S,
    CAMERA_RATE_TOLERANCE,
    LOAD_CELL_GAIN_SD,
    LOAD_CELL_RATE_TOLERANCE,
    LOAD_CELL_TARE_READINGS,
    LOAD_CELL_TRANSPORT_S,
    WIDTH_READ_SPREAD,
    WIDTH_SAMPLE_FRACTION,
)

__all__ = ["LiveGrasp"]


class LiveGrasp:
    """One object between the simulated fingers, sampled live (see the module docstring).

    Parameters
    ----------
    obj : LiveObject
        The prepared object.
    settings : Settings
        Rates and noise of the devices (``load_cell``, ``sensors``, ``gripper``, ``simulation``).
    rng : Generator
        Every noise draw of the grasp.
    width_m : float
        The fingers' width now (m).
    clock : callable
        Monotonic seconds, the devices' clock.
    """

    def __init__(self, obj: LiveObject, *, settings: Settings, rng: np.random.Generator, width_m: float,
                 clock: Callable[[], float] = time.monotonic):
        self.object = obj
        self.settings = settings
        self.clock = clock
        self._rng = rng
        self._rng_lock = threading.Lock()  # the readers draw from one generator
        now = clock()
        self.motor = Motor(width_m, now, stall_width_m=obj.stall_width_m)
        cell, sim = settings.load_cell, settings.simulation
        self._cell_period_s = 1.0 / (cell.sample_rate_hz * (1.0 + rng.normal(0.0, LOAD_CELL_RATE_TOLERANCE)))
        self._next_conversion_s = now + rng.uniform(0.0, self._cell_period_s)
        self._cell_gain = 1.0 + rng.normal(0.0, LOAD_CELL_GAIN_SD)
        noise_counts = sim.force_noise_n * cell.counts_per_n
        self._cell_zero_counts = rng.normal(0.0, noise_counts / math.sqrt(LOAD_CELL_TARE_READINGS))
        self._pending: list[tuple[float, float]] = []  # (stamp, N) converted, not yet arrived
        self._cameras = {}
        for sensor in settings.sensors:
            period = 1.0 / (sensor.camera_hz * (1.0 + rng.normal(0.0, CAMERA_RATE_TOLERANCE)))
            # period, next capture, its index, slots dropped
            self._cameras[sensor.finger] = [period, now + rng.uniform(0.0, period), 0, 0]

    def _draw(self, draw: Callable[[np.random.Generator], float]) -> float:
        with self._rng_lock:
            return float(draw(self._rng))

    # ------------------------------------------------------------------ physics

    def force_at(self, t_s: float) -> float:
        """True force (N) at clock time ``t_s`` (s)."""
        return self.object.force_at(self.motor.width_at(t_s))

    def at_force_limit(self) -> bool:
        """Whether the fingers stand where the force reaches its maximum."""
        return self.motor.stalled(self.clock())

    # ------------------------------------------------------------------ gripper

    def width_read(self) -> tuple[float, float]:
        """One width read returning now: ``(stamp_s, width_m)``, the width of early in the read."""
        now = self.clock()
        latency = self.settings.simulation.width_latency_s
        duration = latency * self._draw(lambda r: r.uniform(1.0 - WIDTH_READ_SPREAD, 1.0 + WIDTH_READ_SPREAD))
        sampled = now - duration * (1.0 - self._draw(lambda r: r.uniform(0.0, WIDTH_SAMPLE_FRACTION)))
        noise = self._draw(lambda r: r.normal(0.0, self.settings.simulation.width_noise_m))
        return now, self.motor.width_at(sampled) + noise

    # ------------------------------------------------------------------ load cell

    def forces_due(self) -> Samples:
        """The readings that arrived at the host since the last call (stamps s, N)."""
        now = self.clock()
        cell, sim = self.settings.load_cell, self.settings.simulation
        while self._next_conversion_s <= now:
            t_s = self._next_conversion_s
            counts = (self._cell_zero_counts + self._cell_gain * cell.counts_per_n * self.force_at(t_s)
                      + self._draw(lambda r: r.normal(0.0, sim.force_noise_n * cell.counts_per_n)))
            stamp = t_s + self._draw(lambda r: r.uniform(*LOAD_CELL_TRANSPORT_S))
            self._pending.append((stamp, round(counts) / cell.counts_per_n))
            self._next_conversion_s += self._cell_period_s
        arrived = [p for p in self._pending if p[0] <= now]
        self._pending = [p for p in self._pending if p[0] > now]
        if not arrived:
            return Samples(np.zeros(0), np.zeros(0))
        t, v = np.array(sorted(arrived)).T
        return Samples(t, v)

    def next_reading_s(self) -> float:
        """When the next reading arrives at the host, at the latest (clock s)."""
        return self._next_conversion_s + LOAD_CELL_TRANSPORT_S[1]

    # ------------------------------------------------------------------ cameras

    def next_frame_s(self, finger: str) -> float:
        """When ``finger``'s next frame reaches the host (clock s, before its jitter)."""
        return self._cameras[finger][1] + self.settings.simulation.camera_offset_s

    def frames_dropped(self, finger: str) -> int:
        """Capture slots of ``finger`` dropped so far because the camera got to them too late."""
        return self._cameras[finger][3]

    def take_frame(self, finger: str) -> CameraFrame:
        """``finger``'s next frame, rendered at the force of its capture instant (call once it is due).

        The frame is the newest capture slot due by now: slots the camera got to more than a
        period late (the last render took longer than a period) are dropped, their indices
        skipped, as a camera's driver that keeps only the newest frames does. The capture times
        stay on the camera's grid.
        """
        period, capture_s, index, dropped = self._cameras[finger]
        offset = self.settings.simulation.camera_offset_s
        late = math.floor((self.clock() - offset - capture_s) / period)  # slots due after this one
        if late > 0:
            capture_s, index, dropped = capture_s + late * period, index + late, dropped + late
        self._cameras[finger] = [period, capture_s + period, index + 1, dropped]
        jitter = self._draw(lambda r: np.clip(r.normal(0.0, CAMERA_JITTER_S), -0.2 * period, 0.2 * period))
        stamp = capture_s + offset + jitter
        return CameraFrame(finger, index, stamp, self.object.frame(finger, self.force_at(capture_s)), "jpeg")
