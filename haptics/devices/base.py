"""The softness-display device family: one base class, one lifecycle, every backend.

A backend implements six small hooks (open, close, write an OUTPUT report,
read an INPUT report, get and set the FEATURE report); the base class owns
the lifecycle, the protocol encoding, the sequence numbers and the
disconnect-on-failure rule that makes reconnection possible.

Versions: ``connect()`` reads the FEATURE report and the display's
``protocol_version`` decides the session: OUTPUT reports carry that version,
and a version-2 display's INPUT pipe carries grip reports (``0x04``) between
its status reports (``0x03``). The base class sorts them by report ID, so
:meth:`SoftnessDisplay.read_status` and :meth:`SoftnessDisplay.read_operator`
each see only their own kind; a version-1 display behaves exactly as before
(a ``0x04`` report from it is refused by ``read_status`` like any other
foreign report ID).
"""

from __future__ import annotations

import abc
import logging
import math
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Any, ClassVar, Self

from haptics.errors import DisplayError, DisplayNotConnectedError, ProtocolError
from haptics.protocol import (
    GRIP_LAYOUT,
    DeviceStatus,
    DisplayInfo,
    StiffnessCommand,
    decode_feature_report,
    decode_input_report,
    encode_feature_report,
    encode_output_report,
)
from haptics.protocol_grip import GripReport, decode_grip_report
from haptics.settings import DisplaySettings
from teleop.bus.pubsub import is_decade

__all__ = ["Reconnector", "SoftnessDisplay"]

log = logging.getLogger(__name__)

#: INPUT reports of one kind kept aside while reading the other kind (oldest dropped beyond).
_INBOX_SIZE = 256
#: Most INPUT reports one read_status() / read_operator() call takes from the device.
_MAX_READS = 1024


