"""Simulated twins of the robot's devices: live, real-time replays of a recorded grasp.

The simulator (:mod:`teleop.sim`) produces a whole grasp offline as a
:class:`~teleop.record.GraspRecord`. A :class:`GraspPlayback` replays it on the monotonic
clock: from :meth:`GraspPlayback.start` on, each force sample, width sample and frame
becomes due at its own record timestamp, shifted by one constant so that the record's
``command_grasp`` event (or, without one, its earliest sample) falls on the start time.
The ``sim`` backends of the three families release exactly what the record holds, when
it falls due, stamped with those shifted times, like hardware would:

* :class:`SimulatedGripper`: ``grasp()`` starts the replay (if not started) and returns
  when the recorded fingers stop at the target force (the record's ``grasp_done`` event;
  without one, where the recorded width reaches its minimum); the width read then is the
  record's next width read, handed out at once and stamped as the record stamps it (so the
  live width stream stays the recorded one, as a model trained on records expects), or at
  the record's end the recorded width of the hold (:meth:`GraspPlayback.hold_width_m`).
  Widths come from the record until it ends.
  A replay cannot react to commands: ``move()`` during a replay waits for its end. Without
  a replay (or after it) the gripper is kinematic: the width moves at the commanded speed,
  stalling at ``object_width_m`` when an object is given.
* :class:`SimulatedCamera`: every frame of its finger, in order, each when due (a replay's frames
  are pre-rendered: a reader that fell behind catches up at once, so none is dropped).
* :class:`SimulatedLoadCell`: every force sample due since the last read.

One playback is shared by all devices of a rig; :meth:`replay` on each device switches
them to the next grasp.

Live mode: ``live(grasp)`` on each device switches it to a
:class:`~teleop.devices.live_sim.LiveGrasp` instead, an operator-driven grasp simulated as it
happens: the gripper's moves, grasps and :meth:`~teleop.devices.gripper.Gripper.follow` drive
the simulated motor (stalling at the maximum force), the width reads, the load cell and the
cameras sample it. ``live(None)`` or a ``replay()`` leaves live mode; the gripper's kinematics
take over from the live width.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from typing import TYPE_CHECKING

import numpy as np

from teleop.devices.camera import CameraFrame, TactileCamera
from teleop.devices.gripper import Gripper
from teleop.devices.loadcell import LoadCell
from teleop.errors import DeviceError
from teleop.record import GRASP_DONE_EVENT, GraspRecord, Samples
from teleop.settings import GripperSettings, LoadCellSettings, SensorSettings

if TYPE_CHECKING:  # the class is only named here: the simulator stays unloaded where nothing simulates
    from teleop.devices.live_sim import LiveGrasp

__all__ = ["GraspPlayback", "SimulatedCamera", "SimulatedGripper", "SimulatedLoadCell"]


class GraspPlayback:
    """A grasp record replayed in real time.

    Parameters
    ----------
    record : GraspRecord
        The grasp to replay.
    clock : callable, optional
        Monotonic seconds; ``time.monotonic`` (the device clock) by default.
    """

    def __init__(self, record: GraspRecord, *, clock: Callable[[], float] = time.monotonic):
        self.record = record
        self.clock = clock
        firsts = [s.t_s[0] for s in (record.force_n, record.width_m, *record.frames) if len(s)]
        lasts = [s.t_s[-1] for s in (record.force_n, record.width_m, *record.frames) if len(s)]
        if not firsts:
            raise DeviceError("cannot replay a grasp record without any samples or frames")
        self.origin_s = float(record.events.get("command_grasp", min(firsts)))
        self.duration_s = float(max(lasts) - self.origin_s)
        self._t0_s: float | None = None
        self._started = threading.Event()

    @property
    def started(self) -> bool:
        return self._started.is_set()

    def start(self, t0_s: float | None = None) -> None:
        """Start the replay: the record's origin falls on ``t0_s`` (default: now)."""
        if self.started:
            raise DeviceError("this grasp playback was already started; make a new one to replay again")
        self._t0_s = self.clock() if t0_s is None else float(t0_s)
        self._started.set()

    def wait_started(self, timeout_s: float) -> bool:
        """Block until :meth:`start` was called (True) or ``timeout_s`` passed (False)."""
        return self._started.wait(timeout_s)

    def live_time(self, t_record_s: np.ndarray | float) -> np.ndarray | float:
        """Record time(s) to device-clock time(s); the playback must have started."""
        if self._t0_s is None:
            raise DeviceError("grasp playback has not started")
        return t_record_s - self.origin_s + self._t0_s

    def now(self) -> float:
        return self.clock()

    def done(self, now_s: float | None = None) -> bool:
        """Whether everything in the record is due."""
        if not self.started:
            return False
        return (self.now() if now_s is None else now_s) >= self.live_time(self.origin_s + self.duration_s)

    def _due(self, samples: Samples, start: int, now_s: float | None) -> tuple[int, Samples]:
        if not self.started:
            return start, Samples(np.zeros(0), np.zeros(0))
        now = self.now() if now_s is None else now_s
        live = self.live_time(samples.t_s)
        end = max(start, int(np.searchsorted(live, now, side="right")))
        return end, Samples(live[start:end], samples.value[start:end])

    def forces_due(self, start: int, now_s: float | None = None) -> tuple[int, Samples]:
        """Force samples ``start:end`` due by now (live times); returns ``(end, samples)``."""
        return self._due(self.record.force_n, start, now_s)

    def widths_due(self, start: int, now_s: float | None = None) -> tuple[int, Samples]:
        """Width samples ``start:end`` due by now (live times); returns ``(end, samples)``."""
        return self._due(self.record.width_m, start, now_s)

    def frame_count(self, finger: str) -> int:
        return len(self.record.stream(finger))

    def frame_due_s(self, finger: str, index: int) -> float:
        """Live time at which frame ``index`` of ``finger`` is due."""
        return float(self.live_time(self.record.stream(finger).t_s[index]))

    def frame_due(self, finger: str, now_s: float | None = None) -> int | None:
        """Index of the latest frame of ``finger`` due by now, or None."""
        if not self.started:
            return None
        now = self.now() if now_s is None else now_s
        live = self.live_time(self.record.stream(finger).t_s)
        index = int(np.searchsorted(live, now, side="right")) - 1
        return index if index >= 0 else None

    def grasp_settled_s(self) -> float:
        """Live time at which the fingers stop and the grasp holds: the record's ``grasp_done``
        event, else where the recorded width reaches its minimum (else the record's end)."""
        widths = self.record.width_m
        if GRASP_DONE_EVENT in self.record.events:
            return float(self.live_time(self.record.events[GRASP_DONE_EVENT]))
        if not len(widths):
            return float(self.live_time(self.origin_s + self.duration_s))
        return float(self.live_time(widths.t_s[int(np.argmin(widths.value))]))

    def hold_width_m(self) -> float:
        """The fingers' width while they hold still after the stop (m): the last width recorded
        before the record's ``command_release`` event (read well after the stop, as a hold lasts
        several reads), else the smallest recorded width. NaN without widths."""
        widths = self.record.width_m
        if not len(widths):
            return float("nan")
        release_s = self.record.events.get("command_release")
        before = np.flatnonzero(widths.t_s <= release_s) if release_s is not None else np.zeros(0, dtype=np.intp)
        return float(widths.value[before[-1]] if before.size else widths.value.min())


