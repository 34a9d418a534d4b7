"""The USB HID backend, over hidapi (``import hid``, PyPI ``hidapi``).

Discovery is ``hid.enumerate(vendor_id, product_id)``, filtered to the
vendor-defined usage page where the platform reports usage pages; the display
is opened by path, so a display replugged under a new path is found again.
Every vendor ``OSError`` / ``ValueError`` becomes a
:class:`~haptics.errors.DisplayError` (``raise ... from``), which the base
class takes as an unplug. Status reports and a version-2 display's grip
reports both arrive through ``read()`` on the one interrupt IN endpoint; the
base class sorts them by report ID, and asks each ``read()`` for one short slice of
its wait (hidapi takes the timeout as a C int of milliseconds, and its handle must
not be closed under a read in flight).
"""

from __future__ import annotations

import contextlib
import importlib
from types import ModuleType
from typing import Any, Self

from haptics.devices.base import SoftnessDisplay
from haptics.errors import DisplayBackendNotFoundError, DisplayError
from haptics.protocol import FEATURE_LAYOUT, USAGE_PAGE
from haptics.settings import DisplaySettings

__all__ = ["HidDisplay", "import_hid", "list_hid_displays"]

#: Bytes asked of each read: more than any report, so a report of the wrong length shows.
_READ_SIZE = 64


def import_hid() -> ModuleType:
    """The ``hid`` module of hidapi, or a DisplayBackendNotFoundError saying how to get it."""
    try:
        return importlib.import_module("hid")
    except ImportError as exc:
        raise DisplayBackendNotFoundError(
            f"the HID backend needs hidapi (`pip install hidapi`, then `import hid`): {exc}"
        ) from exc


def list_hid_displays(
    vendor_id: int, product_id: int, *, hid_module: ModuleType | None = None
) -> list[dict[str, Any]]:
    """hidapi's device dicts for the displays plugged in, vendor-defined interface only.

    An interface whose usage page the platform does not report (0) is kept.
    """
    hid = hid_module or import_hid()
    try:
        found = hid.enumerate(vendor_id, product_id)
    except (OSError, ValueError) as exc:
        raise DisplayError(f"HID enumeration failed: {exc}") from exc
    return [d for d in found if d.get("usage_page", 0) in (0, USAGE_PAGE)]


class HidDisplay(SoftnessDisplay):
    """A softness display on USB HID.

    Parameters
    ----------
    vendor_id, product_id : int
        USB IDs to discover.
    serial : str, optional
        Pick the display with this serial number when several are plugged in.
    hid_module : module, optional
        The ``hid`` module to use (tests inject a fake); by default hidapi's.
    """

    def __init__(
        self,
        *,
        vendor_id: int,
        product_id: int,
        serial: str | None = None,
        hid_module: ModuleType | None = None,
    ) -> None:
        super().__init__()
        self.vendor_id = vendor_id
        self.product_id = product_id
        self.serial = serial
        self._hid = hid_module or import_hid()
        self._device: Any = None
        self.path: bytes | None = None

    @classmethod
    def from_settings(cls, settings: DisplaySettings, **options: Any) -> Self:
        return cls(vendor_id=settings.vendor_id, product_id=settings.product_id, **options)

    def __str__(self) -> str:
        where = f" at {self.path.decode(errors='backslashreplace')}" if self.path else ""
        return f"HID display {self.vendor_id:04X}:{self.product_id:04X}{where}"

    def _open(self) -> None:
        found = list_hid_displays(self.vendor_id, self.product_id, hid_module=self._hid)
        if self.serial is not None:
            found = [d for d in found if d.get("serial_number") == self.serial]
        if not found:
            serial = f" serial {self.serial!r}" if self.serial is not None else ""
            raise DisplayError(
                f"no HID display {self.vendor_id:04X}:{self.product_id:04X}{serial} is plugged in "
                "(`haptics devices` lists what is)"
            )
        self.path = found[0]["path"]
        device = self._hid.device()
        try:
            device.open_path(self.path)
            # Reads then honour their timeout instead of blocking (timeout 0 = poll).
            device.set_nonblocking(1)
        except (OSError, ValueError) as exc:
            with contextlib.suppress(OSError, ValueError):  # opened but unusable: no handle left behind
                device.close()
            raise DisplayError(
                f"{self}: cannot open ({exc}); on Linux the user needs read/write access to the "
                "hidraw node (a udev rule)"
            ) from exc
        self._device = device

    def _close(self) -> None:
        device, self._device = self._device, None
        if device is not None:
            # The handle of an unplugged device may already be gone.
            with contextlib.suppress(OSError, ValueError):
                device.close()

    def _check_written(self, what: str, written: int, expected: int) -> None:
        if written < expected:
            raise DisplayError(f"{self}: {what} wrote {written} of {expected} bytes")

    def _write_report(self, report: bytes) -> None:
        try:
            written = self._device.write(report)
        except (OSError, ValueError) as exc:
            raise DisplayError(f"{self}: output report write failed: {exc}") from exc
        self._check_written("output report", written, len(report))

    def _read_report(self, timeout_s: float) -> bytes | None:
        try:
            data = self._device.read(_READ_SIZE, round(timeout_s * 1000))
        except (OSError, ValueError) as exc:
            raise DisplayError(f"{self}: input report read failed: {exc}") from exc
        return bytes(data) or None

    def _get_feature(self) -> bytes:
        try:
            data = self._device.get_feature_report(FEATURE_LAYOUT.report_id, FEATURE_LAYOUT.size)
        except (OSError, ValueError) as exc:
            raise DisplayError(f"{self}: feature report read failed: {exc}") from exc
        return bytes(data)

    def _set_feature(self, report: bytes) -> None:
        try:
            written = self._device.send_feature_report(report)
        except (OSError, ValueError) as exc:
            raise DisplayError(f"{self}: feature report write failed: {exc}") from exc
        self._check_written("feature report", written, len(report))
