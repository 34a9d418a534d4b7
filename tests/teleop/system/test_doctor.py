"""``teleop doctor``: the shipped simulated rig is ready; an unplugged device is named with what to do."""

from __future__ import annotations

import argparse
import errno
import json
import os
import re
import shlex
import socket
import sys
import threading
import time
import tty

import numpy as np
import pytest
from support.rig_settings import rig_settings

from teleop.bus.security import init_keys
from teleop.cli import main
from teleop.devices.playback import GraspPlayback
from teleop.errors import ComplianceTeleopError, TeleopError
from teleop.operator import FOLLOW_RATE_HZ
from teleop.record import FrameStream, GraspRecord, Provenance, Samples
from teleop.settings import (
    BusSettings,
    SensorSettings,
    Settings,
    default_settings_path,
    load_settings,
)
from teleop.system.doctor import (
    Check,
    _camera_probe,
    _display_probe,
    _judge,  # the verdict on readings, without reading a device
    _Probe,
    _run_probe,
    check_calibrations,
    check_devices,
    check_duration,
    check_endpoints,
)

DEVICES = ["gripper", "load cell", "camera left", "camera right", "display", "input keyboard"]


def _closed_port() -> int:
    probe = socket.create_server(("127.0.0.1", 0))
    port = probe.getsockname()[1]
    probe.close()
    return port


def _doctor(capsys, *argv: str) -> tuple[int, dict]:
    code = main(["doctor", "--json", "--duration-s", "1", *argv])
    return code, json.loads(capsys.readouterr().out)


def _edited(tmp_path, line, replacement):
    """The shipped settings with one line replaced, as a tester edits a copy (no check before writing)."""
    text = default_settings_path().read_text(encoding="utf-8")
    assert line in text
    path = tmp_path / "rig.toml"
    path.write_text(text.replace(line, replacement), encoding="utf-8")
    return path


@pytest.mark.slow
def test_the_shipped_simulated_rig_is_ready(capsys):
    code, report = _doctor(capsys)
    devices = {d["name"]: d for d in report["devices"]}
    assert list(devices) == DEVICES
    assert all(d["ok"] and d["problem"] is None for d in devices.values()), devices
    settings = load_settings(default_settings_path())
    assert devices["load cell"]["rate_hz"] == pytest.approx(settings.load_cell.sample_rate_hz, rel=0.2)
    assert devices["camera left"]["rate_hz"] == pytest.approx(settings.sensor("left").camera_hz, rel=0.2)
    assert devices["gripper"]["rate_hz"] == pytest.approx(settings.gripper.width_read_hz, rel=0.2)
    read = [d for name, d in devices.items() if name != "input keyboard"]  # the console's keys: nothing to open
    assert devices["input keyboard"]["detail"]["note"].startswith("the console's own keys")
    assert all(0 <= d["latency_ms"] < 150 for d in read)
    assert all(d["detail"]["monotonic"] and d["detail"]["host_clock"] for d in read)
    assert all(c["ok"] for c in report["calibrations"])
    assert all(c["detail"]["age_days"] >= 0 for c in report["calibrations"] if c["name"].startswith("calibration"))
    # the bus ports are free unless something on this machine holds them right now
    assert report["ok"] == all(e["ok"] for e in report["endpoints"]) and code == (0 if report["ok"] else 1)


