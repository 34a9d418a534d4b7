"""An HX711 cell that gives no valid reading for a while is down: silent, garbage or saturated."""

from __future__ import annotations

import contextlib
import os
import queue
import threading
import time

import pytest

from teleop import node_devices
from teleop.devices.gripper import make_gripper
from teleop.devices.hx711 import STALL_S
from teleop.devices.loadcell import make_load_cell
from teleop.errors import DeviceError, DeviceTimeoutError
from teleop.node_devices import NodeDevices
from teleop.settings import GripperSettings, LoadCellSettings

CAL = {"counts_per_n": 1000.0, "tare_counts": 0, "timeout_s": 1.0}
RAIL = 2**23 - 1  # what a saturated HX711 reads


class Bridge:
    """Writes ``line`` to the serial line at 80 Hz (None: nothing) until closed."""

    def __init__(self, master: int):
        self.master = master
        self.line: bytes | None = b"1000\n"
        self._done = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._done.wait(1 / 80):
            if self.line is not None:
                os.write(self.master, self.line)

    def close(self) -> None:
        self._done.set()
        self._thread.join(timeout=2.0)


@pytest.fixture
def bridge(pty_pair):
    master, port = pty_pair
    feeder = Bridge(master)
    yield feeder, port
    feeder.close()


def _read_until_down(cell, within_s: float) -> tuple[DeviceError, float]:
    """The error that says the cell is down, and how long after the first read it came."""
    started = time.monotonic()
    while time.monotonic() - started < within_s:
        try:
            cell.read(timeout_s=0.05)
        except DeviceTimeoutError:
            continue
        except DeviceError as exc:
            return exc, time.monotonic() - started
    pytest.fail(f"the cell was not down within {within_s} s")


def _collect(captured: queue.Queue, got: list, within_s: float, done=lambda: False) -> bool:
    """Append what the readers queue to ``got`` until ``done()`` (True) or ``within_s`` passed (False)."""
    end = time.monotonic() + within_s
    while not done():
        if time.monotonic() > end:
            return False
        with contextlib.suppress(queue.Empty):
            got.append(captured.get(timeout=0.05))
    return True


@pytest.mark.parametrize(("line", "why"), [
    (None, "silent: nothing arrived"),
    (b"hello\n", "garbage"),
    (b"%d\n" % RAIL, f"saturated or out of range: counts {RAIL}"),
])
def test_a_cell_without_valid_readings_is_down_saying_why_until_one_comes(bridge, line, why):
    feeder, port = bridge
    with make_load_cell(LoadCellSettings(backend="serial", port=port, **CAL)) as cell:
        assert len(cell.read(timeout_s=2.0))
        feeder.line = line
        error, after_s = _read_until_down(cell, 3.0)
        assert why in str(error) and "no valid reading for" in str(error)
        assert after_s < STALL_S + 0.5  # the threshold, not the cell's 1 s timeout
        feeder.line = b"2000\n"
        end = time.monotonic() + 2.0
        while True:  # down until a valid reading comes, then read as ever
            assert time.monotonic() < end, "the cell did not read again"
            try:
                if 2.0 in cell.read(timeout_s=0.05).value:
                    break
            except DeviceError:
                continue


@pytest.mark.slow
def test_a_saturated_cell_is_said_once_on_the_bus_and_that_it_reads_again(bridge, monkeypatch):
    monkeypatch.setattr(node_devices, "REOPEN_S", 0.2)
    feeder, port = bridge
    captured: queue.Queue = queue.Queue()
    devices = NodeDevices(make_gripper(GripperSettings()), [],
                          make_load_cell(LoadCellSettings(backend="serial", port=port, **CAL)), captured)
    devices.connect(tare=False)
    try:
        feeder.line = b"%d\n" % RAIL
        got: list = []
        assert _collect(captured, got, 5.0, lambda: any(kind == "device_error" for kind, _ in got))
        _collect(captured, got, 1.5)  # saturated for several reopen periods more
        feeder.line = b"1000\n"
        assert _collect(captured, got, 5.0, lambda: ("device_error", ("load_cell", "reading again")) in got)
        errors = [item for kind, item in got if kind == "device_error"]
        assert len(errors) == 2 and errors[1] == ("load_cell", "reading again")  # once, not per read
        name, reason = errors[0]
        assert name == "load_cell" and f"counts {RAIL}" in reason and reason.endswith("; opening it again")
    finally:
        devices.stop()
        devices.close()


@pytest.mark.slow
def test_a_reader_left_in_a_slow_receive_by_close_writes_nothing_into_the_next_connection():
    from teleop.devices.hx711 import SerialHx711

    class Stuck(SerialHx711):
        """Its first connection's receive hangs past close()'s wait, then returns a reading."""

        def __init__(self, settings):
            super().__init__(settings)
            self.release, self.connections = threading.Event(), 0

        def _open_link(self) -> None:
            self.connections += 1

        def _close_link(self) -> None:
            pass

        def _receive(self) -> bytes:
            if self.connections == 1:
                self.release.wait(10.0)
                return b"777000\n777000\n777000\n"  # 777 N: the old connection's, late
            time.sleep(0.01)
            return b""

    cell = Stuck(LoadCellSettings(backend="serial", port="/dev/null", **CAL))
    cell.connect()
    old = cell._reader
    cell.close()  # the reader is still in its receive after close's 2 s wait
    cell.connect()
    cell.release.set()
    old.join(5.0)  # it has done whatever it does with its late bytes
    try:
        late = cell.read(timeout_s=0.3)
    except DeviceError:  # stalled: nothing valid arrived on this connection, as it should be
        late = None
    assert late is None or not len(late), late
    cell.close()
