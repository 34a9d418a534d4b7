"""What every device family shares: an explicit lifecycle and a name table of backends.

A device is built unconnected, opened with :meth:`Device.connect` (or ``with``), used,
and closed with :meth:`Device.close`; using it while not connected raises
:class:`~teleop.errors.DeviceNotConnectedError`. Backends are named in a per-family
table of ``"module:Class"`` strings and imported only when opened, so the simulated
backend never imports vendor libraries. A backend class says whether it simulates its device
(:attr:`Device.simulated`); :mod:`teleop.devices.simulated` asks it by backend name.

All device timestamps are seconds of ``time.monotonic()`` on the host that reads the
device, the clock the bus and the grasp records of live sessions use.
"""

from __future__ import annotations

import importlib
import threading
from collections import deque
from collections.abc import Mapping
from typing import Any, ClassVar

import numpy as np

from teleop.errors import (
    BackendNotFoundError,
    DeviceError,
    DeviceNotConnectedError,
    InvalidCommandError,
)
from teleop.record import Samples

__all__ = ["Device", "SampleQueue", "check_timeout", "load_backend"]


def load_backend(family: str, backends: Mapping[str, str], name: str, *,
                 install: Mapping[str, str] | None = None) -> type:
    """Import the class registered as ``name`` in ``backends`` (``"module:Class"``).

    ``install`` says, per backend, what provides a library it needs when that is not the
    ``robot`` extra (the hardware libraries).

    Raises
    ------
    BackendNotFoundError
        ``name`` is not in the table (the message lists the names there are), or its
        module or a library it needs cannot be imported (the message says what to install).
    """
    if name not in backends:
        raise BackendNotFoundError(
            f"no {family} backend named {name!r}; available: {', '.join(sorted(backends))}"
        )
    module_name, _, class_name = backends[name].partition(":")
    try:
        module = importlib.import_module(module_name)
    except ImportError as exc:
        raise BackendNotFoundError.missing_library(f"{family} backend {name!r}", exc,
                                                   install=(install or {}).get(name)) from exc
    return getattr(module, class_name)


def check_timeout(timeout_s: float, *, poll: bool = False) -> float:
    """``timeout_s`` if it is a finite number > 0 (>= 0 with ``poll``); InvalidCommandError otherwise."""
    number = isinstance(timeout_s, int | float) and not isinstance(timeout_s, bool)  # True is no duration
    if not (number and (timeout_s >= 0 if poll else timeout_s > 0) and timeout_s < float("inf")):
        bound = ">= 0" if poll else "> 0"
        raise InvalidCommandError(f"timeout_s = {timeout_s!r}: expected a finite number of seconds {bound}")
    return float(timeout_s)


class Device:
    """Base of every device: ``connect()``, ``close()``, context manager, connected check.

    Subclasses implement ``_connect()`` and ``_close()``; public methods that touch the
    hardware call :meth:`_require_connected` first.
    """

    family = "device"
    #: Whether the backend simulates its device (fed by a simulated grasp) rather than drive hardware.
    simulated: ClassVar[bool] = False

    def __init__(self) -> None:
        self._connected = False
        self._was_closed = False

    @property
    def connected(self) -> bool:
        """Whether :meth:`connect` succeeded and :meth:`close` has not been called since."""
        return self._connected

    def connect(self):
        """Open the device; returns ``self``. Connecting twice is an error."""
        if self._connected:
            raise DeviceError(f"{self!r} is already connected")
        self._connect()
        self._connected = True
        self._was_closed = False
        return self

    def close(self) -> None:
        """Release the device; closing an unconnected device does nothing."""
        if self._connected:
            self._connected = False
            self._was_closed = True
            self._close()

    def __enter__(self):
        return self.connect()

    def __exit__(self, *exc: Any) -> None:
        self.close()

    def _require_connected(self) -> None:
        if not self._connected:
            state = "was closed" if self._was_closed else "is not connected: call connect() first"
            raise DeviceNotConnectedError(f"{self!r} {state}")

    def _connect(self) -> None:
        raise NotImplementedError

    def _close(self) -> None:
        raise NotImplementedError

    def __repr__(self) -> str:
        return f"<{type(self).__name__}>"


class SampleQueue:
    """Thread-safe queue of timestamped scalar samples, drained in batches.

    A reader thread :meth:`put` s samples as they arrive; the device's user takes all
    of them at once with :meth:`take`. When ``maxlen`` is reached the oldest samples
    are dropped and counted in :attr:`dropped`. :meth:`close` says no more will come:
    it wakes a waiting :meth:`take`, and later takes no longer wait.
    """

    def __init__(self, maxlen: int = 100_000):
        self._items: deque[tuple[float, float]] = deque(maxlen=maxlen)
        self._ready = threading.Condition()
        self._closed = False
        self.dropped = 0

    def close(self) -> None:
        """End the stream (device closed, link failed): takes return what is queued at once."""
        with self._ready:
            self._closed = True
            self._ready.notify_all()

    def put(self, t_s: float, value: float) -> None:
        with self._ready:
            if len(self._items) == self._items.maxlen:
                self.dropped += 1
            self._items.append((t_s, value))
            self._ready.notify_all()

    def take(self, timeout_s: float = 0.0) -> Samples:
        """Every queued sample (oldest first), waiting up to ``timeout_s`` (0: not at all) for at least one.

        Returns empty Samples when none arrived in time or the queue was closed.
        """
        timeout_s = check_timeout(timeout_s, poll=True)
        with self._ready:
            if timeout_s:
                self._ready.wait_for(lambda: bool(self._items) or self._closed, timeout=timeout_s)
            items = list(self._items)
            self._items.clear()
        if not items:
            return Samples(np.zeros(0), np.zeros(0))
        t, v = np.array(items, dtype=np.float64).T
        return Samples(t, v)