@pytest.mark.slow
def test_unplugged_devices_are_named_with_what_to_do(tmp_path, capsys):
    cell_port, camera_port = _closed_port(), _closed_port()
    path = rig_settings(tmp_path, {
        "load_cell.backend": "tcp", "load_cell.address": f"tcp://127.0.0.1:{cell_port}",
        "sensors.left.camera_backend": "opencv", "sensors.left.camera_source": f"http://127.0.0.1:{camera_port}/",
        "sensors.right.camera_backend": "opencv",  # and no source at all
    })
    code, report = _doctor(capsys, "--settings", str(path))
    devices = {d["name"]: d for d in report["devices"]}
    assert code == 1 and not report["ok"]
    assert not devices["load cell"]["ok"] and devices["load cell"]["rate_hz"] is None
    assert f"127.0.0.1:{cell_port}" in devices["load cell"]["problem"]
    assert devices["load cell"]["problem"].endswith("check the bridge runs (`teleop hx711-bridge`) and "
                                                    "`load_cell.address`")
    assert not devices["camera left"]["ok"]
    assert f"http://127.0.0.1:{camera_port}/" in devices["camera left"]["problem"]
    assert "`camera_source` in [sensors.left]" in devices["camera left"]["problem"]
    assert "no source (set camera_source" in devices["camera right"]["problem"]
    assert all(devices[name]["ok"] for name in ("gripper", "display"))


@pytest.mark.slow  # a whole doctor run each
@pytest.mark.parametrize("name", ["gamepad", "sim"])
def test_the_operators_input_device_is_opened_and_read(tmp_path, capsys, name):
    absent = tmp_path / "no-such-event"  # a gamepad that is not plugged in
    path = rig_settings(tmp_path, {"operator.input": name, "operator.gamepad_path": str(absent)})
    code, report = _doctor(capsys, "--settings", str(path))
    device = next(d for d in report["devices"] if d["name"] == f"input {name}")
    if name == "sim":
        assert device["ok"] and device["problem"] is None
        # read as often as the console reads it, not in a spin that starves the other devices' reads
        assert device["detail"]["readings"] <= FOLLOW_RATE_HZ * 1.0 + 1
    else:  # named, with what to do
        assert code == 1 and not device["ok"] and f"cannot open gamepad {absent}" in device["problem"]
        assert device["problem"].endswith("name another in `[operator] input` (or pass `haptics operate --input`)")


def _judged(lags_s: list[float], *, read_hz: float = 50.0, stamps: list[float] | None = None) -> Check:
    """A device configured at 50 Hz, read at ``read_hz`` on this host's clock (or stamped ``stamps``),
    whose readings reached this process ``lags_s`` late."""
    now = time.monotonic()
    stamps = stamps or [now + i / read_hz for i in range(len(lags_s))]
    probe = _Probe("load cell", object(), list, 50.0, "the cell", "check it")
    return _judge(probe, stamps, lags_s, len(lags_s) / read_hz)


def test_a_stalled_read_is_not_taken_for_a_device_on_another_clock():
    check = _judged([0.001] * 30 + [1.6] + [0.001] * 30)  # this process stalled 1.6 s once (a loaded host)
    assert check.ok and check.detail["host_clock"] and check.problem is None


@pytest.mark.parametrize("offset_s", [5.0, -3.0])  # stamped in the past, or in the future, every time
def test_a_device_stamping_on_another_clock_is_named(offset_s):
    check = _judged([offset_s + 0.001 * (i % 3) for i in range(40)])
    assert not check.ok and not check.detail["host_clock"]
    assert f"timestamps are {offset_s:+.3g} s from this host's monotonic clock" in check.problem


def test_a_device_reading_under_80_percent_of_its_configured_rate_is_not_ready():
    check = _judged([0.001] * 31, read_hz=30.0)
    assert not check.ok and check.rate_hz == pytest.approx(30.0)
    assert "reads at 30 Hz, configured 50 Hz" in check.problem
    assert _judged([0.001] * 46, read_hz=45.0).ok  # 90 %: within the tolerance


def test_timestamps_going_backwards_are_not_ready():
    # at rate and on this host's clock, but one reading restamped earlier than the one before it
    now = time.monotonic()
    stamps = [now + 0.02 * i for i in range(51)]
    stamps[20], stamps[21] = stamps[21], stamps[20]
    check = _judged([0.001] * 51, stamps=stamps)
    assert not check.ok and not check.detail["monotonic"]
    assert "timestamps go backwards" in check.problem


