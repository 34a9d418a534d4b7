"""A gamepad as the operator input device, through Linux evdev (the ``evdev`` package).

The grip is an analogue trigger: an absolute axis (``[operator] gamepad_trigger``, default
``ABS_RZ``, the right trigger of most pads) scaled by the axis' own ``min`` .. ``max`` (its
``absinfo``) to 0 (released) .. 1 (pulled fully). The enable is a shoulder button
(``gamepad_enable``, default ``BTN_TR``): enabled while held, so letting go of the pad stops the
fingers. Face buttons give the discrete buttons, each counted once per press (key-repeat events
are not presses): ``gamepad_grasp`` (``BTN_SOUTH``), ``gamepad_release`` (``BTN_EAST``),
``gamepad_stop`` (``BTN_WEST``), ``gamepad_next`` (``BTN_NORTH``), ``gamepad_quit``
(``BTN_SELECT``). Which physical button has which name depends on the pad and its driver:
``evtest`` shows them.

The device is ``gamepad_path`` or, when that is empty, the first event device (in
``/dev/input/event*`` order) with the trigger axis and the enable button. Reading needs
permission on that node (usually membership of the ``input`` group). A pad unplugged while in
use raises :class:`~haptics.errors.InputDeviceError` on the next read and leaves the device
disconnected; ``connect()`` finds it again. The state is read at connect (trigger position,
held buttons) and after the kernel reports dropped events (``SYN_DROPPED``; the events up to and
including the next ``SYN_REPORT`` are dropped, as the kernel's documentation says), so a read never
waits. A trigger range with ``max <= min`` (at connect or after such a resync) raises
:class:`~haptics.errors.InputDeviceError` and leaves the device disconnected. ``force_n`` is None:
a trigger measures no force.
"""

from __future__ import annotations

import contextlib
import errno
import time
from typing import Any, ClassVar, Self

import evdev
from evdev import ecodes

from haptics.errors import InputDeviceError
from haptics.inputs.base import OperatorInput, OperatorInputDevice
from haptics.settings import OperatorSettings, operator_settings
from teleop.settings import Settings

__all__ = ["GamepadInput"]


