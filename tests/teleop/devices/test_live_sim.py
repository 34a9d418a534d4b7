"""LiveGrasp's cameras: a renderer slower than the frame rate drops frames instead of falling behind."""

from __future__ import annotations

import time

import numpy as np

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


def _live(obj: SlowObject, clock) -> LiveGrasp:
    return LiveGrasp(obj, settings=Settings(), rng=np.random.default_rng(0), width_m=0.05, clock=clock)


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
