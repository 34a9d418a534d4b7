"""The live system with CURVE keys in its settings: every bus end, the demo's own included, uses them."""

from __future__ import annotations

import dataclasses
import json
import time

import pytest
from support.scenes import one_grasp_scene

import teleop.cli
from teleop.bus.pubsub import Publisher, Subscriber
from teleop.bus.security import init_keys
from teleop.settings import default_settings_path, load_settings
from teleop.settings_edit import update_settings_file
from teleop.system.live_system import LiveSystem
from teleop.system.seat import SimulatedSeat


@pytest.mark.slow
def test_the_demos_and_the_seats_bus_ends_use_the_settings_keys(tmp_path):
    # The children run CURVE when the settings name keys, on loopback too; plain ends would hear none of them.
    init_keys(tmp_path / "keys")
    shipped = load_settings()
    settings = dataclasses.replace(shipped, bus=dataclasses.replace(shipped.bus, keys_dir=str(tmp_path / "keys")))
    system = LiveSystem(default_settings_path(), "quick", tmp_path, tmp_path / "calibration.npz")
    seat = None
    try:
        system.open_bus(settings)
        bus = system.bus
        assert (bus.keys_dir, bus.command) == (settings.bus.keys_dir, system.endpoints["command"])
        seat = SimulatedSeat(system, settings, grasps=1)
        with (
            Publisher.from_settings(bus, bus.robot_pub, lossless=False, source="robot") as robot,  # as the node
            Subscriber.from_settings(bus, bus.command, ("command",)) as node_commands,
        ):
            listeners = (system.events, seat._subscriber, node_commands)
            deadline = time.monotonic() + 5.0
            while time.monotonic() < deadline and not (
                    "robot" in system.events.heartbeat.peers() and "robot" in seat._subscriber.heartbeat.peers()
                    and "operator" in node_commands.heartbeat.peers()):
                robot.send("heartbeat", t_capture_s=time.monotonic(), interval_s=0.5)
                system.commands.send("heartbeat", t_capture_s=time.monotonic(), interval_s=0.5)
                for listener in listeners:
                    listener.recv(timeout_s=0.01)
            assert [listener.heartbeat.peers() for listener in listeners] == [["robot"], ["robot"], ["operator"]]
    finally:
        if seat is not None:
            seat._subscriber.close()
        system.stop()


@pytest.mark.slow
def test_a_demo_whose_settings_name_keys_runs_curve_end_to_end(tmp_path, capsys):
    init_keys(tmp_path / "keys")
    shipped = load_settings()
    settings = tmp_path / "rig.toml"
    settings.write_bytes(default_settings_path().read_bytes())
    update_settings_file(settings, {"bus.keys_dir": str(tmp_path / "keys"),  # the copy's calibrations stay found
                                    **{f"sensors.{s.finger}.calibration": s.calibration for s in shipped.sensors}})
    scene = one_grasp_scene(tmp_path)
    scene.write_text(scene.read_text() + 'settings = "rig.toml"\n')
    code = teleop.cli.main(["demo", "--scene", str(scene), "--settings", str(settings), "--operator", "script",
                            "--json", "--no-view", "--out", str(tmp_path / "run")])
    captured = capsys.readouterr()
    assert code == 0, captured.err
    assert [g["state"] for g in json.loads(captured.out.strip().splitlines()[-1])["grasps"]] != ["insufficient_data"]
    assert not [line for log in (tmp_path / "run").glob("*.log") for line in log.read_text().splitlines()
                if "CURVE handshake" in line or "refused a CURVE client" in line]
