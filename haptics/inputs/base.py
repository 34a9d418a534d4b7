"""The operator input device family: one base class, one lifecycle, a name table of backends.

An operator input device tells the operator side what the person's hand does: how far the grip
(or trigger) is squeezed, whether the dead-man enable is held, and which discrete buttons
(:data:`teleop.operator.BUTTONS`) were pressed. Backends:

``keyboard`` (:mod:`haptics.inputs.keyboard`)
    keys pushed by the console that owns the terminal; the grip steps, the enable toggles.
``gamepad`` (:mod:`haptics.inputs.gamepad`)
    an analogue trigger and buttons through Linux evdev.
``display`` (:mod:`haptics.inputs.display`)
    the softness display's own grip (HID protocol version 2).
``sim`` (:mod:`haptics.inputs.sim`)
    the seeded, person-like simulated operator, closed loop on what it feels.

Typical use (python-can style: built unconnected, then a context manager)::

    with make_input("gamepad", settings) as device:
        while True:
            reading = device.read(timeout_s=0.02)
            device.feel(force_n=state.force_n, width_m=state.width_m, stiffness=None)

Lifecycle: ``connect()`` (a no-op when connected), ``read()`` / ``feel()``, ``close()`` (safe
twice). Using a device unconnected raises :class:`~haptics.errors.InputNotConnectedError`. A
device failure (an unplugged gamepad or display) raises
:class:`~haptics.errors.InputDeviceError` and leaves the device disconnected; ``connect()``
again brings it back. A backend's module is imported only when it is opened, so ``evdev`` is
imported by the gamepad backend alone.

:meth:`OperatorInputDevice.read` reports the latest state and the buttons pressed since the
previous read, each press once. It never waits longer than ``timeout_s``; backends whose state
is always known (keyboard, gamepad, sim) return at once, and before a device has reported
anything the state is the safe one: grip open, enable released. Every method is thread-safe
(a console thread pushes keys while the link thread reads), and a ``close()`` from another
thread ends a pending read at once: a backend that waits checks :attr:`connected` between short
waits, and the read raises :class:`~haptics.errors.InputNotConnectedError`.
"""

from __future__ import annotations

import abc
import math
import threading
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, ClassVar, Self

from haptics.errors import (
    InputBackendNotFoundError,
    InputDeviceError,
    InputNotConnectedError,
    OperatorInputError,
)
from haptics.settings import operator_settings
from teleop.devices.base import load_backend
from teleop.errors import BackendNotFoundError
from teleop.operator import BUTTONS
from teleop.settings import Settings

__all__ = ["BACKENDS", "OperatorInput", "OperatorInputDevice", "input_class", "make_input"]

#: Backend name -> "module:class"; the module is imported only when the backend is used.
BACKENDS = {
    "keyboard": "haptics.inputs.keyboard:KeyboardInput",
    "gamepad": "haptics.inputs.gamepad:GamepadInput",
    "display": "haptics.inputs.display:DisplayInput",
    "sim": "haptics.inputs.sim:SimulatedInput",
}
# What provides a backend's library: evdev is a dependency of the project on Linux only.
_INSTALL = {"gamepad": "evdev, a dependency of the project on Linux only: pip install evdev"}


def _finite(where: str, value: object) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise OperatorInputError(f"{where} = {value!r}: expected a finite number")
    return float(value)


@dataclass(frozen=True)
class OperatorInput:
    """One reading of an operator input device.

    Attributes
    ----------
    t_s : float
        ``time.monotonic()`` of the reading (the backend's clock where one was given).
    grip : float
        How far the grip is squeezed: 0 open .. 1 fully squeezed
        (:func:`teleop.operator.grip_to_width_m` turns it into the fingers' target width).
    enable : bool
        Whether the dead-man enable is held; follow commands count only while it is.
    force_n : float or None
        The operator's grip force (N) where the device measures it, else None.
    buttons : frozenset of str
        The buttons of :data:`teleop.operator.BUTTONS` pressed since the previous read.
    lost : bool
        Whether the device's state is not heard (the display's grip reports stopped, or none came
        yet): the enable then reads released, and the operator's loop takes it as let go, to be
        read let go and held again before it drives (a hand that held it all along drives nothing).
    """

    t_s: float
    grip: float
    enable: bool
    force_n: float | None = None
    buttons: frozenset[str] = frozenset()
    lost: bool = False

    def __post_init__(self) -> None:
        _finite("OperatorInput.t_s", self.t_s)
        if not 0.0 <= _finite("OperatorInput.grip", self.grip) <= 1.0:
            raise OperatorInputError(f"OperatorInput.grip = {self.grip!r}: expected a value in [0, 1]")
        if not isinstance(self.enable, bool):
            raise OperatorInputError(f"OperatorInput.enable = {self.enable!r}: expected True or False")
        if not isinstance(self.lost, bool):
            raise OperatorInputError(f"OperatorInput.lost = {self.lost!r}: expected True or False")
        if self.force_n is not None:
            _finite("OperatorInput.force_n", self.force_n)
        if not isinstance(self.buttons, frozenset):
            raise OperatorInputError(f"OperatorInput.buttons = {self.buttons!r}: expected a frozenset")
        unknown = sorted(self.buttons - set(BUTTONS))
        if unknown:
            raise OperatorInputError(f"OperatorInput.buttons names {unknown[0]!r}: expected some of "
                                     f"{', '.join(BUTTONS)}")


