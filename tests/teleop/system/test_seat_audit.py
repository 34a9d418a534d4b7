"""An operator seat that does not stop keeps the command publisher it drives: the live system's stop,
which comes right after the seat is left, must not close it under the operator's running loop."""

from __future__ import annotations

import threading
from types import SimpleNamespace

from teleop.settings import default_settings_path, load_settings
from teleop.system.live_system import LiveSystem
from teleop.system.seat import SimulatedSeat


class _Device:
    operator = None

    def connect(self) -> None:
        pass

    def close(self) -> None:
        pass


def test_an_operator_that_does_not_stop_keeps_its_command_publisher_through_the_systems_stop(tmp_path,
                                                                                            monkeypatch):
    # A ZeroMQ socket closed under another thread can abort the process: the seat left its subscriber
    # open, but the live system's stop then closed the publisher the stuck loop still sends on.
    monkeypatch.setattr("teleop.system.seat.JOIN_TIMEOUT_S", 0.05)
    settings = load_settings(default_settings_path())
    system = LiveSystem(default_settings_path(), "quick", tmp_path, tmp_path / "calibration.npz")
    system.open_bus(settings)
    publisher = system.commands
    seat = SimulatedSeat(system, settings, grasps=1)
    seat.device = _Device()
    release = threading.Event()
    seat.loop = SimpleNamespace(run=lambda stop: release.wait(timeout=60.0))  # deaf to its stop
    try:
        with seat:
            pass
        assert seat._thread.is_alive()
        system.stop()
        assert publisher._socket is not None  # still open for the running loop
    finally:
        release.set()
        seat._thread.join(timeout=30.0)
        seat._subscriber.close()
        publisher.close()


def test_an_operator_that_stops_leaves_the_command_publisher_to_the_systems_stop(tmp_path):
    settings = load_settings(default_settings_path())
    system = LiveSystem(default_settings_path(), "quick", tmp_path, tmp_path / "calibration.npz")
    system.open_bus(settings)
    publisher = system.commands
    seat = SimulatedSeat(system, settings, grasps=1)
    seat.device = _Device()
    seat.loop = SimpleNamespace(run=lambda stop: stop.wait(timeout=60.0))
    try:
        with seat:
            pass
        assert system.commands is publisher
    finally:
        system.stop()
    assert publisher._socket is None