def _wait_until(t_s: float, clock: Callable[[], float], stop: threading.Event | None = None) -> bool:
    """Sleep until clock time ``t_s``; False if ``stop`` was set first."""
    remaining = t_s - clock()
    if remaining <= 0:
        return True
    if stop is None:
        time.sleep(remaining)
        return True
    return not stop.wait(remaining)


def _due_before(playback: GraspPlayback, due_s: float, deadline_s: float) -> bool:
    """Whether playback time ``due_s`` comes before monotonic ``deadline_s``."""
    return due_s - playback.now() <= deadline_s - time.monotonic()


class SimulatedGripper(Gripper):
    """The ``sim`` gripper: a replay while one runs, kinematic otherwise (see module docstring).

    Parameters
    ----------
    settings : GripperSettings
    playback : GraspPlayback, optional
        Grasp to replay; :meth:`replay` sets another later.
    object_width_m : float, optional
        Width of an object between the fingers for kinematic grasps (None: nothing there).
    """

    simulated = True

    def __init__(self, settings: GripperSettings, *, playback: GraspPlayback | None = None, object_width_m: float | None = None):
        super().__init__(settings)
        self.object_width_m = object_width_m
        self._lock = threading.Lock()
        self._halt = threading.Event()
        # Kinematic state: the width moves from _from_m (at _from_s) towards _to_m at _speed.
        self._from_m = settings.max_width_m
        self._from_s = time.monotonic()
        self._to_m = settings.max_width_m
        self._speed = 1.0
        self._grasped = False
        self._playback: GraspPlayback | None = None
        self._width_index = 0
        self._live: LiveGrasp | None = None
        if playback is not None:
            self.replay(playback)

    def replay(self, playback: GraspPlayback) -> None:
        """Serve widths from ``playback`` (started by the next grasp unless already running)."""
        self.live(None)
        with self._lock:
            self._playback = playback
            self._width_index = 0

    def live(self, grasp: LiveGrasp | None) -> None:
        """Drive and read the motor of ``grasp`` (None: back to the kinematics, from its width)."""
        with self._lock:
            now = time.monotonic()
            if grasp is None and self._live is not None:
                self._from_m = self._to_m = self._live.motor.width_at(now)
                self._from_s = now
            self._live = grasp
            if grasp is not None:
                self._playback = None

    def _open(self) -> None:
        self._halt.clear()

    def _shutdown(self) -> None:
        self._halt.set()

    def _begin_command(self) -> None:
        self._halt.clear()

    def _max_width(self) -> float:
        return self.settings.max_width_m

    def _is_grasped(self) -> bool:
        return self._grasped

    def _replaying(self, now: float) -> GraspPlayback | None:
        """The playback while it runs; when it has ended, the kinematics take over from its last width."""
        playback = self._playback
        if playback is None or not playback.started:
            return None
        if not playback.done(now):
            return playback
        self._width_index, rest = playback.widths_due(self._width_index, now)
        for t_s, width in zip(rest.t_s.tolist(), rest.value.tolist(), strict=True):
            self._width_queue.put(t_s, width)  # the reader has not handed these out yet
        widths = playback.record.width_m
        if len(widths):
            self._from_m = self._to_m = float(widths.value[-1])
        self._from_s = now
        self._playback = None
        return None

    def _kinematic_width(self, now: float) -> float:
        travelled = self._speed * max(0.0, now - self._from_s)
        gap = self._to_m - self._from_m
        return self._to_m if abs(gap) <= travelled else self._from_m + np.sign(gap) * travelled

    def _read_width(self) -> float:
        with self._lock:
            if self._live is not None:
                return self._live.width_read()[1]
            now = time.monotonic()
            playback = self._replaying(now)
            if playback is None:
                return float(self._kinematic_width(now))
            _, due = playback.widths_due(0, now)
            return float(due.value[-1]) if len(due) else float(self._kinematic_width(now))

    def _poll_widths(self) -> list[tuple[float, float]]:
        with self._lock:
            if self._live is not None:
                return [self._live.width_read()]
            playback = self._replaying(time.monotonic())
            if playback is not None:
                self._width_index, due = playback.widths_due(self._width_index)
                return list(zip(due.t_s.tolist(), due.value.tolist(), strict=True))
        return [self._timed_read()]

    def _readings_at_stop(self) -> list[tuple[float, float]]:
        """The recorded widths due by now, then the read that returns with the stopped fingers:
        the record's next read, early (during a replay; module docstring)."""
        with self._lock:
            if self._live is not None:
                return [self._live.width_read()]
            now = time.monotonic()
            playback = self._replaying(now)
            if playback is None or not np.isfinite(hold := playback.hold_width_m()):
                return [(now, float(self._kinematic_width(now)))]
            self._width_index, due = playback.widths_due(self._width_index, now)
            readings = list(zip(due.t_s.tolist(), due.value.tolist(), strict=True))
            widths = playback.record.width_m
            if self._width_index < len(widths):
                t_next = float(playback.live_time(widths.t_s[self._width_index]))
                readings.append((t_next, float(widths.value[self._width_index])))
                self._width_index += 1
                return readings
            return [*readings, (now, hold)]

    def _drive(self, to_m: float, speed: float) -> float:
        """Start a kinematic (or live) motion; returns when (clock time) it ends."""
        with self._lock:
            now = time.monotonic()
            if self._live is not None:
                self._grasped = False
                return self._live.motor.command(to_m, speed, now)
            self._replaying(now)  # hand over from an ended replay
            self._from_m = float(self._kinematic_width(now))
            self._from_s, self._to_m, self._speed = now, to_m, speed
            self._grasped = False
            return now + abs(to_m - self._from_m) / speed

    def _wait_for_replay(self) -> bool:
        """Wait for a running replay to end; False if stopped or closed meanwhile."""
        playback = self._playback
        if playback is None or not playback.started:
            return True
        return _wait_until(playback.live_time(playback.origin_s + playback.duration_s), playback.clock, self._halt)

    def _move(self, width_m: float, speed_m_s: float) -> bool:
        if not self._wait_for_replay():
            return False
        return _wait_until(self._drive(width_m, speed_m_s), time.monotonic, self._halt)

    def _grasp(self, width_m: float, speed_m_s: float, force_n: float, epsilon_inner_m: float, epsilon_outer_m: float) -> bool:
        playback = self._playback
        if self._live is not None:
            if not _wait_until(self._drive(width_m, speed_m_s), time.monotonic, self._halt):
                return False
            width = self._live.motor.width_at(time.monotonic())
            self._grasped = width_m - epsilon_inner_m <= width <= width_m + epsilon_outer_m
            return self._grasped
        if playback is not None and not playback.done():
            if not playback.started:
                playback.start()
            held = _wait_until(playback.grasp_settled_s(), playback.clock, self._halt)
            width = self._read_width()
            self._grasped = held and width_m - epsilon_inner_m <= width <= width_m + epsilon_outer_m
            return self._grasped
        if not self._wait_for_replay():
            return False
        current = self._read_width()
        stall = self.object_width_m
        target = stall if stall is not None and width_m <= stall <= current else width_m
        if not _wait_until(self._drive(target, speed_m_s), time.monotonic, self._halt):
            return False
        self._grasped = width_m - epsilon_inner_m <= target <= width_m + epsilon_outer_m
        return self._grasped

    def _follow(self, width_m: float, speed_m_s: float) -> None:
        """Head for ``width_m`` at once (a running move or grasp returns, interrupted); stalls at
        the object as a grasp does (kinematic) or where the force reaches its maximum (live)."""
        playback = self._playback
        if playback is not None and playback.started and not playback.done():
            raise DeviceError("the simulated gripper replays a recorded grasp: it cannot follow until it ends")
        self._halt.set()
        target, stall = width_m, self.object_width_m
        if self._live is None and stall is not None and width_m <= stall <= self._read_width():
            target = stall
        self._drive(target, speed_m_s)

    def _stop(self) -> bool:
        self._halt.set()
        with self._lock:
            if self._live is not None:
                self._live.motor.stop(time.monotonic())
                return True
            if self._replaying(time.monotonic()) is None:
                now = time.monotonic()
                self._from_m = self._to_m = float(self._kinematic_width(now))
                self._from_s = now
        return True


