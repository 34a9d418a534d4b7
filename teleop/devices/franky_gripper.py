"""Franka hand through ``franky`` (PyPI ``franky-control``): the ``franky`` gripper backend.

``franky.Gripper(host)`` connects to the robot controller (or to ``franky-sim`` on
loopback). Its calls block; the base class runs them in its command thread for the
``*_async`` variants and reads the width in its background reader (about 0.1 s per read
on a real hand). Every ``franky`` exception is wrapped in
:class:`~teleop.errors.DeviceError` naming the host.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TypeVar

import franky

from teleop.devices.gripper import Gripper
from teleop.errors import DeviceError

__all__ = ["FrankyGripper"]

T = TypeVar("T")


class FrankyGripper(Gripper):
    """The Franka hand at ``settings.host``."""

    _gripper: franky.Gripper | None = None

    def __repr__(self) -> str:
        return f"<FrankyGripper {self.settings.host}>"

    def _call(self, what: str, fn: Callable[[], T]) -> T:
        try:
            return fn()
        except (franky.Exception, franky.GripperException, RuntimeError) as exc:
            raise DeviceError(f"franky gripper at {self.settings.host}: {what} failed: {exc}") from exc

    def _open(self) -> None:
        self._gripper = self._call("connect", lambda: franky.Gripper(self.settings.host))

    def _shutdown(self) -> None:
        # franky has no close(): dropping the object closes its connection.
        self._gripper = None

    def _move(self, width_m: float, speed_m_s: float) -> bool:
        return self._call(f"move to {width_m} m", lambda: self._gripper.move(width_m, speed_m_s))

    def _grasp(self, width_m: float, speed_m_s: float, force_n: float, epsilon_inner_m: float, epsilon_outer_m: float) -> bool:
        return self._call(
            f"grasp at {width_m} m",
            lambda: self._gripper.grasp(width_m, speed_m_s, force_n, epsilon_inner_m, epsilon_outer_m),
        )

    def _stop(self) -> bool:
        return self._call("stop", lambda: self._gripper.stop())

    def _read_width(self) -> float:
        gripper = self._gripper
        if gripper is None:  # the reader thread can race close()
            raise DeviceError(f"franky gripper at {self.settings.host} is closed")
        return self._call("width read", lambda: gripper.width)

    def _max_width(self) -> float:
        return self._call("max_width read", lambda: self._gripper.max_width)

    def _is_grasped(self) -> bool:
        return self._call("is_grasped read", lambda: self._gripper.is_grasped)