def test_a_display_reporting_a_fault_is_not_ready():
    settings = load_settings(default_settings_path())
    probe = _display_probe(settings, "check [display] backend")
    probe.device.firmware.inject_fault("over_temperature")  # it answers, with a fault bit set
    check = _run_probe(probe, 0.3)
    assert not check.ok
    assert "reports faults ['over_temperature']" in check.problem and "power-cycle it" in check.problem


def _playback_of_frames(height_px: int, width_px: int) -> GraspPlayback:
    """A second of blank ``width_px`` x ``height_px`` frames per finger at 30 Hz, replayed from now
    (a simulated grasp takes seconds to make)."""
    t = np.arange(0.0, 1.0, 1 / 30)
    frames = np.zeros((t.size, height_px, width_px, 3), np.uint8)
    fingers = ("left", "right")
    record = GraspRecord(
        sensors=tuple(SensorSettings(finger=f) for f in fingers),
        frames=tuple(FrameStream.from_frames(f, t, frames, encoding="jpeg", jpeg_quality=80) for f in fingers),
        force_n=Samples(t, np.zeros(t.size)),
        width_m=Samples(t, np.full(t.size, 0.05)),
        provenance=Provenance(source="simulated", seed=0, model="synthetic-test"),
    )
    playback = GraspPlayback(record)
    playback.start()
    return playback


def test_a_camera_whose_frames_are_not_the_configured_size_is_not_ready():
    settings = load_settings(default_settings_path())
    sensor = settings.sensor("left")
    assert (sensor.raw_width_px, sensor.raw_height_px) == (640, 480)
    check = _run_probe(_camera_probe(settings, sensor, _playback_of_frames(48, 64)), 0.3)
    assert not check.ok  # at rate, but not the size [sensors.left] says
    assert "frames are 64x48 px, the settings say 640x480: set raw_width_px / raw_height_px" in check.problem


@pytest.mark.slow
def test_a_silent_serial_cell_says_no_data_and_the_table_says_not_ready(tmp_path, capsys):
    master, slave = os.openpty()
    tty.setraw(slave)
    port = os.ttyname(slave)
    try:
        path = rig_settings(tmp_path, {"load_cell.backend": "serial", "load_cell.port": port})
        code = main(["doctor", "--settings", str(path), "--duration-s", "1"])
    finally:
        os.close(master)
        os.close(slave)
    table = capsys.readouterr().out
    assert code == 1 and "NOT ready" in table
    line = next(ln for ln in table.splitlines() if ln.startswith("load cell"))
    assert f"no data from {port} within 1 s: check the cable and `load_cell.port`" in line


@pytest.mark.slow
def test_a_serial_cell_sending_garbage_is_not_told_to_check_its_cable(tmp_path, capsys):
    master, slave = os.openpty()
    tty.setraw(slave)
    port = os.ttyname(slave)
    done = threading.Event()

    def babble():  # what a wrong baud rate or another sketch looks like
        while not done.wait(0.02):
            os.write(master, b"HX711 ready?\n")

    sender = threading.Thread(target=babble, daemon=True)
    sender.start()
    try:
        path = rig_settings(tmp_path, {"load_cell.backend": "serial", "load_cell.port": port})
        code = main(["doctor", "--settings", str(path), "--duration-s", "1"])
    finally:
        done.set()
        sender.join()
        os.close(master)
        os.close(slave)
    line = next(ln for ln in capsys.readouterr().out.splitlines() if ln.startswith("load cell"))
    assert code == 1 and f"no valid reading from {port} within 1 s" in line and "unreadable skipped" in line
    assert "`load_cell.baud`" in line and "cable" not in line


