"""A port another program holds: each server that listens says so and what to do, naming its option."""

from __future__ import annotations

import socket

import pytest

import teleop.system.demo
from teleop.cli import main
from teleop.devices.hx711_bridge import Hx711Bridge
from teleop.errors import BusError, DeviceError, TeleopError
from teleop.session.foxglove_live import LiveServer


@pytest.fixture
def held_port():
    """A loopback TCP port another program (here: a plain socket) listens on."""
    with socket.create_server(("127.0.0.1", 0)) as holder:
        yield holder.getsockname()[1]


def test_the_foxglove_view_on_a_held_port_says_to_stop_the_other_program_or_choose_another(held_port):
    with pytest.raises(BusError, match=f"127.0.0.1:{held_port}.*another program.*holds the port: stop it or choose "
                                       "another \\(--foxglove PORT, or --foxglove 0 for any free one\\)"):
        LiveServer("127.0.0.1", held_port)


def test_the_hx711_bridge_on_a_held_port_says_to_stop_the_other_program_or_choose_another(held_port):
    with pytest.raises(DeviceError, match=f"127.0.0.1:{held_port}.*another program.*holds the port: stop it or "
                                          "choose another \\(teleop hx711-bridge --port PORT, or --port 0"):
        Hx711Bridge(lambda: 0, host="127.0.0.1", port=held_port).start()


def test_demo_names_the_foxglove_view_only_once_the_system_serving_it_is_up(tmp_path, capsys, monkeypatch):
    class RecorderCannotBind:  # the live system whose recorder exits: its Foxglove port is held
        def __init__(self, *args, **kwargs):
            pass

        def __enter__(self):
            raise TeleopError("recorder exited with status 2")

        def __exit__(self, *exc):
            pass

    monkeypatch.setattr(teleop.system.demo, "LiveSystem", RecorderCannotBind)
    assert main(["demo", "--scene", "quick", "--no-view", "--foxglove", "--out", str(tmp_path / "run")]) == 2
    err = capsys.readouterr().err
    assert "recorder exited" in err and "Foxglove live view" not in err