class SoftnessDisplay(abc.ABC):
    """A haptic softness display speaking the protocol of :mod:`haptics.protocol`.

    Lifecycle: ``connect()`` (reads the device info), then ``write_command()`` /
    ``read_status()`` / ``read_operator()`` / ``configure()``, then ``close()``;
    or use it as a context manager. Using it unconnected raises
    :class:`~haptics.errors.DisplayNotConnectedError`. An I/O failure raises
    :class:`~haptics.errors.DisplayError` and leaves the display disconnected;
    :meth:`reconnect` (driven by :class:`Reconnector`) brings it back and
    resends the last command.

    Thread-safe: a :meth:`close` from another thread ends a read in flight within
    :attr:`read_slice_s` (it raises DisplayNotConnectedError) and never releases the device
    under a backend call.
    """

    #: Longest wait asked of one ``_read_report`` call (None where the backend never waits):
    #: a close() from another thread ends a read within it.
    read_slice_s: ClassVar[float | None] = 0.05

    def __init__(self) -> None:
        self._connected = False
        #: Why it is not connected: "never", "closed" or "failed" (an I/O failure, e.g. an unplug).
        self._down = "never"
        # Held by every backend call and by the release of the device, so that a close()
        # from another thread waits for the call in flight (a read waits one slice at most).
        self._lock = threading.RLock()
        self._state_lock = threading.Lock()
        self._info: DisplayInfo | None = None
        self._sequence = 0
        self._last_command: StiffnessCommand | None = None
        self.reports_written = 0
        # INPUT reports read while looking for the other kind, as raw bytes (decoded when
        # their own reader takes them, so that a malformed one is refused there).
        self._status_inbox: deque[bytes] = deque(maxlen=_INBOX_SIZE)
        self._grip_inbox: deque[bytes] = deque(maxlen=_INBOX_SIZE)

    # ------------------------------------------------------------ backend hooks

    @classmethod
    @abc.abstractmethod
    def from_settings(cls, settings: DisplaySettings, **options: Any) -> Self:
        """A display configured from ``settings`` (not yet connected)."""

    @abc.abstractmethod
    def _open(self) -> None:
        """Find and open the device; raise DisplayError when it is not there."""

    @abc.abstractmethod
    def _close(self) -> None:
        """Release the device; must not raise."""

    @abc.abstractmethod
    def _write_report(self, report: bytes) -> None:
        """Send one OUTPUT report; raise DisplayError on failure."""

    @abc.abstractmethod
    def _read_report(self, timeout_s: float) -> bytes | None:
        """One INPUT report, or None when none arrives within ``timeout_s`` (at most
        :attr:`read_slice_s`)."""

    @abc.abstractmethod
    def _get_feature(self) -> bytes:
        """The FEATURE report as the device answers it."""

    @abc.abstractmethod
    def _set_feature(self, report: bytes) -> None:
        """Send a FEATURE report."""

    # ------------------------------------------------------------ lifecycle

    @property
    def connected(self) -> bool:
        return self._connected

    @property
    def info(self) -> DisplayInfo | None:
        """Device info read at the last successful connect (None before the first)."""
        return self._info

    @property
    def protocol_version(self) -> int | None:
        """The protocol version of the session: the display's own (None before connecting)."""
        return None if self._info is None else self._info.protocol_version

    @property
    def has_grip(self) -> bool:
        """The display serves grip reports (protocol version 2 or later)."""
        return self._info is not None and self._info.protocol_version >= GRIP_LAYOUT.version

    @property
    def last_command(self) -> StiffnessCommand | None:
        """The last command asked of :meth:`write_command`, written or not."""
        return self._last_command

    def connect(self) -> DisplayInfo:
        """Open the device and read its info; a no-op when already connected."""
        with self._lock:
            if self._connected:
                return self._info
            self._open()
            self._status_inbox.clear()
            self._grip_inbox.clear()
            try:
                self._info = self._fetch_info()
            except BaseException:
                self._close()
                raise
            self._connected = True
        log.info("%s connected: %s", self, self._info)
        return self._info

    def close(self) -> None:
        """Release the device; safe to call twice, and from another thread than a read's."""
        # The flag first, outside the lock: a read in flight holds the lock and checks the
        # flag between slices, so it ends and lets the device go.
        if self._mark_down("closed"):
            with self._lock:
                self._close()

    def __enter__(self) -> Self:
        self.connect()
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    def reconnect(self) -> DisplayInfo:
        """Close what is left of the link, connect again and resend the last command."""
        self.close()
        info = self.connect()
        last = self._last_command
        if last is not None and last.level <= info.level_max:
            self.write_command(last)
        elif last is not None:
            log.warning("%s came back with level_max %d: not resending level %d",
                        self, info.level_max, last.level)
        return info

    # ------------------------------------------------------------ I/O

    def write_command(self, command: StiffnessCommand) -> bytes:
        """Encode ``command`` with the next sequence number and send it; return the report.

        Raises
        ------
        DisplayNotConnectedError
            Not connected (never, closed, or after a failed write).
        ProtocolError
            ``command.level`` is above this display's ``level_max``.
        DisplayError
            The write failed; the display is now disconnected.
        """
        self._require_connected("write_command")
        if command.level > self._info.level_max:
            raise ProtocolError(
                f"StiffnessCommand.level = {command.level}: above this display's "
                f"level_max = {self._info.level_max}"
            )
        self._last_command = command
        report = encode_output_report(
            command, sequence=self._sequence, version=self._info.protocol_version
        )
        self._call("write_command", self._write_report, report)
        self._sequence = (self._sequence + 1) % 256
        self.reports_written += 1
        return report

    def read_status(self, *, timeout_s: float = 0.0) -> DeviceStatus | None:
        """The next status report, or None when none arrives within ``timeout_s`` seconds.

        A report that does not decode, or whose ``level`` is above this display's ``level_max``
        (PROTOCOL.md: out of range), raises ProtocolError naming the report and the field; the
        report is dropped and the link stays up.
        """
        self._require_connected("read_status")
        self._check_timeout("read_status", timeout_s)
        if not self._status_inbox:
            self._read_inputs("read_status", timeout_s, until=self._status_inbox)
        if not self._status_inbox:
            return None
        status = decode_input_report(self._status_inbox.popleft())
        if status.level > self._info.level_max:
            raise ProtocolError(
                f"input report 0x03: level = {status.level}, expected 0-{self._info.level_max} "
                "(this display's level_max)"
            )
        return status

    def read_operator(self, *, timeout_s: float) -> GripReport | None:
        """The operator's grip on the display's handle, or None.

        None for a version-1 display (at once: it has no grip; see :attr:`has_grip`) and when
        no grip report arrives within ``timeout_s`` seconds. Otherwise the newest grip report
        of :meth:`read_operator_reports`, with ``buttons`` the union over all of them, so that
        a press shorter than the caller's polling period is not lost (a release and a new
        press of a held button are: a caller that counts presses takes the reports one by one).
        """
        reports = self.read_operator_reports(timeout_s=timeout_s)
        if not reports:
            return None
        pressed = frozenset().union(*(report.buttons for report in reports))
        return replace(reports[-1], buttons=pressed)

    def read_operator_reports(self, *, timeout_s: float) -> tuple[GripReport, ...]:
        """Every grip report that arrived since the previous call, oldest first.

        Empty for a version-1 display (at once) and when no grip report arrives within
        ``timeout_s`` seconds. Status reports read on the way are kept for :meth:`read_status`.
        A grip report that does not decode raises ProtocolError naming it when it is the first;
        after good ones, those are returned and the bad one is refused by the next call (the
        link stays either way).
        """
        self._require_connected("read_operator")
        self._check_timeout("read_operator", timeout_s)
        if not self.has_grip:
            return ()
        if not self._grip_inbox:
            self._read_inputs("read_operator", timeout_s, until=self._grip_inbox)
        if self._grip_inbox:
            self._read_inputs("read_operator", 0.0, until=None)  # and whatever else is already there
        reports: list[GripReport] = []
        while self._grip_inbox:
            try:
                report = decode_grip_report(self._grip_inbox[0])
            except ProtocolError:
                if not reports:
                    self._grip_inbox.popleft()
                    raise
                break
            self._grip_inbox.popleft()
            reports.append(report)
        return tuple(reports)

    def configure(self, *, watchdog_ms: int) -> DisplayInfo:
        """Set the display's watchdog (0 = off) and return the info read back."""
        with self._lock:  # the write and the read back, with no close() between
            self._require_connected("configure")
            report = encode_feature_report(replace(self._info, watchdog_ms=watchdog_ms))
            self._io(self._set_feature, report)
            info = self._fetch_info()
        if info.watchdog_ms != watchdog_ms:
            raise DisplayError(
                f"{self} kept watchdog_ms = {info.watchdog_ms} after being asked for {watchdog_ms}"
            )
        self._info = info
        return info

    # ------------------------------------------------------------ helpers

    def _check_timeout(self, what: str, timeout_s: float) -> None:
        if isinstance(timeout_s, bool) or not (
                isinstance(timeout_s, int | float) and math.isfinite(timeout_s) and timeout_s >= 0):
            raise DisplayError(f"{what} timeout_s = {timeout_s!r}: expected a number >= 0")

    def _read_inputs(self, what: str, timeout_s: float, *, until: deque[bytes] | None) -> None:
        """Read INPUT reports into the inboxes, sorted by report ID.

        Stops as soon as a report lands in ``until``, waiting up to ``timeout_s`` in all;
        with ``until=None`` reads, without waiting, what is already there. Only a display that
        serves grip reports has its ``0x04`` reports set aside: from a version-1 display every
        report goes to the status inbox (and a foreign report ID is refused by ``read_status``).
        """
        deadline = time.monotonic() + timeout_s
        grip = self.has_grip
        reads = 0
        while reads < _MAX_READS:
            left_s = 0.0 if until is None else max(0.0, deadline - time.monotonic())
            wait_s = left_s if self.read_slice_s is None else min(left_s, self.read_slice_s)
            data = self._call(what, self._read_report, wait_s)
            if not data:  # None, or an empty read (no report), as the hid backend takes it
                if wait_s >= left_s:
                    return
                continue
            reads += 1
            is_grip = grip and data[0] == GRIP_LAYOUT.report_id
            (self._grip_inbox if is_grip else self._status_inbox).append(data)
            if until:
                return

    def _require_connected(self, what: str) -> None:
        if not self._connected:
            state = {
                "never": "it was never connected; call connect() first",
                "closed": "it was closed; call connect() again",
                "failed": "its link failed (unplugged?); call reconnect()",
            }[self._down]
            raise DisplayNotConnectedError(f"{self}: {what}() needs a connected display; {state}")

    def _mark_down(self, why: str) -> bool:
        """Mark the display not connected, for ``why``; True when it was connected."""
        with self._state_lock:
            was, self._connected = self._connected, False
            if was:
                self._down = why
        return was

    def _call(self, what: str, hook, *args):
        """Run a backend I/O hook on a connected display (a close() from another thread may
        have come since the caller checked)."""
        with self._lock:
            self._require_connected(what)
            return self._io(hook, *args)

    def _io(self, hook, *args):
        """Run a backend I/O hook (the caller holds the lock); a failure means the link is gone:
        mark it disconnected."""
        try:
            return hook(*args)
        except DisplayError:
            if self._mark_down("failed"):
                self._close()
            raise

    def _fetch_info(self) -> DisplayInfo:
        data = self._io(self._get_feature)
        try:
            return decode_feature_report(data)
        except ProtocolError as exc:
            raise DisplayError(
                f"{self} answered a device-info report this host cannot use: {exc}"
            ) from exc