class GamepadInput(OperatorInputDevice):
    """A gamepad through evdev (module notes).

    Parameters
    ----------
    settings : OperatorSettings
        The device path and the codes of the trigger and the buttons.
    device : evdev.InputDevice-like, optional
        An already opened device to use instead of finding one; it stays its owner's (never
        closed here). Tests pass a fake one: it needs ``capabilities()``, ``absinfo(code)``,
        ``active_keys()`` and ``read_one()``.
    """

    name: ClassVar[str] = "gamepad"

    def __init__(self, settings: OperatorSettings | None = None, *, device: Any = None) -> None:
        super().__init__()
        self.settings = settings or OperatorSettings()
        self._given = device
        self._device: Any = None
        # OperatorSettings refused names evdev does not know
        self._trigger = ecodes.ecodes[self.settings.gamepad_trigger]
        self._buttons: dict[int, str] = {}
        for button, name in self.settings.gamepad_buttons().items():
            code = ecodes.ecodes[name]
            if code in self._buttons:  # two names of one code (settings checked without evdev)
                other = self._buttons[code]
                raise InputDeviceError(
                    f"gamepad buttons {other} ({self.settings.gamepad_buttons()[other]}) and {button} ({name}) "
                    f"are the same evdev code {code}: set [operator] gamepad_{button} to another button")
            self._buttons[code] = button
        self._enable_code = next(c for c, b in self._buttons.items() if b == "enable")
        self._lo, self._hi = 0, 1
        self._value = 0
        self._dropping = False  # after SYN_DROPPED, until the next SYN_REPORT: events are dropped
        self._held: set[str] = set()
        self._pressed: set[str] = set()

    @classmethod
    def from_settings(cls, settings: Settings, **options: Any) -> Self:
        """Options: ``device`` (an opened evdev-like device; tests)."""
        return cls(operator_settings(settings), **options)

    def __repr__(self) -> str:
        where = getattr(self._device, "path", None) or self.settings.gamepad_path or "first suitable"
        return f"<GamepadInput {where}>"

    # ------------------------------------------------------------ finding the pad

    def _suitable(self, device: Any) -> str:
        """'' when ``device`` has the trigger axis and the enable button, else what it lacks."""
        caps = device.capabilities()
        axes = {entry[0] if isinstance(entry, tuple) else entry for entry in caps.get(ecodes.EV_ABS, [])}
        keys = set(caps.get(ecodes.EV_KEY, []))
        if self._trigger not in axes:
            return f"no absolute axis {self.settings.gamepad_trigger}"
        if self._enable_code not in keys:
            return f"no enable button {self.settings.gamepad_enable}"
        return ""

    def _find(self) -> Any:
        path = self.settings.gamepad_path
        if path:
            device = self._open_path(path)
            lacks = self._suitable(device)
            if lacks:
                device.close()
                raise InputDeviceError(f"gamepad {path} ({getattr(device, 'name', '?')}) has {lacks}: "
                                       "set [operator] gamepad_trigger / gamepad_enable to codes it has "
                                       "(evtest lists them)")
            return device
        seen = []
        for candidate in sorted(_list_devices(), key=_event_number):
            try:
                device = _input_device(candidate)
            except OSError as exc:
                seen.append(f"{candidate} ({exc.strerror or exc})")
                continue
            lacks = self._suitable(device)
            if not lacks:
                return device
            seen.append(f"{candidate} {device.name!r}: {lacks}")
            device.close()
        found = "; ".join(seen) if seen else "no readable /dev/input/event* device"
        raise InputDeviceError(f"no gamepad with the trigger axis {self.settings.gamepad_trigger} and the "
                               f"enable button {self.settings.gamepad_enable} ({found}); plug one in, "
                               "check permissions (the 'input' group) or set [operator] gamepad_path")

    @staticmethod
    def _open_path(path: str) -> Any:
        try:
            return _input_device(path)
        except OSError as exc:
            fix = ("add yourself to the 'input' group" if exc.errno in (errno.EACCES, errno.EPERM) else
                   "plug the pad in and check `[operator] gamepad_path` (evtest lists the devices; '' finds the first pad)")
            raise InputDeviceError(f"cannot open gamepad {path}: {exc.strerror or exc}: {fix}") from exc

    # ------------------------------------------------------------ lifecycle hooks

    def _open(self) -> None:
        if self._given is not None:
            try:
                lacks = self._suitable(self._given)
            except OSError as exc:
                raise self._gone(exc) from exc
            if lacks:
                raise InputDeviceError(f"{self!r} has {lacks}")
            self._device = self._given
        else:
            self._device = self._find()
        try:
            self._drain()  # events from before: the state read next already holds them
            self._dropping = False
            self._sync()
        except InputDeviceError:
            self._close()
            raise
        self._pressed.clear()

    def _close(self) -> None:
        device, self._device = self._device, None
        if device is not None and device is not self._given:  # a given device stays its owner's
            with contextlib.suppress(OSError):  # already gone
                device.close()

    def _sync(self) -> None:
        """Read the whole state from the device: trigger range and position, held buttons."""
        try:
            info = self._device.absinfo(self._trigger)
            active = set(self._device.active_keys())
        except OSError as exc:
            raise self._gone(exc) from exc
        self._check_range(info.min, info.max)
        self._lo, self._hi, self._value = info.min, info.max, info.value
        held = {button for code, button in self._buttons.items() if code in active}
        self._pressed |= held - self._held
        self._held = held

    def _check_range(self, lo: int, hi: int) -> None:
        """Refuse a trigger range the grip cannot be scaled by (at connect and after a resync)."""
        if not hi > lo:
            raise InputDeviceError(f"{self!r}: trigger {self.settings.gamepad_trigger} reports the range "
                                   f"{lo}..{hi}: expected max > min (a flat or inverted axis cannot give "
                                   "a grip); check the pad, or set [operator] gamepad_trigger to another axis")

    def _drain(self) -> None:
        for _ in range(4096):
            try:
                if self._device.read_one() is None:
                    return
            except OSError as exc:
                raise self._gone(exc) from exc

    def _gone(self, exc: OSError) -> InputDeviceError:
        return InputDeviceError(f"{self!r} went away ({exc.strerror or exc}): plug it back in and "
                                "connect() again")

    # ------------------------------------------------------------ reading

    def _read(self, timeout_s: float) -> OperatorInput:  # noqa: ARG002 - the state is always known
        resync = False
        for _ in range(4096):  # bounded: a pad cannot keep one read busy for ever
            try:
                event = self._device.read_one()
            except OSError as exc:
                raise self._gone(exc) from exc
            if event is None:
                break
            if event.type == ecodes.EV_SYN and event.code == ecodes.SYN_DROPPED:
                # Events were lost: the kernel's rule is to drop every event up to and including
                # the next SYN_REPORT (a partial packet), then read the state again.
                self._dropping = resync = True
            elif self._dropping:
                if event.type == ecodes.EV_SYN and event.code == ecodes.SYN_REPORT:
                    self._dropping, resync = False, True  # the state is whole again: read it
            elif event.type == ecodes.EV_ABS and event.code == self._trigger:
                self._value = event.value
            elif event.type == ecodes.EV_KEY and event.code in self._buttons:
                button = self._buttons[event.code]
                if event.value == 1:  # press; 2 is key repeat, 0 release
                    self._pressed.add(button)
                    self._held.add(button)
                elif event.value == 0:
                    self._held.discard(button)
        if resync:
            self._sync()
        grip = min(max((self._value - self._lo) / (self._hi - self._lo), 0.0), 1.0)
        pressed, self._pressed = frozenset(self._pressed - {"enable"}), set()
        return OperatorInput(t_s=time.monotonic(), grip=grip, enable="enable" in self._held, force_n=None,
                             buttons=pressed)


def _list_devices() -> list[str]:
    """The event devices this user can read (evdev before 1.9 lists only writable ones)."""
    try:
        return evdev.list_devices(writable=False)
    except TypeError:
        return evdev.list_devices()


def _input_device(path: str) -> Any:
    """``path`` opened read-only where evdev can (``readonly`` came with evdev 1.9)."""
    try:
        return evdev.InputDevice(path, readonly=True)
    except TypeError:
        return evdev.InputDevice(path)


def _event_number(path: str) -> tuple[int, str]:
    digits = "".join(ch for ch in str(path).rsplit("event", 1)[-1] if ch.isdigit())
    return (int(digits) if digits else 1 << 30, str(path))
