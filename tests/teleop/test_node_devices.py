"""The node's device readers (:class:`teleop.node_devices.NodeDevices`): a gripper that loses its link.

A gripper backend whose link the test cuts and restores stands in for a Franka hand whose robot
(or franky-sim) went away and came back.
"""

from __future__ import annotations

import queue
import threading
import time
from collections.abc import Callable
from typing import Any

import pytest

from teleop import node_devices
from teleop.devices import gripper as gripper_module
from teleop.devices.gripper import Gripper
from teleop.devices.loadcell import make_load_cell
from teleop.errors import DeviceError
from teleop.node_devices import NodeDevices
from teleop.settings import GripperSettings, LoadCellSettings

NET = "franky gripper at 127.0.0.77: width read failed: Net Exception"


class LinkGripper(Gripper):
    """A gripper whose link is up while ``up`` is set: its reads and connects fail meanwhile, and
    a max width read blocks as franky's does on a dead link."""

    def __init__(self, settings: GripperSettings):
        super().__init__(settings)
        self.up = threading.Event()
        self.up.set()
        self.opens = 0
        self.max_width_reads = 0
        self.stops = 0

    def _link(self) -> None:
        if not self.up.is_set():
            time.sleep(0.05)
            raise DeviceError(NET)

    def _open(self) -> None:
        self.opens += 1
        self._link()

    def _shutdown(self) -> None:
        pass

    def _move(self, width_m: float, speed_m_s: float) -> bool:
        self._link()
        return True

    def _follow(self, width_m: float, speed_m_s: float) -> None:
        pass

    def _stop(self) -> bool:
        self.stops += 1
        self._link()
        return True

    def _read_width(self) -> float:
        self._link()
        return 0.05

    def _max_width(self) -> float:
        self.max_width_reads += 1
        if not self.up.is_set():
            time.sleep(1.0)  # franky blocks about this long before a Net Exception
        self._link()
        return 0.08


def _wait_for(captured: queue.Queue, wanted: Callable[[tuple[str, Any]], bool], within_s: float) -> list:
    """What the readers queued up to and including the first item ``wanted`` accepts."""
    got, end = [], time.monotonic() + within_s
    while time.monotonic() < end:
        try:
            got.append(captured.get(timeout=0.05))
        except queue.Empty:
            continue
        if wanted(got[-1]):
            return got
    pytest.fail(f"nothing wanted within {within_s} s: got {[kind for kind, _ in got]}")


def _gripper_errors(got: list) -> list[str]:
    return [item[1] for kind, item in got if kind == "device_error" and item[0] == "gripper"]


@pytest.fixture
def rig(monkeypatch):
    monkeypatch.setattr(node_devices, "REOPEN_S", 0.2)
    gripper = LinkGripper(GripperSettings(width_read_hz=50.0))
    captured: queue.Queue = queue.Queue()
    devices = NodeDevices(gripper, [], make_load_cell(LoadCellSettings()), captured)  # a silent simulated cell
    devices.connect(tare=False)
    yield gripper, captured
    devices.stop()
    devices.close()


def test_a_gripper_that_loses_its_link_is_reported_once_and_opened_again_when_it_is_back(rig):
    gripper, captured = rig
    _wait_for(captured, lambda item: item[0] == "width", 2.0)
    gripper.up.clear()
    got = _wait_for(captured, lambda item: item[0] == "device_error", 3.0)
    (reason,) = _gripper_errors(got)
    assert NET in reason and reason.endswith("; opening it again")
    # Down: commands are refused at once, saying why, and the node tries to open it again.
    with pytest.raises(DeviceError, match="is down .*Net Exception"):
        gripper.move_async(0.04)
    opens = gripper.opens
    end = time.monotonic() + 5.0
    while gripper.opens < opens + 2:
        assert time.monotonic() < end, "the gripper was not opened again"
        time.sleep(0.02)
    with pytest.raises(DeviceError, match="is down .*Net Exception"):
        gripper.move_async(0.04)
    gripper.up.set()  # the robot is back
    got += _wait_for(captured, lambda item: item == ("device_error", ("gripper", "reading again")), 5.0)
    got += _wait_for(captured, lambda item: item[0] == "width", 2.0)
    assert _gripper_errors(got) == [reason, "reading again"]  # once, not per read
    assert gripper.connected and gripper.opens > opens
    assert gripper.move_async(0.04).result(timeout=2.0)


