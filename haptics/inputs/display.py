"""The softness display's own grip as the operator input device (HID protocol version 2).

A version-2 display reports the operator's grip in INPUT reports (:class:`haptics.protocol.GripReport`:
``grip`` 0..1, ``force_n`` where it has a force sensor, ``enable``, ``buttons`` held,
``sequence``), read one by one through :meth:`SoftnessDisplay.read_operator_reports`. A version-1
display has no grip: :meth:`DisplayInput.connect` refuses it, naming the version.

The display is either given (``display=``, e.g. the one the renderer drives; it is connected
here if it is not yet, and closed here only then) or made from the ``[display]`` table and owned.
Each read drains the grip reports that have arrived and keeps the latest; a button counts as
pressed when a report shows it held and the one before did not, report by report, so a press is
reported once however many reports show it held, and a release and a new press between two reads
is a new press. Before the first report, and when no report has come for ``stale_s`` (by default
:data:`~haptics.protocol.GRIP_LOST_AFTER_S`, 100 ms, after which PROTOCOL.md takes the grip as
lost), the enable reads released and the reading is marked ``lost``
(:attr:`~haptics.inputs.base.OperatorInput.lost`). A display failure (unplugged) raises
:class:`~haptics.errors.InputDeviceError` and leaves this device disconnected.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from typing import Any, ClassVar, Self

from haptics.devices.base import SoftnessDisplay
from haptics.errors import DisplayError, InputDeviceError, ProtocolError
from haptics.inputs.base import OperatorInput, OperatorInputDevice
from haptics.protocol import GRIP_LOST_AFTER_S
from haptics.settings import display_settings
from teleop.operator import BUTTONS
from teleop.settings import Settings

__all__ = ["DisplayInput"]

#: Batches of reports drained per read at most (a display sends a few hundred a second at most).
_MAX_DRAIN = 1024
#: Longest single wait for the display: a close() from another thread ends a read within it.
_WAIT_SLICE_S = SoftnessDisplay.read_slice_s


class DisplayInput(OperatorInputDevice):
    """The grip of a version-2 softness display (module notes).

    Parameters
    ----------
    display : SoftnessDisplay
        The display to read the grip from.
    owned : bool
        Whether this device owns the display (closes it on close).
    stale_s : float
        After this long without a grip report the enable reads released, in s (> 0; default
        :data:`~haptics.protocol.GRIP_LOST_AFTER_S`, the protocol's).
    clock : callable
        Monotonic seconds: the readings' ``t_s`` and the staleness are on it.
    """

    name: ClassVar[str] = "display"

    def __init__(self, display: Any, *, owned: bool = False, stale_s: float = GRIP_LOST_AFTER_S,
                 clock: Callable[[], float] = time.monotonic) -> None:
        super().__init__()
        if isinstance(stale_s, bool) or not (
                isinstance(stale_s, int | float) and math.isfinite(stale_s) and stale_s > 0):
            raise InputDeviceError(f"stale_s = {stale_s!r}: expected a number of seconds > 0")
        self.display = display
        self._owned = owned
        self._opened_link = False
        self.stale_s = float(stale_s)
        self._clock = clock
        self._reset()

    @classmethod
    def from_settings(cls, settings: Settings, **options: Any) -> Self:
        """Options: ``display`` (a SoftnessDisplay to share; default: one made from ``[display]``
        and owned), ``stale_s``, ``clock``."""
        display = options.pop("display", None)
        if display is None:
            from haptics.devices import make_display

            return cls(make_display(display_settings(settings)), owned=True, **options)
        return cls(display, owned=False, **options)

    def __repr__(self) -> str:
        return f"<DisplayInput {self.display}>"

    def _reset(self) -> None:
        self._latest: Any = None
        self._latest_s = -math.inf
        self._held: frozenset[str] = frozenset()
        self._pressed: set[str] = set()

    # ------------------------------------------------------------ lifecycle hooks

    def _open(self) -> None:
        self._reset()
        self._opened_link = False
        if not self.display.connected:
            try:
                self.display.connect()
            except DisplayError as exc:
                raise InputDeviceError(f"{self!r}: the display cannot be connected: {exc}") from exc
            self._opened_link = True
        version = getattr(self.display.info, "protocol_version", None)
        if version is not None and version < 2:
            self._close()
            raise InputDeviceError(f"display speaks protocol version {version}: it has no grip "
                                   "(the display input needs protocol version 2; choose another "
                                   "[operator] input)")
        try:  # what arrived before: the hand's state now, but no presses
            for report in self._next_reports(0.0):
                self._take(report)
        except BaseException:
            self._close()
            raise
        self._pressed.clear()

    def _close(self) -> None:
        if self._owned or self._opened_link:
            self._opened_link = False
            self.display.close()

    # ------------------------------------------------------------ reading

    def _next_reports(self, timeout_s: float) -> tuple[Any, ...]:
        try:
            return self.display.read_operator_reports(timeout_s=timeout_s)
        except ProtocolError:
            raise  # a malformed report is named by the protocol; the link stays
        except DisplayError as exc:
            raise InputDeviceError(f"{self!r}: the display failed: {exc}") from exc

    def _take(self, report: Any) -> None:
        held = frozenset(report.buttons) & frozenset(BUTTONS)
        self._pressed |= held - self._held
        self._held = held
        self._latest = report
        self._latest_s = self._clock()

    def _wait_for_reports(self, timeout_s: float) -> tuple[Any, ...]:
        """The reports that arrive within ``timeout_s``, waited for in short slices so that a
        close() from another thread ends the wait (InputNotConnectedError)."""
        deadline = time.monotonic() + timeout_s
        while True:
            left_s = max(0.0, deadline - time.monotonic())
            reports = self._next_reports(min(left_s, _WAIT_SLICE_S))
            if reports or left_s <= _WAIT_SLICE_S:
                return reports
            self._require_connected("read")

    def _read(self, timeout_s: float) -> OperatorInput:
        # Wait (up to timeout_s) only for the first report ever; then take what has arrived.
        reports = self._wait_for_reports(timeout_s if self._latest is None else 0.0)
        for _ in range(_MAX_DRAIN):
            if not reports:
                break
            for report in reports:  # one by one: a release between two presses shows
                self._take(report)
            reports = self._next_reports(0.0)
        now = self._clock()
        pressed, self._pressed = frozenset(self._pressed), set()
        latest = self._latest
        if latest is None:
            return OperatorInput(t_s=now, grip=0.0, enable=False, force_n=None, buttons=pressed, lost=True)
        fresh = now - self._latest_s <= self.stale_s
        grip = float(latest.grip)
        if not math.isfinite(grip):
            raise InputDeviceError(f"{self!r}: the display reported grip = {grip!r}")
        force = None if latest.force_n is None else float(latest.force_n)
        return OperatorInput(t_s=now, grip=min(max(grip, 0.0), 1.0), enable=bool(latest.enable) and fresh,
                             force_n=force, buttons=pressed, lost=not fresh)
