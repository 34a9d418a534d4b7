"""The parallel gripper family: base class, backend table and :func:`make_gripper`.

A gripper moves its fingers to a width, grasps with a force, and reports its width.
On a Franka hand one width read takes about 0.1 s, so a background reader polls the
width at ``GripperSettings.width_read_hz`` and timestamps every reading when its read call
returns: the convention of the simulated records the shipped model learned from and of the
estimator's lag model (:mod:`teleop.sim.sensors`, :mod:`estimator.lag`), whatever part of the
call the value comes from. :meth:`Gripper.widths` hands out everything read since the last
call. The gripper measures no force.

Width reads failing for :data:`LINK_DOWN_S` in a row (two failures at least: one dropped read,
however slow, is not enough) leave the
gripper *down* (:attr:`Gripper.link_error` says why) until one succeeds: meanwhile
:meth:`Gripper.widths` raises that failure, and every command but :meth:`Gripper.stop` is refused
with it at once rather than blocking on a dead link. The hand's widest opening is read once per
connection, at :meth:`~teleop.devices.base.Device.connect`.

A grasp command completes when the fingers stop: at the target force, or where they were
stopped. That moment ends the loading of the object, so the gripper then reads its width at
once (the fingers are still, so the read is the width from the stop on) and queues it with
the background reader's samples, in time order; :attr:`Gripper.last_stop` holds the stop's
time and that reading (:class:`GraspStop`) for the robot node's loading-end marker.

Leader-follower teleoperation drives the fingers with :meth:`Gripper.follow`: it sets the
fingers' target width and returns at once; the backend moves them toward the latest target
(by default at :data:`~teleop.operator.FOLLOW_SPEED_M_S`) until :meth:`Gripper.stop`, which ends the following
within one of the backend's control steps.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from typing import Any

from teleop.devices.base import Device, SampleQueue, check_timeout, load_backend
from teleop.errors import DeviceError, DeviceNotConnectedError, InvalidCommandError
from teleop.operator import FOLLOW_SPEED_M_S
from teleop.record import Samples
from teleop.settings import GripperSettings

__all__ = ["BACKENDS", "FOLLOW_SPEED_M_S", "FRANKY_FIX", "LINK_DOWN_S", "MAX_FORCE_N", "MAX_SPEED_M_S", "GraspStop", "Gripper",
           "make_gripper"]

log = logging.getLogger(__name__)

BACKENDS = {
    "sim": "teleop.devices.playback:SimulatedGripper",
    "franky": "teleop.devices.franky_gripper:FrankyGripper",
}
MAX_SPEED_M_S = 0.2
MAX_FORCE_N = 140.0  # the Franka hand's peak grasp force
LINK_DOWN_S = 0.5  # width reads failing this long in a row and the gripper is down (module docstring)
FRANKY_FIX = "check the robot is on with FCI enabled and `gripper.host`"  # what to do when it does not connect


def make_gripper(settings: GripperSettings, *, backend: str | None = None, **options) -> Gripper:
    """An unconnected gripper of ``backend`` (default ``settings.backend``).

    ``options`` go to the backend (e.g. ``playback=`` for ``sim``).
    """
    cls = load_backend("gripper", BACKENDS, backend or settings.backend)
    return cls(settings, **options)


def _finite(name: str, value: float, lo: float, hi: float, *, lo_open: bool = False) -> float:
    ok = isinstance(value, int | float) and math.isfinite(value) and (value > lo if lo_open else value >= lo)
    if not ok or value > hi:
        left = "(" if lo_open else "["
        raise InvalidCommandError(f"{name} = {value!r}: expected a number in {left}{lo}, {hi}]")
    return float(value)


@dataclass(frozen=True)
class GraspStop:
    """Where a grasp command's motion ended.

    Attributes
    ----------
    stopped_s : float
        When the grasp command completed (``time.monotonic()`` seconds): the fingers stopped.
    width_t_s, width_m : float
        The width read right after (s, m), stamped as every width sample is; it is queued in
        the width stream too.
    held : bool
        What the grasp command returned (an object held within its tolerance).
    """

    stopped_s: float
    width_t_s: float
    width_m: float
    held: bool


class _Cancelled(Exception):
    """A stop came after the command was given, before its motion went out."""


class Gripper(Device):
    """A parallel gripper.

    Backends implement ``_open``, ``_shutdown``, ``_move``, ``_grasp``, ``_follow``, ``_stop``,
    ``_read_width``, ``_max_width`` and ``_is_grasped``; they may override
    ``_poll_widths`` when their widths come with their own timestamps, and then
    ``_readings_at_stop`` as well, and ``_begin_command`` to arm what :meth:`stop` interrupts
    before a move or grasp starts.

    A :meth:`stop` also cancels the moves and grasps given before it that have not started (an
    async command still queued behind another): they return False without moving the fingers,
    and a cancelled grasp leaves no :attr:`last_stop`. A backend whose motion can wait, after it
    began, where its ``_stop`` cannot reach it (franky: behind a follow step) calls
    ``_raise_if_stopped_since_given`` once nothing more delays the motion.
    """

    family = "gripper"

    def __init__(self, settings: GripperSettings):
        super().__init__()
        self.settings = settings
        self._width_queue = SampleQueue()
        self._width_lock = threading.Lock()  # one read-and-queue at a time: the queue stays in time order
        self._last_stop: GraspStop | None = None
        self._reader: threading.Thread | None = None
        self._reader_stop = threading.Event()
        self._executor: ThreadPoolExecutor | None = None
        self._max_width_m = 0.0  # read at connect: a connected hand's opening does not change
        self._link_error: str | None = None
        self._stops = 0  # stop() calls so far: a command given before the latest one does not start
        self._given = threading.local()  # .stops: the count when the running command was given

    # ------------------------------------------------------------------ lifecycle

    def _connect(self) -> None:
        try:
            self._open()
            try:
                self._max_width_m = float(self._max_width())
            except BaseException:
                self._shutdown()
                raise
        except DeviceError as exc:
            self._link_error = str(exc)  # still down: commands say why
            raise
        self._link_error = None
        self._width_queue = SampleQueue()  # widths and stops of an earlier connection are stale
        self._last_stop = None
        self._executor = ThreadPoolExecutor(max_workers=1, thread_name_prefix=f"{type(self).__name__}-command")
        self._reader_stop = threading.Event()  # per connection: a reader left in a slow read still stops
        self._reader = threading.Thread(target=self._read_widths_forever, args=(self._reader_stop, self._width_queue),
                                        name=f"{type(self).__name__}-width", daemon=True)
        self._reader.start()

    def _close(self) -> None:
        self._reader_stop.set()
        self._width_queue.close()  # wake a widths() waiting in another thread
        if self._reader is not None:
            self._reader.join(timeout=5.0)
        if self._executor is not None:
            self._executor.shutdown(wait=False, cancel_futures=True)
        self._shutdown()

    # ------------------------------------------------------------------ commands

    @property
    def max_width_m(self) -> float:
        """Widest opening (m), as the gripper reports it."""
        self._require_connected()
        return self._max_width_m

    @property
    def link_error(self) -> str | None:
        """Why the gripper is down: the last width read, or connect, failed with this; None while it reads."""
        return self._link_error

    @property
    def last_stop(self) -> GraspStop | None:
        """The stop of the last grasp command that completed (None before the first); read it
        once the command's future is done."""
        return self._last_stop

    @property
    def is_grasped(self) -> bool:
        """Whether the last grasp holds an object within its tolerance."""
        self._require_up()
        return bool(self._is_grasped())

    def move(self, width_m: float, *, speed_m_s: float | None = None) -> bool:
        """Move the fingers to ``width_m`` at ``speed_m_s`` (default: closing speed); blocks.

        Returns True when the width was reached, False when stopped or failed.
        """
        self._require_up()
        return self._move_unless_stopped(self._stops, *self._motion_args(width_m, speed_m_s))

    def grasp(
        self,
        width_m: float,
        *,
        speed_m_s: float | None = None,
        force_n: float | None = None,
        epsilon_inner_m: float = 0.005,
        epsilon_outer_m: float = 0.005,
    ) -> bool:
        """Close on an object expected ``width_m`` wide with ``force_n``; blocks.

        Returns True when the fingers stopped within ``[width_m - epsilon_inner_m,
        width_m + epsilon_outer_m]``. Speed and force default to the settings.
        """
        self._require_up()
        return self._grasp_until_stop(self._grasp_args(width_m, speed_m_s, force_n, epsilon_inner_m, epsilon_outer_m),
                                      self._stops)

    def move_async(self, width_m: float, *, speed_m_s: float | None = None) -> Future[bool]:
        """:meth:`move` in the command thread; bad arguments are refused here, at once."""
        self._require_up()
        args, issued = self._motion_args(width_m, speed_m_s), self._stops
        return self._submit(self._move_unless_stopped, issued, *args)

    def grasp_async(
        self,
        width_m: float,
        *,
        speed_m_s: float | None = None,
        force_n: float | None = None,
        epsilon_inner_m: float = 0.005,
        epsilon_outer_m: float = 0.005,
    ) -> Future[bool]:
        """:meth:`grasp` in the command thread; bad arguments are refused here, at once."""
        self._require_up()
        args = self._grasp_args(width_m, speed_m_s, force_n, epsilon_inner_m, epsilon_outer_m)
        return self._submit(self._grasp_until_stop, args, self._stops)

    def follow(self, width_m: float, *, speed_m_s: float | None = None) -> None:
        """Set the fingers' target width ``width_m`` (m) and return at once.

        The fingers move toward the latest target at up to ``speed_m_s`` (m/s, default
        :data:`~teleop.operator.FOLLOW_SPEED_M_S`) and hold it, until :meth:`stop` or another command. A running
        move or grasp is superseded. Arguments are checked as :meth:`move` checks them.
        """
        self._require_up()
        self._follow(*self._motion_args(width_m, FOLLOW_SPEED_M_S if speed_m_s is None else speed_m_s))

    def stop(self) -> bool:
        """Stop a running move, grasp or follow and hold the current width; a move or grasp given
        before and not started yet does not start."""
        self._require_connected()
        self._stops += 1
        return bool(self._stop())

    def read_width(self) -> tuple[float, float]:
        """One width read now: ``(t_s, width_m)``, stamped when the read returns (slow on franky)."""
        self._require_up()
        return self._timed_read()

    def widths(self, *, timeout_s: float = 0.0) -> Samples:
        """Width samples (t_s, m) the background reader took since the last call.

        Waits up to ``timeout_s`` (0: not at all) for at least one; empty Samples if none came.
        DeviceNotConnectedError if the gripper is closed meanwhile; DeviceError with the failure
        while it is down (:attr:`link_error`).
        """
        self._require_up()
        samples = self._width_queue.take(check_timeout(timeout_s, poll=True))
        if not len(samples):
            self._require_connected()  # woken by close(), not by a sample
        return samples

    # ------------------------------------------------------------------ internals

    def _submit(self, call: Callable[..., bool], *args: Any) -> Future[bool]:
        try:
            return self._executor.submit(call, *args)
        except RuntimeError as exc:  # closed meanwhile (the node reopening a gripper that was down)
            raise DeviceNotConnectedError(f"{self!r} was closed while the command was given") from exc

    def _motion_args(self, width_m: float, speed_m_s: float | None) -> tuple[float, float]:
        width = _finite("width_m", width_m, 0.0, self._max_width_m)
        speed = _finite(
            "speed_m_s", self.settings.closing_speed_m_s if speed_m_s is None else speed_m_s, 0.0, MAX_SPEED_M_S, lo_open=True
        )
        return width, speed

    def _grasp_args(
        self, width_m: float, speed_m_s: float | None, force_n: float | None, epsilon_inner_m: float, epsilon_outer_m: float
    ) -> tuple[float, float, float, float, float]:
        width, speed = self._motion_args(width_m, speed_m_s)
        force = _finite("force_n", self.settings.target_force_n if force_n is None else force_n, 0.0, MAX_FORCE_N, lo_open=True)
        inner = _finite("epsilon_inner_m", epsilon_inner_m, 0.0, self.settings.max_width_m)
        outer = _finite("epsilon_outer_m", epsilon_outer_m, 0.0, self.settings.max_width_m)
        return width, speed, force, inner, outer

    def _begin(self, issued: int) -> None:
        """Before a command's motion: arm the backend's interruption, then _Cancelled if :meth:`stop`
        was called since the command was given (``issued``: the stop count then). Armed first, so a
        stop after the check interrupts the motion."""
        self._begin_command()
        self._given.stops = issued
        self._raise_if_stopped_since_given()

    def _raise_if_stopped_since_given(self) -> None:
        """_Cancelled if :meth:`stop` was called since the running command was given."""
        if self._stops != getattr(self._given, "stops", self._stops):
            raise _Cancelled

    def _move_unless_stopped(self, issued: int, width_m: float, speed_m_s: float) -> bool:
        try:
            self._begin(issued)
            return bool(self._move(width_m, speed_m_s))
        except _Cancelled:
            return False

    def _grasp_until_stop(self, args: tuple[float, float, float, float, float], issued: int) -> bool:
        """Run the grasp (unless stopped since ``issued``); when its motion ends, queue a width read
        and remember the stop (none when that read fails: the grasp itself stands)."""
        self._last_stop = None
        try:
            self._begin(issued)
            held = bool(self._grasp(*args))
        except _Cancelled:  # it never began: no stop to report (the node then marks no loading end)
            return False
        stopped_s = time.monotonic()
        try:
            with self._width_lock:
                readings = self._readings_at_stop()
                for t_s, width in readings:
                    self._width_queue.put(t_s, width)
        except DeviceError as exc:
            log.warning("%r: the width read when the grasp stopped failed: %s", self, exc)
            return held
        width_t_s, width_m = readings[-1]
        self._last_stop = GraspStop(stopped_s, width_t_s, width_m, held)
        return held

    def _timed_read(self) -> tuple[float, float]:
        width = float(self._read_width())
        return time.monotonic(), width

    def _poll_widths(self) -> list[tuple[float, float]]:
        """Width samples available now; one timed read unless the backend has its own."""
        return [self._timed_read()]

    def _readings_at_stop(self) -> list[tuple[float, float]]:
        """Width samples to queue when a grasp stops, the last one read now; one timed read
        unless the backend has its own timestamps."""
        return [self._timed_read()]

    def _require_up(self) -> None:
        """Refuse a command at once while the gripper is down (:attr:`link_error`); :meth:`stop` is
        never refused for it: it may still reach the fingers. Down and closed (a failed reopen), it
        says why it is down."""
        if self._link_error is not None:
            raise DeviceError(f"{self!r} is down until a width read succeeds: {self._link_error}")
        self._require_connected()

    def _read_widths_forever(self, stop: threading.Event, queue: SampleQueue) -> None:
        period = 1.0 / self.settings.width_read_hz
        next_s = time.monotonic()
        failing_since: float | None = None  # when the first of the failed reads in a row began
        failures = 0
        while not stop.is_set():
            started = time.monotonic()
            try:
                with self._width_lock:
                    readings = self._poll_widths()
                    if stop.is_set():
                        return  # closed during the read: its widths belong to no connection now
                    for t_s, width in readings:
                        queue.put(t_s, width)
                failing_since, failures = None, 0
                if not stop.is_set():
                    self._link_error = None
            except DeviceError as exc:  # keep polling: the link may come back
                if stop.is_set():
                    return  # closed during the read: not a failure
                if failing_since is None:
                    log.warning("%r: width read failed: %s", self, exc)
                    failing_since = started
                failures += 1
                # Down after a second failure, LINK_DOWN_S on: not one dropped (or one slow) read.
                if failures >= 2 and time.monotonic() - failing_since >= LINK_DOWN_S and not stop.is_set():
                    self._link_error = str(exc)
            now = time.monotonic()
            next_s = max(next_s + period, now)  # after a slow read, resume the period from now
            stop.wait(next_s - now)

    # ------------------------------------------------------------------ backend hooks

    def _open(self) -> None:
        raise NotImplementedError

    def _begin_command(self) -> None:
        """Before a move or grasp: arm the backend's interruption by :meth:`_stop` (default: none)."""

    def _shutdown(self) -> None:
        raise NotImplementedError

    def _move(self, width_m: float, speed_m_s: float) -> bool:
        raise NotImplementedError

    def _grasp(self, width_m: float, speed_m_s: float, force_n: float, epsilon_inner_m: float, epsilon_outer_m: float) -> bool:
        raise NotImplementedError

    def _follow(self, width_m: float, speed_m_s: float) -> None:
        raise NotImplementedError

    def _stop(self) -> bool:
        raise NotImplementedError

    def _read_width(self) -> float:
        raise NotImplementedError

    def _max_width(self) -> float:
        raise NotImplementedError

    def _is_grasped(self) -> bool:
        raise NotImplementedError
