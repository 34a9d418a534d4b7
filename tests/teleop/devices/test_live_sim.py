"""LiveGrasp on an injected clock: its cameras (a renderer slower than the frame rate drops frames
instead of falling behind; what instant a frame shows), its load cell and its width reads."""

from __future__ import annotations

import dataclasses
import time

import numpy as np
import pytest

from teleop.devices.live_sim import LiveGrasp
from teleop.settings import Settings

JITTER_BOUND = 0.2  # of a period: LiveGrasp clips each frame's stamp jitter to this


class FakeClock:
    def __init__(self, now: float = 1000.0):
        self.now = now

    def __call__(self) -> float:
        return self.now


class SlowObject:
    """A stand-in for :class:`~teleop.sim.live.LiveObject` whose frames take ``render_s`` to render
    (on ``clock``: advanced by a fake clock, slept on the real one)."""

    stall_width_m = 0.0

    def __init__(self, render_s: float, clock: FakeClock | None = None):
        self.render_s, self.clock, self.rendered = render_s, clock, 0

    def force_at(self, width_m: float) -> float:
        return 0.0

    def frame(self, finger: str, force_n: float) -> bytes:
        self.rendered += 1
        if self.clock is not None:
            self.clock.now += self.render_s
        else:
            time.sleep(self.render_s)
        return b"jpeg"


class SpringObject:
    """A stand-in for :class:`~teleop.sim.live.LiveObject`: force ``stiffness * (free_m - width)``
    (``constant_n`` when given); each frame records the force it was rendered at."""

    stall_width_m = 0.0

    def __init__(self, *, free_m: float = 0.06, stiffness: float = 2000.0, constant_n: float | None = None):
        self.free_m, self.stiffness, self.constant_n = free_m, stiffness, constant_n
        self.rendered: list[float] = []

    def force_at(self, width_m: float) -> float:
        if self.constant_n is not None:
            return self.constant_n
        return max(0.0, self.stiffness * (self.free_m - width_m))

    def frame(self, finger: str, force_n: float) -> bytes:
        self.rendered.append(force_n)
        return b"jpeg"


def _live(obj: SlowObject | SpringObject, clock, settings: Settings | None = None) -> LiveGrasp:
    return LiveGrasp(obj, settings=settings or Settings(), rng=np.random.default_rng(0), width_m=0.05, clock=clock)


def _take(grasp: LiveGrasp, clock: FakeClock, finger: str):
    """What the simulated camera's reader does: wait until the next frame is due, then take it.
    Returns (the clock when the camera got to it, the frame, the clock when it was rendered)."""
    clock.now = max(clock.now, grasp.next_frame_s(finger))
    got_to = clock.now
    frame = grasp.take_frame(finger)
    return got_to, frame, clock.now


def _grid(grasp: LiveGrasp, finger: str) -> tuple[float, float]:
    """``finger``'s camera period and when its first frame reaches the host (before jitter)."""
    return grasp._cameras[finger][0], grasp.next_frame_s(finger)


def test_a_renderer_slower_than_the_camera_drops_frames_and_stays_at_most_a_period_behind():
    # A loaded machine rendered slower than 30 Hz: the camera fell behind by seconds, one
    # period per frame, instead of dropping frames like a real camera's driver.
    clock = FakeClock()
    obj = SlowObject(render_s=0.085, clock=clock)  # about 2.5 camera periods per frame
    grasp = _live(obj, clock)
    period, first_s = _grid(grasp, "left")
    taken = [_take(grasp, clock, "left") for _ in range(60)]
    indices = [frame.index for _, frame, _ in taken]
    assert indices[0] == 0 and all(b > a for a, b in zip(indices, indices[1:], strict=False))
    for got_to, frame, rendered in taken:
        slot = (frame.t_s - first_s) / period
        assert abs(slot - frame.index) <= JITTER_BOUND + 1e-6  # stamped at its own slot of the grid
        assert got_to - frame.t_s <= (1 + JITTER_BOUND) * period  # the camera got to it within a period
        assert rendered - frame.t_s <= (1 + JITTER_BOUND) * period + obj.render_s  # delivered then
    assert grasp.frames_dropped("left") == indices[-1] + 1 - len(taken) > 0
    assert indices[-1] + 1 - len(taken) >= len(taken)  # a render of 2.5 periods: most slots dropped
    assert grasp.frames_dropped("right") == 0  # each camera counts its own


def test_a_renderer_faster_than_the_camera_delivers_every_frame_on_its_slot():
    clock = FakeClock()
    obj = SlowObject(render_s=0.01, clock=clock)
    grasp = _live(obj, clock)
    period, first_s = _grid(grasp, "right")
    taken = [_take(grasp, clock, "right") for _ in range(60)]
    assert [frame.index for _, frame, _ in taken] == list(range(60))
    for got_to, frame, _ in taken:
        assert abs((frame.t_s - first_s) / period - frame.index) <= JITTER_BOUND + 1e-6
        assert abs(got_to - frame.t_s) <= JITTER_BOUND * period
    assert grasp.frames_dropped("right") == 0


