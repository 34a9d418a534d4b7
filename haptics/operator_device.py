"""The operator loop's hold on its input device: reading it, opening it again, feeding it back.

:class:`DeviceReader` serves :class:`haptics.operator_loop.OperatorLoop`. Each read says whether it
comes after a gap, a time in which the hand was not heard:

* a read that fails and leaves the device disconnected (an unplugged gamepad or display raises
  ``InputDeviceError``) gives the last reading with the enable released and no buttons, the grip
  where it was, so that a follow grasp pauses (the fingers stop where they are) instead of tripping
  the robot's watchdog; the device is opened again at most every :data:`RECONNECT_S`. A read that
  fails with the device still connected (one malformed report) is that released reading too, marked
  ``lost``, but no gap: an enable driving before drives again at the next read, and a suspended one
  stays suspended (the let-go was not read);
* the first reading after the device was opened again;
* a reading the device marks ``lost`` (:attr:`haptics.inputs.base.OperatorInput.lost`: the
  display's grip reports stopped for longer than the protocol allows).

The loop takes a gap as the enable let go: what the hand did meanwhile (a trigger pulled, an
enable held all along) does not drive until the enable has been read let go and held again.
``feel`` is not passed to a device that is not connected: the read's failure and its reconnection
attempts stay the problem shown, not a ``feel()`` on a closed device.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace
from typing import Any

from haptics.errors import InputNotConnectedError
from teleop.errors import ComplianceTeleopError

__all__ = ["RECONNECT_S", "DeviceReader"]

RECONNECT_S = 1.0  # a failed input device (unplugged) is opened again at most this often


class DeviceReader:
    """Reads ``device`` for the operator's loop (module docstring).

    Parameters
    ----------
    device : InputDevice
        The operator input device (connected, or to be opened again on the first read).
    clock : callable
        Monotonic seconds (the reconnection's pace).
    act, trouble, resolved : callable
        The loop's: log an action; show a problem; stop showing the problems of a kind (a prefix).
    """

    def __init__(self, device: Any, clock: Callable[[], float], *, act: Callable[[str], None],
                 trouble: Callable[[str], None], resolved: Callable[[str], None]):
        self.device = device
        self.clock = clock
        self._act, self._trouble, self._resolved = act, trouble, resolved
        self._reconnect_s = -float("inf")  # when a failed device was last opened again

    def read(self, last: Any) -> tuple[Any, bool]:
        """``(reading, gap)``: the device's reading (None when it failed before any reading; else, on
        a failure, ``last`` with the enable released and no buttons), and whether it comes after a
        gap (a failure, a reconnection, a reading the device marks ``lost``)."""
        try:
            reading = self.device.read(timeout_s=0.0)
            return reading, bool(getattr(reading, "lost", False))
        except InputNotConnectedError:
            now = self.clock()
            if now - self._reconnect_s >= RECONNECT_S:
                self._reconnect_s = now
                try:
                    self.device.connect()
                    reading = self.device.read(timeout_s=0.0)
                    self._act("input device connected again")
                    self._resolved("input device:")
                    return reading, True
                except ComplianceTeleopError as exc:
                    self._trouble(f"input device: {exc}; trying again every {RECONNECT_S:g} s")
        except ComplianceTeleopError as exc:
            self._trouble(f"input device: {exc}")
            # A device still connected read one bad report (the link stays): the enable is not heard for
            # one read (``lost``: it pauses, and is no let-go that re-arms a suspended enable), no gap.
            if getattr(self.device, "connected", False):
                return (None if last is None else replace(last, enable=False, buttons=frozenset(), lost=True)), False
        return (None if last is None else replace(last, enable=False, buttons=frozenset())), True

    def feel(self, *, force_n: float, width_m: float, stiffness: float | None) -> None:
        """Feed the robot side's state back to the device; nothing while it is not connected."""
        if not getattr(self.device, "connected", True):
            return
        try:
            self.device.feel(force_n=force_n, width_m=width_m, stiffness=stiffness)
        except InputNotConnectedError:
            pass  # closed since (by another thread, or a failure): the next read says so
        except ComplianceTeleopError as exc:
            self._trouble(f"input device: {exc}")
