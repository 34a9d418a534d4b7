"""The console's own keys as an operator input device.

The console (the terminal UI) owns the terminal, so it pushes each key to :meth:`KeyboardInput.press`
(key names as textual gives them: ``"up"``, ``"k"``, ``"space"``). A terminal sends no key-release
events, so nothing here can be *held*: the grip moves in steps and the dead-man enable toggles.

==========  =============================================================================
key         effect
==========  =============================================================================
up, k       squeeze: grip + ``keyboard_grip_step`` (``[operator]``, default 0.05), up to 1
down, j     open: grip - the step, down to 0
o           open the grip fully (grip 0)
e           toggle the enable (the console shows it; if the console dies, the robot node's
            watchdog stops the fingers, since follow commands stop arriving)
g           button ``grasp`` (a discrete grasp at the chosen force)
r           button ``release``; also lets go: enable off, grip 0, so that the next follow
            cannot start a new grasp by itself
s           button ``stop``; also turns the enable off (the fingers stay where they are)
n           button ``next`` (next object)
q           button ``quit``
==========  =============================================================================

Any other key is ignored (:meth:`~KeyboardInput.press` returns False), so the console can give
it a meaning of its own. ``force_n`` is always None: a keyboard measures no force.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any, ClassVar, Self

from haptics.errors import OperatorInputError
from haptics.inputs.base import OperatorInput, OperatorInputDevice
from haptics.settings import KEYBOARD_GRIP_STEP_MIN, operator_settings
from teleop.settings import Settings

__all__ = ["KEYS", "KeyboardInput"]

#: Key -> what it does (the console's help line shows these).
KEYS = {
    "up": "squeeze a step",
    "k": "squeeze a step",
    "down": "open a step",
    "j": "open a step",
    "o": "open fully",
    "e": "toggle enable",
    "g": "grasp",
    "r": "release (enable off, grip open)",
    "s": "stop (enable off)",
    "n": "next object",
    "q": "quit",
}


class KeyboardInput(OperatorInputDevice):
    """Keys pushed by the console (module notes for the mapping).

    Parameters
    ----------
    grip_step : float
        Grip change per up/down key, in [0.001, 1] (:data:`~haptics.settings.KEYBOARD_GRIP_STEP_MIN`:
        a smaller step would leave the grip unusable); settable later as :attr:`grip_step`.
    clock : callable
        Seconds for :attr:`OperatorInput.t_s` (``time.monotonic``).
    """

    name: ClassVar[str] = "keyboard"
    needs_console: ClassVar[bool] = True

    def __init__(self, *, grip_step: float = 0.05, clock: Callable[[], float] = time.monotonic) -> None:
        super().__init__()
        self.grip_step = grip_step
        self._clock = clock
        self._reset()

    @classmethod
    def from_settings(cls, settings: Settings, **options: Any) -> Self:
        """Options: ``grip_step`` (default ``[operator] keyboard_grip_step``), ``clock``."""
        options.setdefault("grip_step", operator_settings(settings).keyboard_grip_step)
        return cls(**options)

    @property
    def grip_step(self) -> float:
        """Grip change per up/down key, in [0.001, 1]."""
        return self._grip_step

    @grip_step.setter
    def grip_step(self, value: float) -> None:
        if isinstance(value, bool) or not isinstance(value, int | float) or not KEYBOARD_GRIP_STEP_MIN <= value <= 1:
            raise OperatorInputError(f"grip_step = {value!r}: expected a value in [{KEYBOARD_GRIP_STEP_MIN}, 1] "
                                     "(a fraction of the grip range per up/down key)")
        self._grip_step = float(value)

    def _reset(self) -> None:
        self._grip = 0.0
        self._enable = False
        self._pressed: set[str] = set()

    def _open(self) -> None:
        self._reset()  # a fresh connection starts open, not enabled, nothing pressed

    def _close(self) -> None:
        pass

    def press(self, key: str) -> bool:
        """Take one key from the console; True when it is mapped (module notes), False otherwise.

        Raises InputNotConnectedError when the device is not connected.
        """
        with self._lock:
            self._require_connected("press")
            if key in ("up", "k"):
                self._grip = min(1.0, round(self._grip + self._grip_step, 9))
            elif key in ("down", "j"):
                self._grip = max(0.0, round(self._grip - self._grip_step, 9))
            elif key == "o":
                self._grip = 0.0
            elif key == "e":
                self._enable = not self._enable
            elif key == "g":
                self._pressed.add("grasp")
            elif key == "r":
                self._pressed.add("release")
                self._enable, self._grip = False, 0.0
            elif key == "s":
                self._pressed.add("stop")
                self._enable = False
            elif key == "n":
                self._pressed.add("next")
            elif key == "q":
                self._pressed.add("quit")
            else:
                return False
            return True

    def let_go(self) -> None:
        """Turn the enable toggle off: the console's answer when the loop waits for the enable to be
        let go (a terminal reports no key release, so the toggle would stay on)."""
        with self._lock:
            self._enable = False

    def _read(self, timeout_s: float) -> OperatorInput:  # noqa: ARG002 - keys are pushed: never waits
        pressed, self._pressed = frozenset(self._pressed), set()
        return OperatorInput(t_s=self._clock(), grip=self._grip, enable=self._enable, force_n=None,
                             buttons=pressed)