def test_a_camera_a_period_late_still_takes_its_slot_but_not_the_one_after():
    clock = FakeClock()
    grasp = _live(SlowObject(render_s=0.0, clock=clock), clock)
    period, first_s = _grid(grasp, "left")
    clock.now = first_s + 0.9 * period  # late, but the next slot is not due yet
    assert grasp.take_frame("left").index == 0
    clock.now = first_s + 4.5 * period  # slots 1 to 4 due: 1 to 3 are dropped
    assert grasp.take_frame("left").index == 4
    assert grasp.frames_dropped("left") == 3
    assert abs(grasp.next_frame_s("left") - (first_s + 5 * period)) < 1e-9


def test_the_simulated_camera_counts_the_frames_a_slow_renderer_dropped():
    from teleop.devices.camera import make_camera
    from teleop.settings import SensorSettings

    obj = SlowObject(render_s=0.1)  # three 30 Hz periods per frame, on the real clock
    grasp = _live(obj, time.monotonic)
    camera = make_camera(SensorSettings(finger="left"), backend="sim").connect()
    try:
        camera.live(grasp)
        frames = [camera.read(timeout_s=1.0) for _ in range(5)]
    finally:
        camera.close()
    assert camera.dropped == frames[-1].index + 1 - len(frames) > 0
    assert camera.dropped == grasp.frames_dropped("left")


def test_a_frame_shows_the_force_of_its_capture_instant_not_of_its_arrival():
    clock = FakeClock()
    obj = SpringObject()
    grasp = _live(obj, clock)
    grasp.motor.command(0.01, 0.1, clock.now)  # squeezing: the force rises 200 N/s
    offset = grasp.settings.simulation.camera_offset_s
    for _ in range(10):
        clock.now = grasp.next_frame_s("left")
        capture_s = clock.now - offset
        frame = grasp.take_frame("left")
        assert obj.rendered[-1] == pytest.approx(grasp.force_at(capture_s), abs=1e-9)
        assert frame.t_s == pytest.approx(clock.now, abs=JITTER_BOUND / grasp.settings.sensors[0].camera_hz)


def test_frame_stamps_stay_within_the_jitter_bound_of_their_capture_slot_in_a_long_session():
    # The jitter is clipped there (about 3 sigma at 30 Hz: thousands of frames show a clip that is
    # missing): stamps stay in capture order however many frames a session takes.
    clock = FakeClock()
    grasp = _live(SpringObject(constant_n=0.0), clock)
    period, _ = _grid(grasp, "left")
    stamps, slots = [], []
    for _ in range(5000):
        clock.now = grasp.next_frame_s("left")
        slots.append(clock.now)  # the slot's capture time plus the offset, before jitter
        stamps.append(grasp.take_frame("left").t_s)
    deviation = (np.array(stamps) - np.array(slots)) / period
    assert np.max(np.abs(deviation)) <= JITTER_BOUND + 1e-9
    assert np.all(np.diff(stamps) > 0)


def _forces(grasp: LiveGrasp, clock: FakeClock, seconds: float) -> tuple[np.ndarray, np.ndarray]:
    """The readings that arrive over ``seconds``, polled every 10 ms: (stamps s, N)."""
    t, v = [], []
    end = clock.now + seconds
    while clock.now < end:
        clock.now += 0.01
        due = grasp.forces_due()
        t.extend(due.t_s)
        v.extend(due.value)
    return np.array(t), np.array(v)


def test_the_cell_reads_at_its_sample_rate_in_newtons_with_its_noise():
    clock = FakeClock()
    settings = Settings()
    grasp = _live(SpringObject(constant_n=3.3), clock, settings)
    t, v = _forces(grasp, clock, 5.0)
    rate = settings.load_cell.sample_rate_hz
    assert len(t) == pytest.approx(5.0 * rate, rel=0.02)  # its own oscillator: off by parts per thousand
    assert np.median(np.diff(t)) == pytest.approx(1.0 / rate, rel=0.05)
    assert v.mean() == pytest.approx(3.3, abs=0.1)  # a gain error of about 1 %, not whole newtons
    noise = settings.simulation.force_noise_n
    assert 0.5 * noise < v.std() < 2.0 * noise
    counts = v * settings.load_cell.counts_per_n  # the ADC's quantisation: whole counts
    np.testing.assert_allclose(counts, np.round(counts), atol=1e-6)


def test_the_next_reading_has_arrived_by_the_time_next_reading_s_says():
    clock = FakeClock()
    grasp = _live(SpringObject(constant_n=1.0), clock)
    for _ in range(20):
        clock.now = grasp.next_reading_s()
        assert len(grasp.forces_due()) >= 1  # "at the latest": a reader waiting until then gets it


def test_a_width_read_returns_the_width_of_early_in_the_read_not_a_later_one():
    clock = FakeClock()
    settings = Settings()
    settings = dataclasses.replace(settings, simulation=dataclasses.replace(settings.simulation, width_noise_m=0.0))
    grasp = _live(SpringObject(), clock, settings)
    grasp.motor.command(0.01, 0.1, clock.now)  # closing at 0.1 m/s
    clock.now += 0.2
    latency = settings.simulation.width_latency_s
    stamp, width = grasp.width_read()
    assert stamp == clock.now
    # sampled between (1 - 0.15) * 0.9 and (1 + 0.15) latencies before the return: closing, a wider width
    assert grasp.motor.width_at(clock.now - 0.85 * 0.9 * latency) - 1e-12 <= width
    assert width <= grasp.motor.width_at(clock.now - 1.15 * latency) + 1e-12
    assert width > grasp.motor.width_at(clock.now)