class _Switched:
    """A simulated reader's source, a :class:`GraspPlayback` or a :class:`LiveGrasp`, switched by the
    node while the reader waits: the reader takes (source, next index) together under the lock and
    hands data out only if no switch came meanwhile."""

    def _serve(self, playback: GraspPlayback | None) -> None:
        self._lock = threading.Lock()
        self._closed = threading.Event()  # set by close(): a waiting read returns at once
        self._playback: GraspPlayback | None = None
        self._live: LiveGrasp | None = None
        self._next = 0
        if playback is not None:
            self.replay(playback)

    def replay(self, playback: GraspPlayback) -> None:
        """Serve ``playback``'s data from its start on."""
        with self._lock:
            self._playback, self._next, self._live = playback, 0, None

    def live(self, grasp: LiveGrasp | None) -> None:
        """Serve ``grasp``'s data as it is captured (None: silence)."""
        with self._lock:
            self._playback, self._live = None, grasp

    def _connect(self) -> None:
        self._closed.clear()

    def _close(self) -> None:
        self._closed.set()

    def _idle_until(self, deadline: float) -> None:
        """Nothing to hand out: wait as a silent device would, until ``deadline`` or close()."""
        self._closed.wait(max(0.0, deadline - time.monotonic()))

    def _started_by(self, playback: GraspPlayback, deadline: float) -> bool:
        """Whether ``playback`` starts before ``deadline``; False as soon as close() is called."""
        while not playback.wait_started(min(0.05, max(0.0, deadline - time.monotonic()))):  # slices: close() is seen
            if self._closed.is_set() or time.monotonic() >= deadline:
                return False
        return True