@pytest.mark.slow
def test_a_serial_cell_without_pyserial_is_a_no_row_naming_the_extra(tmp_path, capsys, monkeypatch):
    monkeypatch.setitem(sys.modules, "serial", None)  # `import serial` raises ImportError, as when not installed
    path = rig_settings(tmp_path, {"load_cell.backend": "serial", "load_cell.port": "/dev/ttyUSB9"})
    code, report = _doctor(capsys, "--settings", str(path))
    cell = next(d for d in report["devices"] if d["name"] == "load cell")
    assert code == 1 and not cell["ok"]
    assert cell["problem"].startswith("cannot be set up: load cell backend 'serial' cannot be loaded")
    assert cell["problem"].endswith("(install the 'robot' extra)")


def test_a_port_in_use_and_an_unknown_unkeyed_host_are_problems():
    holder = socket.create_server(("127.0.0.1", 0))
    try:
        port = holder.getsockname()[1]
        settings = load_settings(default_settings_path())
        bus = settings.bus.__class__(robot_pub=f"tcp://127.0.0.1:{port}", estimate_pub="tcp://no-such-host.invalid:5551")
        checks = {c.name: c for c in check_endpoints(settings.__class__(bus=bus))}
    finally:
        holder.close()
    assert not checks["robot_pub"].ok and f"port {port} on 127.0.0.1 is in use" in checks["robot_pub"].problem
    assert "`bus.robot_pub`" in checks["robot_pub"].problem
    assert not checks["estimate_pub"].ok
    assert "host 'no-such-host.invalid' does not resolve" in checks["estimate_pub"].problem
    keys = checks["bus keys"]
    assert not keys.ok and "'tcp://no-such-host.invalid:5551' is reachable from other hosts" in keys.problem
    assert keys.problem.count("teleop keys") == 1 and keys.problem.endswith("set bus.keys_dir = DIR in the settings TOML")
    assert checks["command"].ok


def test_every_endpoint_off_loopback_needs_keys_and_any_free_port_is_not_probed():
    # the processes that bind display_pub and control refuse them without keys, so the doctor does too
    bus = BusSettings(display_pub="tcp://*:5553", control="tcp://127.0.0.1:*")
    checks = {c.name: c for c in check_endpoints(Settings(bus=bus))}
    assert not checks["bus keys"].ok and "'tcp://*:5553' is reachable from other hosts" in checks["bus keys"].problem
    assert checks["control"].ok and not checks["control"].detail["probed"]


REMOTE = "tcp://192.0.2.1:5550"  # TEST-NET-1: never an address of this host, so binding it fails (not "in use")


def _remote_check(monkeypatch, outcome: BaseException | None) -> Check:
    """The check of ``REMOTE``, whose host answers a connection (None) or raises ``outcome``."""
    def connect(address, timeout=None):
        assert address == ("192.0.2.1", 5550)
        if outcome is not None:
            raise outcome
        return socket.socket()

    monkeypatch.setattr(socket, "create_connection", connect)
    return {c.name: c for c in check_endpoints(Settings(bus=BusSettings(robot_pub=REMOTE)))}["robot_pub"]


@pytest.mark.parametrize("outcome", [None, ConnectionRefusedError(errno.ECONNREFUSED, "Connection refused")])
def test_an_endpoint_on_another_host_that_answers_or_refuses_is_ready(monkeypatch, outcome):
    # a refusal counts: nothing need listen there before the session starts
    check = _remote_check(monkeypatch, outcome)
    assert check.ok and check.problem is None
    assert check.detail["here"] is False and check.detail["probed"] is True


def test_an_endpoint_on_another_host_that_does_not_answer_is_not_ready(monkeypatch):
    check = _remote_check(monkeypatch, TimeoutError(errno.ETIMEDOUT, "timed out"))
    assert not check.ok
    assert check.problem == ("192.0.2.1:5550 does not answer (timed out): check the network, that host, "
                             "and `bus.robot_pub`")


def _keys_line(keys_dir) -> Check:
    checks = {c.name: c for c in check_endpoints(Settings(bus=BusSettings(keys_dir=str(keys_dir))))}
    return checks["bus keys"]


