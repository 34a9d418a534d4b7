"""The simulated softness display shipped in the package.

:class:`DisplayFirmware` is the device side of the protocol: it decodes the
host's OUTPUT reports exactly as firmware would, answers the FEATURE report
and queues one status (INPUT) report per OUTPUT report it receives. It speaks
protocol version 2 unless told 1; a version-2 one has a scriptable grip
(:meth:`DisplayFirmware.set_grip` queues a grip report on the same INPUT pipe).
:class:`SimulatedDisplay` puts it behind the :class:`SoftnessDisplay`
lifecycle, logs every report byte for byte and can be unplugged and replugged.
The same firmware model stands behind the fake ``hid`` module in the tests.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Iterable
from dataclasses import replace
from typing import Any, Self

from haptics.devices.base import SoftnessDisplay
from haptics.errors import DisplayError, ProtocolError
from haptics.protocol import (
    FAULT_BITS,
    GRIP_LAYOUT,
    PROTOCOL_VERSION,
    DeviceStatus,
    DisplayInfo,
    StiffnessCommand,
    decode_feature_report,
    decode_output_report,
    encode_feature_report,
    encode_input_report,
)
from haptics.protocol_grip import GripReport, encode_grip_report
from haptics.settings import DisplaySettings

__all__ = ["LOG_REPORTS", "DisplayFirmware", "SimulatedDisplay"]

#: How many of the newest reports a simulated display keeps in its ``log``.
LOG_REPORTS = 10_000


class DisplayFirmware:
    """Device-side model of a display: what a microcontroller would do with the reports.

    Parameters
    ----------
    info : DisplayInfo, optional
        What the device reports in its FEATURE report (``watchdog_ms`` is writable).
    protocol_version : int, optional
        The version the device speaks when ``info`` is not given (default: the newest, 2);
        given with ``info``, it must agree with ``info.protocol_version``.
    """

    def __init__(self, info: DisplayInfo | None = None, *, protocol_version: int | None = None) -> None:
        if info is not None and protocol_version not in (None, info.protocol_version):
            raise ProtocolError(
                f"DisplayFirmware: protocol_version = {protocol_version!r} disagrees with "
                f"info.protocol_version = {info.protocol_version}"
            )
        self.info = info or DisplayInfo(
            level_max=4095,
            firmware_version=(1, 0),
            watchdog_ms=1000,
            min_stiffness_n_per_m=0,
            max_stiffness_n_per_m=5000,
            protocol_version=PROTOCOL_VERSION if protocol_version is None else protocol_version,
        )
        self.power_on_reset()

    def power_on_reset(self) -> None:
        """State after power-up: free, nothing received, no faults, no queued status."""
        self.last_command: StiffnessCommand | None = None
        self.sequence = 0
        self.faults: set[str] = set()
        self.bad_reports = 0
        #: The last grip report sent (None before any).
        self.grip: GripReport | None = None
        self._grip_sequence = 0
        # The INPUT pipe: status and (version 2) grip reports, in the order they were sent.
        self._statuses: deque[bytes] = deque(maxlen=64)

    @property
    def level(self) -> int:
        """The level being rendered (0 while faulted or before any command)."""
        if self.last_command is None or self.faults - {"bad_report"}:
            return 0
        return self.last_command.level

    @property
    def state(self) -> str:
        if self.faults - {"bad_report"}:
            return "fault"
        rigid = self.last_command is not None and self.last_command.rigid
        return "rendering" if self.level > 0 or rigid else "free"

    def inject_fault(self, name: str) -> None:
        """Raise a fault bit (one of FAULT_BITS); the actuator goes free."""
        if name not in FAULT_BITS:
            raise ProtocolError(f"fault {name!r}: expected one of {', '.join(FAULT_BITS)}")
        self.faults.add(name)

    def receive_output(self, report: bytes) -> None:
        """Handle one OUTPUT report; a malformed one is counted and flagged, never rendered."""
        try:
            decoded = decode_output_report(report, version=self.info.protocol_version)
            if decoded.command.level > self.info.level_max:
                raise ProtocolError(f"level {decoded.command.level} above {self.info.level_max}")
        except ProtocolError:
            self.bad_reports += 1
            self.faults.add("bad_report")
        else:
            self.last_command, self.sequence = decoded
        self._statuses.append(self.status_report())
        self.faults.discard("bad_report")

    def status_report(self) -> bytes:
        """The INPUT report describing the state now."""
        return encode_input_report(
            DeviceStatus(self.state, self.level, frozenset(self.faults), self.sequence)
        )

    def set_grip(
        self,
        grip: float,
        *,
        force_n: float | None = None,
        enable: bool = True,
        buttons: Iterable[str] = (),
    ) -> bytes:
        """Move the handle: queue the grip report a version-2 device sends; return its bytes.

        ``grip`` 0 (open) to 1 (squeezed); ``force_n`` None for a device without a force
        sensor; ``enable`` the dead-man (held unless said otherwise); ``buttons`` the buttons
        pressed in this report. Each call sends one report, numbered by the device's counter.
        """
        if self.info.protocol_version < GRIP_LAYOUT.version:
            raise ProtocolError(
                f"a protocol version {self.info.protocol_version} display has no grip report "
                f"(version {GRIP_LAYOUT.version} and later)"
            )
        self.grip = GripReport(grip, force_n, enable, frozenset(buttons), self._grip_sequence)
        self._grip_sequence = (self._grip_sequence + 1) % 256
        report = encode_grip_report(self.grip)
        self._statuses.append(report)
        return report

    def queue_input_report(self, report: bytes) -> None:
        """Queue raw bytes as the next INPUT report: lets a test play a misbehaving device."""
        self._statuses.append(bytes(report))

    def next_input_report(self) -> bytes | None:
        """The oldest queued INPUT report (status or grip), or None."""
        return self._statuses.popleft() if self._statuses else None

    def feature_report(self) -> bytes:
        return encode_feature_report(self.info)

    def receive_feature(self, report: bytes) -> None:
        """Apply a FEATURE report from the host: only ``watchdog_ms`` is writable."""
        requested = decode_feature_report(report)
        self.info = replace(self.info, watchdog_ms=requested.watchdog_ms)


class SimulatedDisplay(SoftnessDisplay):
    """A display in memory, speaking the real protocol byte for byte.

    ``log`` holds ``(kind, bytes)`` for the newest :data:`LOG_REPORTS` reports that crossed
    the simulated link, kind in ``output``, ``input``, ``feature_get``, ``feature_set``.
    ``unplug()`` makes every I/O fail as a pulled cable would; ``replug()``
    powers the firmware up again. ``protocol_version`` (1 or 2, default 2) is
    the version the simulated device speaks; a version-2 one's grip is set
    with :meth:`set_grip` and read with :meth:`read_operator`.
    """

    # Its reports are queued by the writes that make them: a read never waits, so never slices.
    read_slice_s = None

    def __init__(
        self, *, firmware: DisplayFirmware | None = None, protocol_version: int | None = None
    ) -> None:
        super().__init__()
        if firmware is not None and protocol_version not in (None, firmware.info.protocol_version):
            raise ProtocolError(
                f"SimulatedDisplay: protocol_version = {protocol_version!r} disagrees with its "
                f"firmware's {firmware.info.protocol_version}"
            )
        self.firmware = firmware or DisplayFirmware(protocol_version=protocol_version)
        # Bounded: the renderer service runs for hours.
        self.log: deque[tuple[str, bytes]] = deque(maxlen=LOG_REPORTS)
        self.plugged = True

    @classmethod
    def from_settings(cls, settings: DisplaySettings, **options: Any) -> Self:
        return cls(**options)

    def __str__(self) -> str:
        return "simulated display"

    @property
    def rendered_command(self) -> StiffnessCommand | None:
        """The last command the firmware decoded and accepted."""
        return self.firmware.last_command

    def set_grip(
        self,
        grip: float,
        *,
        force_n: float | None = None,
        enable: bool = True,
        buttons: Iterable[str] = (),
    ) -> bytes:
        """The operator moves the simulated handle: see :meth:`DisplayFirmware.set_grip`."""
        return self.firmware.set_grip(grip, force_n=force_n, enable=enable, buttons=buttons)

    def unplug(self) -> None:
        self.plugged = False

    def replug(self) -> None:
        self.plugged = True
        self.firmware.power_on_reset()

    def _require_plugged(self) -> None:
        if not self.plugged:
            raise DisplayError(f"{self} is unplugged")

    def _open(self) -> None:
        self._require_plugged()

    def _close(self) -> None:
        """Nothing to release in memory."""

    def _write_report(self, report: bytes) -> None:
        self._require_plugged()
        self.log.append(("output", report))
        self.firmware.receive_output(report)

    def _read_report(self, timeout_s: float) -> bytes | None:
        self._require_plugged()
        report = self.firmware.next_input_report()
        if report is not None:
            self.log.append(("input", report))
        return report

    def _get_feature(self) -> bytes:
        self._require_plugged()
        report = self.firmware.feature_report()
        self.log.append(("feature_get", report))
        return report

    def _set_feature(self, report: bytes) -> None:
        self._require_plugged()
        self.log.append(("feature_set", report))
        self.firmware.receive_feature(report)