class SimulatedCamera(_Switched, TactileCamera):
    """The ``sim`` camera: the frames of its finger from a :class:`GraspPlayback`, or rendered from a
    :class:`LiveGrasp` as they are captured. A live camera whose renderer falls more than a period
    behind drops the capture slots overdue (:meth:`LiveGrasp.take_frame`), counted in
    :attr:`dropped` as :class:`~teleop.devices.opencv_camera.OpenCVCamera` counts its own."""

    simulated = True

    def __init__(self, sensor: SensorSettings, *, playback: GraspPlayback | None = None):
        super().__init__(sensor)
        self._serve(playback)

    def replay(self, playback: GraspPlayback) -> None:
        playback.record.stream(self.sensor.finger)  # KeyError now, not at the first read
        super().replay(playback)

    def _read_live(self, grasp: LiveGrasp, deadline: float) -> CameraFrame | None:
        finger = self.sensor.finger
        due = grasp.next_frame_s(finger)
        if due > deadline:
            self._idle_until(deadline)
            return None
        if not _wait_until(due, time.monotonic, self._closed):
            return None
        with self._lock:
            if self._live is not grasp:
                return None  # switched while the frame was awaited
            dropped = grasp.frames_dropped(finger)
            frame = grasp.take_frame(finger)
            self.dropped += grasp.frames_dropped(finger) - dropped
            return frame

    def _read(self, timeout_s: float) -> CameraFrame | None:
        deadline = time.monotonic() + timeout_s
        with self._lock:
            playback, index, live = self._playback, self._next, self._live
        if live is not None:
            return self._read_live(live, deadline)
        finger = self.sensor.finger
        if (
            playback is None
            or not self._started_by(playback, deadline)
            or index >= playback.frame_count(finger)
            or not _due_before(playback, playback.frame_due_s(finger, index), deadline)
        ):
            self._idle_until(deadline)  # nothing to show: a silent camera
            return None
        due = playback.frame_due_s(finger, index)
        if not _wait_until(due, playback.clock, self._closed):
            return None
        with self._lock:
            if self._playback is not playback or self._next != index:
                return None  # another replay began while this frame was awaited
            self._next = index + 1
        stream = playback.record.stream(finger)
        return CameraFrame(finger, index, due, stream.encoded[index], stream.encoding)


