"""Franka hand through ``franky`` (PyPI ``franky-control``): the ``franky`` gripper backend.

``franky.Gripper(host)`` connects to the robot controller (or to ``franky-sim`` on
loopback), within ``GripperSettings.connect_timeout_s``. Its calls block; the base class runs them in its command thread for the
``*_async`` variants and reads the width in its background reader (about 0.1 s per read
on a real hand). Every ``franky`` exception is wrapped in
:class:`~teleop.errors.DeviceError` naming the host.

Following (:meth:`~teleop.devices.gripper.Gripper.follow`) runs in a follower thread as a
series of short moves, each toward the latest target by at most :data:`FOLLOW_STEP_S` of travel
at the follow speed, re-commanded while the target is more than :data:`FOLLOW_DEADBAND_M` away.
Short moves end by themselves, so :meth:`~teleop.devices.gripper.Gripper.stop` ends a follow by
sending no further step: the fingers stop within one step. A move aborted by ``franky``'s
``stop()`` would do it at once, but franky-sim never answers an aborted move, whose call then
blocks its connection for good. Moves, grasps and follow steps take turns (one command at a time).
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable
from concurrent.futures import Future
from typing import Any, TypeVar

import franky

from teleop.devices.gripper import FRANKY_FIX, Gripper
from teleop.errors import DeviceError, DeviceTimeoutError

__all__ = ["FOLLOW_DEADBAND_M", "FOLLOW_STEP_S", "FrankyGripper"]

log = logging.getLogger(__name__)

T = TypeVar("T")
FOLLOW_STEP_S = 0.02  # one follow step travels at most this long at the follow speed (s)
FOLLOW_DEADBAND_M = 5e-4  # a target this close to the fingers' goal is not re-commanded (m)
IDLE_WAKE_S = 0.1  # the follower with nothing to do wakes this often to see whether it is closing


class FrankyGripper(Gripper):
    """The Franka hand at ``settings.host``."""

    _gripper: franky.Gripper | None = None

    def __init__(self, settings):
        super().__init__(settings)
        self._command_lock = threading.Lock()  # one motion command at a time
        self._follow_lock = threading.Lock()  # guards the two fields below
        self._follow_target: tuple[float, float] | None = None  # (m, m/s) while following
        self._stepping = False  # a follow step is in flight
        self._follow_wake = threading.Event()
        self._follow_stop = threading.Event()
        self._follower: threading.Thread | None = None

    def __repr__(self) -> str:
        return f"<FrankyGripper {self.settings.host}>"

    def _call(self, what: str, fn: Callable[[], T]) -> T:
        try:
            return fn()
        except (franky.Exception, franky.GripperException, RuntimeError) as exc:
            # a connect error says what to do: every command opening the gripper shows it
            fix = f": {FRANKY_FIX}" if what == "connect" else ""
            raise DeviceError(f"franky gripper at {self.settings.host}: {what} failed: {exc}{fix}") from exc

    def _open(self) -> None:
        self._gripper = self._connect_within(self.settings.connect_timeout_s)
        self._follow_target = None
        self._follow_stop.clear()
        self._follower = threading.Thread(target=self._follow_forever, name=f"{self!r}-follow", daemon=True)
        self._follower.start()

    def _connect_within(self, timeout_s: float) -> franky.Gripper:
        """``franky.Gripper(host)``, or DeviceTimeoutError after ``timeout_s``.

        A host that accepts the connection but never answers holds libfranka's handshake for 60 s,
        in C, where Ctrl-C cannot reach it. So it runs in a daemon thread, abandoned on time-out,
        and this thread waits on a future: a timed wait Ctrl-C interrupts at once.
        """
        connected: Future[franky.Gripper] = Future()

        def connect() -> None:
            try:
                connected.set_result(franky.Gripper(self.settings.host))
            except Exception as exc:  # handed to the waiting thread
                connected.set_exception(exc)

        threading.Thread(target=connect, name=f"{self!r}-connect", daemon=True).start()
        try:
            return self._call("connect", lambda: connected.result(timeout=timeout_s))
        except TimeoutError:
            raise DeviceTimeoutError(f"franky gripper at {self.settings.host}: no answer within {timeout_s:g} s "
                              f"(`gripper.connect_timeout_s`): {FRANKY_FIX}") from None

    def _shutdown(self) -> None:
        self._follow_stop.set()
        self._follow_wake.set()
        if self._follower is not None:
            self._follower.join(timeout=5.0)  # a step in flight ends by itself
        # franky has no close(): dropping the object closes its connection.
        self._gripper = None

    def _hand(self) -> Any:
        """The franky gripper; DeviceError once close() dropped it (a command can race a reopen)."""
        gripper = self._gripper
        if gripper is None:
            raise DeviceError(f"franky gripper at {self.settings.host} is closed")
        return gripper

    def _move(self, width_m: float, speed_m_s: float) -> bool:
        with self._command_lock:
            self._raise_if_stopped_since_given()  # a stop while a follow step held the hand reached no motion
            hand = self._hand()
            return self._call(f"move to {width_m} m", lambda: hand.move(width_m, speed_m_s))

    def _grasp(self, width_m: float, speed_m_s: float, force_n: float, epsilon_inner_m: float, epsilon_outer_m: float) -> bool:
        with self._command_lock:
            self._raise_if_stopped_since_given()
            hand = self._hand()
            return self._call(
                f"grasp at {width_m} m",
                lambda: hand.grasp(width_m, speed_m_s, force_n, epsilon_inner_m, epsilon_outer_m),
            )

    def _follow(self, width_m: float, speed_m_s: float) -> None:
        with self._follow_lock:
            self._follow_target = (width_m, speed_m_s)
        self._follow_wake.set()

    def _stop(self) -> bool:
        with self._follow_lock:
            self._follow_target = None
            if self._stepping:
                return True  # the step in flight ends by itself; no further one goes out
        hand = self._hand()
        return self._call("stop", lambda: hand.stop())

    def _follow_forever(self) -> None:
        """The follower thread: short moves toward the latest target (module docstring)."""
        goal = None  # the last step's goal (m); None when not following
        while not self._follow_stop.is_set():
            with self._follow_lock:
                target = self._follow_target
            if target is None:
                goal = None
            if target is None or (goal is not None and abs(target[0] - goal) <= FOLLOW_DEADBAND_M):
                self._follow_wake.wait(IDLE_WAKE_S)
                self._follow_wake.clear()
                continue
            width, speed = target
            try:
                start = self._read_width() if goal is None else goal
                step = speed * FOLLOW_STEP_S
                goal = start + max(-step, min(step, width - start))
                with self._command_lock:
                    with self._follow_lock:
                        if self._follow_target is None:  # stopped meanwhile
                            continue
                        self._stepping = True
                    try:
                        hand = self._hand()
                        self._call(f"follow step to {goal} m", lambda g=goal, v=speed, h=hand: h.move(g, v))
                    finally:
                        self._stepping = False
            except DeviceError as exc:
                log.warning("%r: %s", self, exc)
                goal = None
                self._follow_stop.wait(IDLE_WAKE_S)

    def _read_width(self) -> float:
        hand = self._hand()  # the reader thread can race close()
        return self._call("width read", lambda: hand.width)

    def _max_width(self) -> float:
        hand = self._hand()
        return self._call("max_width read", lambda: hand.max_width)

    def _is_grasped(self) -> bool:
        hand = self._hand()
        return self._call("is_grasped read", lambda: hand.is_grasped)