def test_width_reads_dropped_briefly_do_not_reopen_a_gripper_that_reads_again(rig, monkeypatch):
    gripper, captured = rig
    monkeypatch.setattr(node_devices, "REOPEN_S", 1.0)
    monkeypatch.setattr(gripper_module, "LINK_DOWN_S", 0.02)  # down within the drop: the node hears of it
    _wait_for(captured, lambda item: item[0] == "width", 2.0)
    gripper.up.clear()
    time.sleep(0.1)  # a few dropped reads (at 50 Hz), well within REOPEN_S
    gripper.up.set()
    # Heard or not (the widths' reader may miss so short a loss), it is not opened again.
    _wait_for(captured, lambda item: item[0] == "width", 5.0)
    assert gripper.opens == 1  # a command it ran meanwhile was not cut short


def test_the_max_width_is_read_once_per_connection_and_a_down_gripper_refuses_at_once(rig):
    gripper, captured = rig
    for width in (0.01, 0.02, 0.03):
        assert gripper.move_async(width).result(timeout=2.0)
        gripper.follow(width)
    assert gripper.max_width_m == 0.08 and gripper.max_width_reads == 1
    gripper.up.clear()
    _wait_for(captured, lambda item: item[0] == "device_error", 3.0)
    started = time.monotonic()
    for action in (lambda: gripper.move_async(0.04), lambda: gripper.grasp_async(0.0),
                   lambda: gripper.follow(0.04)):
        with pytest.raises(DeviceError, match="Net Exception"):
            action()
    assert time.monotonic() - started < 1.0  # no blocking call (1 s here) on the dead link in the caller's thread


def test_a_dropped_read_leaves_the_gripper_up_and_a_stop_always_goes_to_the_fingers(monkeypatch):
    monkeypatch.setattr(gripper_module, "LINK_DOWN_S", 2.0)
    with LinkGripper(GripperSettings(width_read_hz=50.0)) as gripper:
        gripper.up.clear()
        time.sleep(0.4)  # several failed reads (each takes 50 ms), but not failing for LINK_DOWN_S: not down yet
        assert gripper.link_error is None
        end = time.monotonic() + 5.0
        while gripper.link_error is None:  # failing for LINK_DOWN_S: down
            assert time.monotonic() < end, "the gripper never went down"
            time.sleep(0.02)
        with pytest.raises(DeviceError, match="is down"):
            gripper.move_async(0.04)
        with pytest.raises(DeviceError, match="Net Exception"):  # the backend's own failure: it was tried
            gripper.stop()
        assert gripper.stops == 1


def test_one_slow_failed_read_is_not_down():
    class SlowOnce(LinkGripper):
        """Its next read fails after 0.6 s (franky on a dropped packet); the one after waits for the test."""

        def __init__(self, settings: GripperSettings):
            super().__init__(settings)
            self.slow, self.second, self.checked = threading.Event(), threading.Event(), threading.Event()

        def _read_width(self) -> float:
            if self.slow.is_set():
                self.slow.clear()
                time.sleep(0.6)
                self.second.set()
                raise DeviceError(NET)
            if self.second.is_set():
                self.checked.wait(5.0)
            return 0.05

    with SlowOnce(GripperSettings(width_read_hz=50.0)) as gripper:
        gripper.slow.set()
        assert gripper.second.wait(5.0)
        time.sleep(0.1)  # the reader has judged the failure and waits in the next read
        assert gripper.link_error is None  # one failed read, however slow, is not a dead link
        gripper.checked.set()


def test_a_franky_command_racing_a_close_is_a_device_error():
    pytest.importorskip("franky")
    from teleop.devices.franky_gripper import FrankyGripper

    hand = FrankyGripper(GripperSettings(backend="franky", host="127.0.0.77"))  # never opened: no franky object
    for command in (hand._stop, lambda: hand._move(0.04, 0.05), hand._max_width, hand._read_width):
        with pytest.raises(DeviceError, match="is closed"):
            command()