class SimulatedLoadCell(_Switched, LoadCell):
    """The ``sim`` load cell: the force samples of a :class:`GraspPlayback`, in newtons as recorded,
    or the readings of a :class:`LiveGrasp` as they arrive."""

    simulated = True

    def __init__(self, settings: LoadCellSettings, *, playback: GraspPlayback | None = None):
        super().__init__(settings)
        self._serve(playback)

    def _take_live(self, grasp: LiveGrasp, deadline: float) -> Samples:
        """The readings of ``grasp`` that arrived, waiting for the next one up to ``deadline``."""
        for waited in (False, True):
            if waited and not _wait_until(min(grasp.next_reading_s(), deadline), time.monotonic, self._closed):
                break
            with self._lock:
                if self._live is not grasp:  # switched meanwhile
                    return Samples(np.zeros(0), np.zeros(0))
                due = grasp.forces_due()
            if len(due):
                break
        return due

    def _take(self, timeout_s: float) -> Samples:
        deadline = time.monotonic() + timeout_s
        with self._lock:
            playback, live = self._playback, self._live
        if live is not None:
            return self._take_live(live, deadline)
        if playback is not None and self._started_by(playback, deadline):
            index, due = self._take_due(playback)
            if len(due):
                return due
            forces = playback.record.force_n
            if index < len(forces):
                next_due = float(playback.live_time(forces.t_s[index]))
                if _due_before(playback, next_due, deadline):
                    if not _wait_until(next_due, playback.clock, self._closed):
                        return Samples(np.zeros(0), np.zeros(0))
                    return self._take_due(playback)[1]
        self._idle_until(deadline)  # nothing due in time: a silent cell
        return Samples(np.zeros(0), np.zeros(0))

    def _take_due(self, playback: GraspPlayback) -> tuple[int, Samples]:
        """The samples of ``playback`` due since the last take and the next index; none (and no
        next) if another replay began since the reader took ``playback``."""
        with self._lock:
            if self._playback is not playback:
                return len(playback.record.force_n), Samples(np.zeros(0), np.zeros(0))
            self._next, due = playback.forces_due(self._next)
            return self._next, due
