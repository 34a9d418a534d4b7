"""The load-cell family: base class, backend table and :func:`make_load_cell`.

A load cell streams normal force (N) samples stamped with ``time.monotonic()`` seconds.
HX711 backends convert raw counts with ``LoadCellSettings``:
``force_n = (counts - tare_counts) / counts_per_n``; :meth:`LoadCell.tare` then zeroes
the reading at rest with an offset in newtons on top of that calibration.
"""

from __future__ import annotations

import numpy as np

from teleop.devices.base import Device, check_timeout, load_backend
from teleop.errors import DeviceTimeoutError, InvalidCommandError
from teleop.record import Samples
from teleop.settings import LoadCellSettings

__all__ = ["BACKENDS", "FIXES", "LoadCell", "make_load_cell"]

BACKENDS = {
    "sim": "teleop.devices.playback:SimulatedLoadCell",
    "serial": "teleop.devices.hx711:SerialHx711",
    "tcp": "teleop.devices.hx711:TcpHx711",
}

FIXES = {  # what to do when a backend's cell does not open or deliver
    "serial": "check the cable and `load_cell.port`",
    "tcp": "check the bridge runs (`teleop hx711-bridge`) and `load_cell.address`",
}
TARE_WINDOW_S = 0.25  # default tare: average over this much of the sample stream


def make_load_cell(settings: LoadCellSettings, *, backend: str | None = None, **options) -> LoadCell:
    """An unconnected load cell of ``backend`` (default ``settings.backend``).

    ``options`` go to the backend (``playback=`` for ``sim``).
    """
    cls = load_backend("load cell", BACKENDS, backend or settings.backend)
    return cls(settings, **options)


class LoadCell(Device):
    """A force sensor. Backends implement ``_connect``, ``_close`` and ``_take``."""

    family = "load cell"

    def __init__(self, settings: LoadCellSettings):
        super().__init__()
        self.settings = settings
        self.offset_n = 0.0
        self._leftover = Samples(np.zeros(0), np.zeros(0))  # raw samples tare took but did not use

    def read(self, *, timeout_s: float | None = None) -> Samples:
        """Every force sample (t_s, N) that arrived since the last read, minus the tare offset.

        Waits up to ``timeout_s`` (default ``settings.timeout_s``) for at least one.

        Raises
        ------
        DeviceTimeoutError
            No sample arrived within the timeout.
        DeviceStalledError
            A streaming cell has given no valid reading for too long (:mod:`teleop.devices.hx711`).
        DeviceError
            The link failed or closed.
        """
        self._require_connected()
        timeout = check_timeout(self.settings.timeout_s if timeout_s is None else timeout_s)
        samples = self._take_raw(timeout)
        if len(samples) == 0:
            self._require_connected()  # closed while waiting
            raise DeviceTimeoutError(f"{self!r}: no force sample within {timeout} s")
        return Samples(samples.t_s, samples.value - self.offset_n)

    def tare(self, *, n_samples: int | None = None, timeout_s: float | None = None) -> float:
        """Zero the reading: the mean of the next ``n_samples`` becomes the offset (N), returned.

        ``n_samples`` (an integer >= 1) defaults to 0.25 s of samples. The samples used are
        consumed. Keep the cell unloaded while it runs.
        """
        self._require_connected()
        n = n_samples if n_samples is not None else max(1, round(TARE_WINDOW_S * self.settings.sample_rate_hz))
        if not isinstance(n, int) or isinstance(n, bool) or n < 1:  # True is no count, though it equals 1
            raise InvalidCommandError(f"n_samples = {n_samples!r}: expected an integer >= 1")
        timeout = check_timeout(self.settings.timeout_s if timeout_s is None else timeout_s)
        batches: list[Samples] = []
        while sum(len(b) for b in batches) < n:
            batch = self._take_raw(timeout)
            if not len(batch):
                self._require_connected()  # closed while waiting
                raise DeviceTimeoutError(f"{self!r}: tare got no force sample within {timeout} s")
            batches.append(batch)
        t = np.concatenate([b.t_s for b in batches])
        raw = np.concatenate([b.value for b in batches])
        self.offset_n = float(raw[:n].mean())
        self._leftover = Samples(t[n:], raw[n:])  # later samples belong to the next read
        return self.offset_n

    def close(self) -> None:
        super().close()
        self._leftover = Samples(np.zeros(0), np.zeros(0))  # a reconnected cell starts afresh

    def _take_raw(self, timeout_s: float) -> Samples:
        if not len(self._leftover):
            return self._take(timeout_s)
        fresh = self._take(0.0)
        leftover, self._leftover = self._leftover, Samples(np.zeros(0), np.zeros(0))
        return Samples(np.concatenate([leftover.t_s, fresh.t_s]), np.concatenate([leftover.value, fresh.value]))

    def counts_to_force_n(self, counts: np.ndarray | int) -> np.ndarray:
        """Raw HX711 counts to newtons with this cell's ``tare_counts`` and ``counts_per_n``."""
        return (np.asarray(counts, dtype=np.float64) - self.settings.tare_counts) / self.settings.counts_per_n

    def _take(self, timeout_s: float) -> Samples:
        """Samples (raw N, before the tare offset) that arrived; waits up to ``timeout_s`` for one."""
        raise NotImplementedError