def test_bus_keys_that_serve_this_hosts_endpoints_say_their_role_and_clients(tmp_path):
    init_keys(tmp_path / "keys")
    keys = _keys_line(tmp_path / "keys")
    assert keys.ok and keys.problem is None
    assert (keys.detail["role"], keys.detail["authorized_clients"]) == ("server and client", 1)
    assert keys.detail["note"] == "server and client; 1 authorised client(s)"


def test_bus_keys_no_server_would_start_with_are_not_ready(tmp_path):
    # what `teleop node` refuses (or, before, started with and then admitted no one) is a NO here
    init_keys(tmp_path / "keys")
    init_keys(tmp_path / "intruder", server_cert=tmp_path / "keys" / "server.key")
    keys = _keys_line(tmp_path / "intruder")
    assert not keys.ok and "holds no server.key_secret: this node can connect but not bind" in keys.problem
    junk = tmp_path / "keys" / "authorized" / "junk.key"
    junk.write_text("garbage\n")
    keys = _keys_line(tmp_path / "keys")
    assert not keys.ok and f"cannot read CURVE certificate {junk}" in keys.problem
    assert "teleop keys add" in keys.problem
    junk.unlink()
    (tmp_path / "keys" / "authorized" / "client.key").unlink()
    keys = _keys_line(tmp_path / "keys")
    assert not keys.ok and "holds no client keys: no client can connect" in keys.problem
    assert keys.detail["authorized_clients"] == 0


@pytest.mark.parametrize(
    ("endpoint", "expected"),
    [
        ("tcp://127.0.0.1", "no port"),
        ("tcp://127.0.0.1:abc", "port 'abc'"),
        ("tcp://127.0.0.1:99999", "port '99999'"),
        ("127.0.0.1:5550", "not a ZeroMQ endpoint"),
    ],
)
def test_a_malformed_endpoint_is_an_error_naming_the_key_not_a_traceback(tmp_path, capsys, endpoint, expected):
    path = _edited(tmp_path, 'robot_pub = "tcp://127.0.0.1:5550"', f'robot_pub = "{endpoint}"')
    assert main(["doctor", "--settings", str(path)]) == 2
    err = capsys.readouterr().err
    assert f"teleop doctor: error: {path}: [bus] BusSettings.robot_pub = {endpoint!r}: {expected}" in err, err
    assert "Traceback" not in err and "teleop keys" not in err


def test_two_endpoints_one_address_is_an_error_naming_both_not_ready_for_a_session(tmp_path, capsys):
    path = _edited(tmp_path, 'estimate_pub = "tcp://127.0.0.1:5551"', 'estimate_pub = "tcp://127.0.0.1:5550"')
    assert main(["doctor", "--settings", str(path)]) == 2
    captured = capsys.readouterr()
    assert "ready for a session" not in captured.out
    assert "BusSettings.estimate_pub = 'tcp://127.0.0.1:5550': the same endpoint as robot_pub" in captured.err


@pytest.mark.parametrize("duration", ["0.05", "1e-9", "0.29"])
def test_a_read_too_short_to_show_the_configured_rates_is_refused_saying_the_minimum(capsys, duration):
    # 0.05 s failed healthy devices ("reads at 0 Hz ... check [gripper] backend"); 1e-9 s failed them all.
    assert main(["doctor", f"--duration-s={duration}"]) == 2
    captured = capsys.readouterr()
    assert captured.out == ""  # nothing read, no report
    assert (f"--duration-s {float(duration):g}: too short to judge the devices' rates; expected at least 0.3 s, "
            "3 periods of the slowest configured device ([gripper] width_read_hz = 10 Hz)") in captured.err


def test_the_shortest_read_follows_the_slowest_configured_device(tmp_path, capsys):
    path = rig_settings(tmp_path, {"gripper.width_read_hz": 100.0})
    with pytest.raises(ComplianceTeleopError, match=r"duration_s = 0.05: .* at least 0.1 s, 3 periods of the "
                                                    r"slowest configured device \(\[sensors.left\] camera_hz = 30 Hz\)"):
        check_devices(load_settings(path), duration_s=0.05)