class OperatorInputDevice(abc.ABC):
    """An operator input device (module notes): ``connect()``, ``read()``, ``feel()``, ``close()``.

    A backend implements ``from_settings``, ``_open``, ``_close`` and ``_read``, and ``_feel``
    where it uses the robot side's state; the base class owns the lifecycle, the argument
    checks, the lock and the disconnect-on-failure rule.
    """

    family: ClassVar[str] = "operator input"
    #: The backend's name in :data:`BACKENDS`.
    name: ClassVar[str] = ""
    #: Whether its input comes through the console's screen (its keys): then it cannot run headless.
    needs_console: ClassVar[bool] = False
    #: Whether it is read only once the robot node is heard: a simulated person waits for the robot
    #: before squeezing, where a person's own device shows its grip at once.
    waits_for_robot: ClassVar[bool] = False

    def __init__(self) -> None:
        self._connected = False
        self._was_closed = False
        self._lock = threading.RLock()
        self._state_lock = threading.Lock()

    # ------------------------------------------------------------ backend hooks

    @classmethod
    @abc.abstractmethod
    def from_settings(cls, settings: Settings, **options: Any) -> Self:
        """A device configured from the whole ``settings`` (its ``[operator]`` table and whatever
        else the backend needs), not yet connected."""

    @abc.abstractmethod
    def _open(self) -> None:
        """Find and open the device; raise InputDeviceError when it is not there or cannot serve."""

    @abc.abstractmethod
    def _close(self) -> None:
        """Release the device; must not raise."""

    @abc.abstractmethod
    def _read(self, timeout_s: float) -> OperatorInput:
        """The latest state, with the buttons pressed since the last call; raise InputDeviceError
        when the device has failed."""

    def _feel(self, force_n: float, width_m: float, stiffness: float | None) -> None:  # noqa: B027 - optional
        """Take the robot side's state; the default ignores it."""

    # ------------------------------------------------------------ lifecycle

    @property
    def connected(self) -> bool:
        """Whether :meth:`connect` succeeded and neither :meth:`close` nor a failure came since."""
        return self._connected

    def connect(self) -> Self:
        """Open the device; returns ``self``; a no-op when already connected."""
        with self._lock:
            if not self._connected:
                self._open()
                self._connected = True
                self._was_closed = False
        return self

    def close(self) -> None:
        """Release the device; safe to call twice, and on a device never connected."""
        # The flag first, outside the lock: a read waiting in another thread holds the lock and
        # sees the flag at its next short wait, so it ends and lets the device go.
        if self._mark_closed():
            with self._lock:
                self._close()

    def __enter__(self) -> Self:
        return self.connect()

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    def __repr__(self) -> str:
        return f"<{type(self).__name__}>"

    # ------------------------------------------------------------ use

    def read(self, *, timeout_s: float = 0.0) -> OperatorInput:
        """The latest state, with the buttons pressed since the previous read (each press once).

        Waits at most ``timeout_s`` seconds (>= 0) for the device to report.

        Raises
        ------
        InputNotConnectedError
            Not connected (never, closed, or after a failure), or closed by another thread while
            waiting.
        OperatorInputError
            ``timeout_s`` is not a number >= 0.
        InputDeviceError
            The device failed (unplugged); it is now disconnected.
        """
        if not (_finite("timeout_s", timeout_s) >= 0):
            raise OperatorInputError(f"timeout_s = {timeout_s!r}: expected a number of seconds >= 0")
        with self._lock:
            self._require_connected("read")
            reading = self._io(self._read, float(timeout_s))
        if not isinstance(reading, OperatorInput):  # a backend bug, named where it happens
            raise TypeError(f"{self!r}._read returned {reading!r}: expected an OperatorInput")
        return reading

    def feel(self, *, force_n: float, width_m: float, stiffness: float | None = None) -> None:
        """Tell the device the robot side's state: the force the fingers feel (N), their width (m)
        and the stiffness the display renders (None when it renders nothing). Only the simulated
        operator uses them (it closes its loop on the force); the others ignore them."""
        force_n, width_m = _finite("force_n", force_n), _finite("width_m", width_m)
        if stiffness is not None:
            stiffness = _finite("stiffness", stiffness)
        with self._lock:
            self._require_connected("feel")
            self._io(self._feel, force_n, width_m, stiffness)

    # ------------------------------------------------------------ helpers

    def _require_connected(self, what: str) -> None:
        if not self._connected:
            state = ("was closed or failed; call connect() again" if self._was_closed
                     else "is not connected; call connect() (or use it in a with block) first")
            raise InputNotConnectedError(f"{self!r}: {what}() needs a connected {self.family} device; it {state}")

    def _mark_closed(self) -> bool:
        """Mark the device not connected; True when it was (the caller then releases it)."""
        with self._state_lock:
            was, self._connected = self._connected, False
            if was:
                self._was_closed = True
        return was

    def _io(self, hook: Callable[..., Any], *args: Any) -> Any:
        """Run a backend hook; a device failure means the device is gone: mark it disconnected."""
        try:
            return hook(*args)
        except InputDeviceError:
            if self._mark_closed():
                self._close()
            raise


def input_class(name: str) -> type[OperatorInputDevice]:
    """The operator input class registered as ``name``; the error lists the names there are."""
    try:
        return load_backend("operator input", BACKENDS, name, install=_INSTALL)
    except BackendNotFoundError as exc:
        raise InputBackendNotFoundError(str(exc)) from exc


def make_input(name: str | None, settings: Settings, **options: Any) -> OperatorInputDevice:
    """The operator input backend ``name`` (None: the settings' ``[operator] input``), configured
    from ``settings``, not yet connected: use it in a ``with`` block.

    ``options`` go to the backend's ``from_settings`` (each backend's docstring lists its own).
    """
    if name is None:
        name = operator_settings(settings).input
    return input_class(name).from_settings(settings, **options)