@dataclass
class Reconnector:
    """Retries :meth:`SoftnessDisplay.reconnect` with exponential backoff on the caller's clock.

    No sleeping and no threads: call :meth:`poll` with the current time as often
    as convenient; it attempts at most once per backoff step, doubling the wait
    from ``initial_s`` up to ``max_s`` after each failure.

    ``accept``, when given, is called after each reconnect: a DisplayError from it means the
    display came back but cannot be used; it is closed and that counts as a failed attempt.
    :meth:`reject` does the same for a display found unusable outside :meth:`poll`.
    The first failure of a run is logged at warning, then only the 10th, 100th, ... in a row,
    so that a display left unplugged does not flood the log; its return after failures is
    logged once at info.
    """

    display: SoftnessDisplay
    initial_s: float = 0.05
    max_s: float = 2.0
    failures: int = 0
    next_attempt_s: float = -math.inf
    accept: Callable[[], None] | None = None

    def poll(self, now_s: float) -> bool:
        """True when the display is connected after this call."""
        if self.display.connected:
            return True
        if now_s < self.next_attempt_s:
            return False
        try:
            self.display.reconnect()
            if self.accept is not None:
                self.accept()
        except DisplayError as exc:
            self.reject(now_s, exc)
            return False
        if self.failures:
            log.info("%s: back after %d failed reconnect attempt(s)", self.display, self.failures)
        self.failures = 0
        self.next_attempt_s = -math.inf
        return True

    def reject(self, now_s: float, exc: DisplayError) -> None:
        """Count a failed attempt at ``now_s`` for ``exc``: close the display (it may be connected
        but unusable) and put the next attempt off by the backoff."""
        self.display.close()
        self.failures += 1
        # The exponent is capped so that a display left unplugged for hours cannot overflow.
        delay_s = min(self.max_s, self.initial_s * 2.0 ** min(self.failures - 1, 60))
        self.next_attempt_s = now_s + delay_s
        if is_decade(self.failures):
            log.warning("%s: reconnect failed (%s); next try in %.3g s (failure %d in a row; logged "
                        "at the 1st, 10th, 100th, ...)", self.display, exc, delay_s, self.failures)
