"""The robot node's devices: connect them, read each in its own thread, close them.

:class:`NodeDevices` takes the node's gripper, tactile cameras and load cell, connects them
(taring a hardware load cell) and reads each in its own thread until closed, putting what
they capture on the node's queue as ``(kind, item)``: ``("frame", frame)`` from each camera,
``("force", samples)`` from the load cell, ``("width", samples)`` from the gripper, and
``("device_error", (name, reason))`` once when a device's reads fail and once when it reads
again. A device whose reads fail is opened again every :data:`REOPEN_S` meanwhile, as after a
bridge, stream or robot restart: a camera or the load cell at once (nothing else drives them), the
gripper only while it stays down (:attr:`~teleop.devices.gripper.Gripper.link_error`), since
reopening it ends the command it runs. The node (:mod:`teleop.node`) publishes the queue.
"""

from __future__ import annotations

import logging
import queue
import threading
from collections.abc import Callable
from typing import Any

from teleop.devices.camera import TactileCamera
from teleop.devices.gripper import Gripper
from teleop.devices.loadcell import LoadCell
from teleop.errors import DeviceError, DeviceTimeoutError
from teleop.record import Samples

__all__ = ["READ_TIMEOUT_S", "REOPEN_S", "NodeDevices"]

log = logging.getLogger("teleop.node")  # the node's own logger, so filters on the node see the readers

READ_TIMEOUT_S = 0.05  # device reads wake this often to see whether the node is stopping
REOPEN_S = 1.0  # a device whose reads fail is opened again this often


class NodeDevices:
    """The node's devices and their reader threads (see the module docstring)."""

    def __init__(self, gripper: Gripper, cameras: list[TactileCamera], load_cell: LoadCell,
                 captured: queue.Queue[tuple[str, Any]]):
        self.gripper = gripper
        self.cameras = cameras
        self.load_cell = load_cell
        self.captured = captured
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []

    def connect(self, *, tare: bool) -> None:
        """Connect the devices (``tare``: tare the load cell, at rest) and start one reader per device."""
        devices = [self.gripper, *self.cameras, self.load_cell]
        try:
            for device in devices:
                device.connect()
            if tare:
                self.load_cell.tare()  # at rest: nothing is grasped yet
        except BaseException:
            for device in devices:
                device.close()
            raise
        readers = [(f"camera-{c.sensor.finger}", self._read_camera, c) for c in self.cameras]
        readers += [("load-cell", self._read_forces, self.load_cell), ("gripper", self._read_widths, self.gripper)]
        for name, target, device in readers:
            thread = threading.Thread(target=target, args=(device,), name=name, daemon=True)
            thread.start()
            self._threads.append(thread)

    def stop(self) -> None:
        """Stop the readers; calling twice is fine."""
        self._stop.set()
        for thread in self._threads:
            thread.join(timeout=2.0)
        self._threads.clear()

    def close(self) -> None:
        """Release the devices; calling twice is fine."""
        for device in (self.gripper, *self.cameras, self.load_cell):
            device.close()

    # ------------------------------------------------------------------ readers (one thread each)

    def _read_camera(self, camera: TactileCamera) -> None:
        self._read_forever(camera, f"camera/{camera.sensor.finger}",
                           lambda: ("frame", camera.read(timeout_s=READ_TIMEOUT_S)), reopen=True)

    def _read_forces(self, cell: LoadCell) -> None:
        self._read_forever(cell, "load_cell", lambda: ("force", cell.read(timeout_s=READ_TIMEOUT_S)), reopen=True)

    def _read_widths(self, gripper: Gripper) -> None:
        def read() -> tuple[str, Samples] | None:
            widths = gripper.widths(timeout_s=READ_TIMEOUT_S)
            return ("width", widths) if len(widths) else None

        self._read_forever(gripper, "gripper", read, reopen=lambda: gripper.link_error is not None or not gripper.connected)

    def _read_forever(self, device: Any, name: str, read: Callable[[], tuple[str, Any] | None], *,
                      reopen: bool | Callable[[], bool]) -> None:
        """Read ``device`` until the node stops. A failure is said once on the bus (and that it
        reads again); meanwhile the device is opened again every :data:`REOPEN_S` (``reopen``
        True, or a callable saying whether it still needs it)."""
        failing = False
        while not self._stop.is_set():
            try:
                item = read()
            except DeviceTimeoutError:
                continue
            except DeviceError as exc:
                if not self._stop.is_set() and not failing:
                    log.warning("%r: read failed: %s", device, exc)
                    self.captured.put(("device_error", (name, f"{exc}; opening it again")))
                failing = True
                if not self._stop.wait(REOPEN_S) and (reopen() if callable(reopen) else reopen):
                    self._reopen(device)
                continue
            if failing:
                log.warning("%r: reading again", device)
                self.captured.put(("device_error", (name, "reading again")))
                failing = False
            if item is not None:
                self.captured.put(item)

    def _reopen(self, device: Any) -> None:
        device.close()
        try:
            device.connect()
        except DeviceError as exc:
            log.debug("%r: not open again yet: %s", device, exc)
        if self._stop.is_set():  # the node closed while it opened (a camera may take seconds)
            device.close()
