"""The demo's simulated operator seat (:class:`teleop.system.seat.SimulatedSeat`) without its processes:
what it listens to and drives, its thread's start and stop, and what it hands the demo's main thread."""

from __future__ import annotations

import dataclasses
import threading
import time
from types import SimpleNamespace

import pytest

from haptics.operator_link import ROBOT_TOPICS
from teleop.errors import BusError
from teleop.settings import default_settings_path, load_settings
from teleop.system.live_system import LiveSystem
from teleop.system.seat import SimulatedSeat


@pytest.fixture
def opened(tmp_path):
    """A live system with its bus ends open (no children), and settings with their own heartbeat."""
    shipped = load_settings(default_settings_path())
    settings = dataclasses.replace(shipped, bus=dataclasses.replace(shipped.bus,
                                                                    heartbeat_s=shipped.bus.heartbeat_s + 0.25))
    system = LiveSystem(default_settings_path(), "quick", tmp_path, tmp_path / "calibration.npz")
    try:
        system.open_bus(settings)
        yield system, settings
    finally:
        system.stop()


class _Device:
    """The simulated input's part the seat itself uses, recording what happens to it."""

    operator = None

    def __init__(self, thread_alive):
        self.calls: list[tuple[str, bool]] = []
        self._thread_alive = thread_alive

    def connect(self) -> None:
        self.calls.append(("connect", self._thread_alive()))

    def close(self) -> None:
        self.calls.append(("close", self._thread_alive()))


class _Loop:
    """An operator loop that runs until told to stop, then takes a moment to finish its step."""

    def __init__(self, error: BaseException | None = None):
        self.error = error
        self.stopped = False

    def run(self, stop: threading.Event) -> None:
        if self.error is not None:
            raise self.error
        self.stopped = stop.wait(timeout=60.0)
        time.sleep(0.2)


def test_the_seat_listens_to_the_robot_estimates_and_display_and_drives_the_command_publisher(opened):
    system, settings = opened
    seat = SimulatedSeat(system, settings, grasps=3)
    try:
        bus = system.bus
        assert seat._subscriber.endpoints == [bus.robot_pub, bus.estimate_pub, bus.display_pub]
        assert set(seat._subscriber.topics) - {"heartbeat"} == {*ROBOT_TOPICS, "estimate", "display"}
        assert seat.link.publisher is system.commands and seat.link.subscriber is seat._subscriber
        assert seat.link.heartbeat_s == settings.bus.heartbeat_s
        assert seat.device.grasps == 3 and seat.loop.device is seat.device and seat.loop.link is seat.link
        assert seat.style() == ""  # before the first grasp
        seat.device = _Device(seat._thread.is_alive)
        seat.device.operator = SimpleNamespace(style=SimpleNamespace(describe=lambda: "slow, firm, two pauses"))
        assert seat.style() == "slow, firm, two pauses"
        assert seat._thread.daemon  # a stuck operator does not keep the demo's process alive
    finally:
        seat._subscriber.close()


def test_leaving_the_seat_stops_the_operator_and_waits_for_it_before_closing_the_device_and_bus(opened):
    system, settings = opened
    seat = SimulatedSeat(system, settings, grasps=1)
    seat.device = device = _Device(seat._thread.is_alive)
    seat.loop = loop = _Loop()
    with seat:
        assert device.calls == [("connect", False)]  # connected before the operator's thread starts
        assert seat._thread.is_alive()
    assert loop.stopped  # told to stop, not left to time out
    assert device.calls == [("connect", False), ("close", False)]  # its thread ended before the close
    with pytest.raises(BusError, match="is closed"):
        seat._subscriber.recv(timeout_s=0.0)
    seat.check()  # nothing went wrong


@pytest.mark.parametrize("error", [RuntimeError("the operator's hand slipped"), SystemExit("hand slipped")])
def test_what_ended_the_operators_thread_is_raised_in_the_demos(opened, error):
    # Whatever ended it, a SystemExit too: the thread keeps it for the demo's main thread to raise.
    system, settings = opened
    seat = SimulatedSeat(system, settings, grasps=1)
    seat.device = _Device(seat._thread.is_alive)
    seat.loop = _Loop(error=error)
    with seat:
        seat._thread.join(timeout=30.0)
    assert seat.error is error
    with pytest.raises(type(error), match="hand slipped"):
        seat.check()


def test_an_operator_that_does_not_stop_is_left_its_device_and_bus_and_said_so(opened, monkeypatch, caplog):
    # Closing them under its running loop would pull a ZeroMQ socket from under another thread.
    system, settings = opened
    monkeypatch.setattr("teleop.system.seat.JOIN_TIMEOUT_S", 0.05)
    seat = SimulatedSeat(system, settings, grasps=1)
    seat.device = device = _Device(seat._thread.is_alive)
    release = threading.Event()
    seat.loop = SimpleNamespace(run=lambda stop: release.wait(timeout=60.0))  # deaf to its stop
    try:
        with caplog.at_level("WARNING", logger="teleop.system.seat"), seat:
            pass
        assert seat._thread.is_alive() and device.calls == [("connect", False)]
        assert "the simulated operator did not stop within 0.05 s" in caplog.text
    finally:
        release.set()
        seat._thread.join(timeout=30.0)
        seat._subscriber.close()