def test_the_shortest_read_said_is_one_that_is_accepted(tmp_path):
    path = rig_settings(tmp_path, {"gripper.width_read_hz": 7.0})  # 3 periods: 0.4286 s
    with pytest.raises(ComplianceTeleopError, match=r"at least 0.43 s") as caught:
        check_duration(load_settings(path), 0.4)
    said = float(re.search(r"at least ([0-9.]+) s", str(caught.value)).group(1))
    check_duration(load_settings(path), said)  # no error


@pytest.mark.parametrize("duration", [float("nan"), 0.05])
def test_the_function_refuses_a_read_time_that_is_not_a_number_or_too_short(duration):
    # scripts call check_devices() directly: a NaN is refused as the command line refuses it, not read for no time
    with pytest.raises(TeleopError, match="too short to judge the devices' rates"):
        check_duration(load_settings(default_settings_path()), duration)


@pytest.mark.parametrize("duration", ["0", "-1", "nan", "inf"])
def test_a_read_time_that_is_not_a_positive_number_is_refused(capsys, duration):
    with pytest.raises(SystemExit) as info:
        main(["doctor", f"--duration-s={duration}"])
    assert info.value.code == 2
    assert f"argument --duration-s: {duration!r}: expected a number > 0" in capsys.readouterr().err


def _calibrate_args(problem: str, monkeypatch) -> argparse.Namespace:
    """The command a problem says to run, parsed by the estimator's own command line (not run)."""
    import estimator.perception.calibrate_cli as calibrate_cli
    from estimator.cli import main as estimator_main

    command = shlex.split(problem.split("run `", 1)[1].split("`", 1)[0])
    assert command[:2] == ["estimator", "calibrate"]
    parsed = []
    monkeypatch.setattr(calibrate_cli, "run", parsed.append)
    assert estimator_main(command[1:]) == 0  # argparse exits 2 on a missing or unknown option
    return parsed[0]


def test_a_missing_calibration_is_a_problem_for_the_estimators_finger(tmp_path, monkeypatch):
    path = rig_settings(tmp_path, {"sensors.left.calibration": "calibration/absent.npz", "sensors.right.calibration": ""})
    checks = {c.name: c for c in check_calibrations(load_settings(path), path)}
    assert not checks["calibration left"].ok
    assert "absent.npz" in checks["calibration left"].problem
    args = _calibrate_args(checks["calibration left"].problem, monkeypatch)
    assert args.capture and args.settings == str(path) and args.finger == "left"
    assert args.out == str(tmp_path / "calibration" / "absent.npz")  # the file the settings name
    assert args.presses and args.ball_radius_mm > 0  # a folder to capture into; captured presses state no ball
    assert checks["calibration right"].ok and checks["calibration right"].problem is None  # nothing needs it


def test_no_calibration_at_all_suggests_one_beside_the_settings_and_where_to_name_it(tmp_path, monkeypatch):
    path = rig_settings(tmp_path, {"sensors.left.calibration": ""})
    check = {c.name: c for c in check_calibrations(load_settings(path), path)}["calibration left"]
    assert not check.ok and check.problem.startswith("none configured: ")  # the estimator's finger
    args = _calibrate_args(check.problem, monkeypatch)
    assert args.out == str(tmp_path / "calibration-left.npz")
    assert check.problem.endswith('then set calibration = "calibration-left.npz" in [sensors.left]')


def test_a_model_folder_without_its_metadata_is_named(tmp_path):
    model = tmp_path / "model"
    model.mkdir()
    (model / "model.onnx").write_bytes(b"not really")  # and no metadata.json
    path = rig_settings(tmp_path, {"estimator.model_path": str(model)})
    check = {c.name: c for c in check_calibrations(load_settings(path), path)}["model"]
    assert not check.ok
    assert check.problem == f"{model} lacks model.onnx or metadata.json: fix `estimator.model_path` or train one"
