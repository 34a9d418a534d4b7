"""``teleop doctor`` (teleop.system.doctor) at the edges its other tests leave: each device's advice and
where it is read, the probes' reads, the verdict on readings, the bus checks and the calibration ages."""

from __future__ import annotations

import dataclasses
import json
import math
import socket
import time

import pytest
from support.rig_settings import rig_settings

from teleop.devices.camera import opencv_fix
from teleop.devices.gripper import FRANKY_FIX
from teleop.devices.loadcell import FIXES as LOAD_CELL_FIXES
from teleop.errors import DeviceStalledError, DeviceTimeoutError, TeleopError
from teleop.operator import FOLLOW_RATE_HZ
from teleop.settings import BusSettings, Settings, default_settings_path, load_settings
from teleop.system import doctor
from teleop.system.doctor import Check, _judge, _Probe, _run_probe

SHIPPED = default_settings_path()


def _probes(monkeypatch, settings) -> dict:
    """The probes of ``settings`` by name, built (nothing opened) without simulating a grasp."""
    monkeypatch.setattr(doctor, "_simulated_playback", lambda settings: None)
    return {p.name: p for p in doctor._probes(settings)}


def _hardware(tmp_path):
    return load_settings(rig_settings(tmp_path, {
        "gripper.backend": "franky", "gripper.host": "10.0.0.9", "display.backend": "hid",
        "load_cell.backend": "tcp", "load_cell.address": "tcp://10.0.0.8:5000",
        "sensors.left.camera_backend": "opencv", "sensors.left.camera_source": "http://10.0.0.7/",
        "operator.input": "gamepad"}))


# --------------------------------------------------------------------------- what each device's line advises


def test_hardware_devices_are_advised_by_their_own_backends_fix(tmp_path, monkeypatch):
    probes = _probes(monkeypatch, _hardware(tmp_path))
    assert probes["gripper"].fix == FRANKY_FIX and probes["gripper"].where == "10.0.0.9"
    assert probes["load cell"].fix == LOAD_CELL_FIXES["tcp"] and probes["load cell"].where == "tcp://10.0.0.8:5000"
    assert probes["camera left"].fix == opencv_fix("left") and probes["camera left"].where == "http://10.0.0.7/"
    assert probes["camera right"].fix == "check [sensors]"  # still simulated
    assert "`display.vendor_id` / `display.product_id`" in probes["display"].fix
    assert probes["input gamepad"].fix.startswith("to drive without it, name another in `[operator] input`")


def test_simulated_devices_are_advised_to_check_their_settings_section(tmp_path, monkeypatch):
    probes = _probes(monkeypatch, load_settings(rig_settings(tmp_path, {"operator.input": "sim"})))
    assert probes["gripper"].fix == "check [gripper] backend" and probes["gripper"].where == "the simulated gripper"
    assert probes["load cell"].fix == "check [load_cell]" and probes["load cell"].where == "the simulated cell"
    assert probes["camera left"].fix == "check [sensors]" and probes["display"].fix == "check [display] backend"
    assert probes["input sim"].fix == "check [operator]"


def test_the_keyboard_is_not_opened_and_a_configured_input_device_is(tmp_path, monkeypatch):
    keyboard = _probes(monkeypatch, load_settings(SHIPPED))["input keyboard"]
    assert isinstance(keyboard, Check) and keyboard.ok and "nothing to open" in keyboard.detail["note"]
    sim = _probes(monkeypatch, load_settings(rig_settings(tmp_path, {"operator.input": "sim"})))["input sim"]
    assert isinstance(sim, _Probe) and sim.expected_hz is None


def test_the_input_device_is_read_at_the_consoles_rate_not_in_a_spin(tmp_path, monkeypatch):
    probe = doctor._input_probe(load_settings(rig_settings(tmp_path, {"operator.input": "sim"})))
    slept = []
    monkeypatch.setattr(doctor.time, "sleep", slept.append)
    probe.device.connect()
    try:
        assert len(probe.read()) == 1
    finally:
        probe.device.close()
    assert slept == [1.0 / FOLLOW_RATE_HZ]


def test_every_rated_device_is_judged_against_its_configured_rate(monkeypatch):
    settings = load_settings(SHIPPED)
    probes = _probes(monkeypatch, settings)
    assert probes["gripper"].expected_hz == settings.gripper.width_read_hz
    assert probes["load cell"].expected_hz == settings.load_cell.sample_rate_hz
    assert probes["camera left"].expected_hz == settings.sensor("left").camera_hz
    assert probes["display"].expected_hz is None


# --------------------------------------------------------------------------- the probes' reads


def test_a_camera_read_that_times_out_is_no_reading_not_an_error(monkeypatch):
    settings = load_settings(SHIPPED)
    probe = doctor._camera_probe(settings, settings.sensor("left"), None)

    def silent(timeout_s):
        raise DeviceTimeoutError("no frame")

    monkeypatch.setattr(probe.device, "read", silent)
    assert probe.read() == []


@pytest.mark.parametrize("error", [DeviceTimeoutError, DeviceStalledError])
def test_a_load_cell_read_that_times_out_or_stalls_is_no_reading_not_an_error(monkeypatch, error):
    settings = load_settings(SHIPPED)
    probe = doctor._load_cell_probe(settings, None, "check it")

    def silent(timeout_s):
        raise error("nothing")

    monkeypatch.setattr(probe.device, "read", silent)
    assert probe.read() == []


def test_the_display_is_probed_with_a_free_command_and_a_silent_one_gives_no_reading(monkeypatch):
    monkeypatch.setattr(doctor.time, "sleep", lambda s: None)
    probe = doctor._display_probe(load_settings(SHIPPED), "check [display] backend")
    probe.device.connect()
    try:
        assert len(probe.read()) == 1
        command = probe.device.rendered_command
        assert command.level == 0 and not command.rigid  # safe with a hand on the handle
        monkeypatch.setattr(probe.device, "read_status", lambda timeout_s: None)
        assert probe.read() == []
    finally:
        probe.device.close()


def test_a_long_display_keepalive_does_not_hold_the_read_past_its_slice(monkeypatch, tmp_path):
    import shutil

    from teleop.settings_edit import update_settings_file

    path = tmp_path / "settings.toml"
    shutil.copy(SHIPPED, path)
    update_settings_file(path, {"display.keepalive_s": 60.0})
    slept = []
    monkeypatch.setattr(doctor.time, "sleep", slept.append)
    probe = doctor._display_probe(load_settings(path), "check [display] backend")
    probe.device.connect()
    try:
        assert len(probe.read()) == 1 and slept == [doctor.READ_SLICE_S]
    finally:
        probe.device.close()


def test_the_simulated_grasp_is_started_so_that_its_first_reading_is_due_now(monkeypatch):
    import numpy as np

    import teleop.sim.grasp
    from teleop.record import GraspRecord, Provenance, Samples
    from teleop.settings import SensorSettings

    # The fingers start closing 1.5 s after the grasp command: started at the command, the devices
    # would be silent for the first 1.5 s of their read.
    t = np.arange(1.5, 3.0, 0.1)
    record = GraspRecord(sensors=tuple(SensorSettings(finger=f) for f in ("left", "right")), frames=(),
                         force_n=Samples(t, np.zeros(t.size)), width_m=Samples(t, np.full(t.size, 0.05)),
                         provenance=Provenance(source="simulated", seed=0, model="synthetic-test"),
                         events={"command_grasp": 0.0})
    monkeypatch.setattr(teleop.sim.grasp, "simulate_grasp", lambda *args, **kwargs: (record,))
    before = time.monotonic()
    playback = doctor._simulated_playback(load_settings(SHIPPED))
    assert before <= playback.live_time(1.5) <= time.monotonic()


# --------------------------------------------------------------------------- the verdict on readings


def _probe(expected_hz: float | None = 50.0, inspect=None) -> _Probe:
    return _Probe("load cell", object(), list, expected_hz, "the cell", "check it", inspect)


def test_readings_all_stamped_at_one_instant_read_at_no_rate_not_a_division_by_zero():
    check = _judge(_probe(), [5.0, 5.0, 5.0], [0.001] * 3, 1.0)
    assert not check.ok and check.rate_hz is None and "reads at 0 Hz, configured 50 Hz" in check.problem


def test_a_single_reading_of_a_rated_device_reads_at_no_rate():
    check = _judge(_probe(), [5.0], [0.001], 1.0)
    assert not check.ok and check.rate_hz is None and "reads at 0 Hz" in check.problem


def test_a_device_without_a_configured_rate_shows_none():
    check = _judge(_probe(None), [i / 5 for i in range(10)], [0.001] * 10, 2.0)
    assert check.ok and check.rate_hz is None and check.problem is None


def test_a_device_at_exactly_80_percent_of_its_rate_is_ready():
    check = _judge(_probe(), [i / 40 for i in range(41)], [0.001] * 41, 1.0)
    assert check.rate_hz == 40.0 and check.ok, check.problem


def test_the_latency_is_the_median_of_the_reads():
    check = _judge(_probe(None), [0.0, 0.1, 0.2, 0.3, 0.4], [0.5, 0.002, 0.002, 0.002, 0.9], 1.0)
    assert check.latency_ms == pytest.approx(2.0)


def test_readings_sharing_a_timestamp_do_not_go_backwards():
    check = _judge(_probe(), [i // 2 / 25 for i in range(52)], [0.001] * 52, 1.0)
    assert check.detail["monotonic"] and check.problem is None


class _Device:
    """A device that opens (or raises ``opening``) and records whether it was closed."""

    def __init__(self, opening: Exception | None = None):
        self.opening, self.closed = opening, False

    def connect(self):
        if self.opening is not None:
            raise self.opening

    def close(self):
        self.closed = True


def test_the_latency_is_that_of_the_newest_reading_of_a_read_and_every_reading_counts():
    reads = []

    def read():  # three readings a read, the oldest 10 s before the newest
        now = time.monotonic()
        reads.append(now)
        return [now - 10.0, now - 5.0, now]

    device = _Device()
    check = _run_probe(_Probe("gripper", device, read, None, "the gripper", "check it"), 0.05)
    assert check.latency_ms < 5000 and check.detail["readings"] == 3 * len(reads)
    assert device.closed


def test_a_device_failing_while_read_is_not_ready_and_is_closed():
    def read():
        raise TeleopError("the link dropped")

    device = _Device()
    check = _run_probe(_Probe("gripper", device, read, 10.0, "the gripper", "check it"), 0.05)
    assert not check.ok and check.problem == "failed while read: the link dropped: check it"
    assert device.closed


@pytest.mark.parametrize(("error", "problem"), [
    ("no answer: check it", "cannot open: no answer: check it"),  # the device's own error says what to do
    ("no answer", "cannot open: no answer: check it"),
])
def test_a_device_that_does_not_open_says_what_to_do_once(error, problem):
    check = _run_probe(_Probe("gripper", _Device(TeleopError(error)), list, 10.0, "the gripper", "check it"), 0.05)
    assert not check.ok and check.problem == problem


class _BrokenClose(_Device):
    def close(self):
        raise OSError(5, "Input/output error")


def test_a_drivers_own_error_is_that_devices_problem_and_its_close_failing_only_a_log_line(caplog):
    opening = _run_probe(_Probe("display", _Device(OSError(19, "No such device")), list, 10.0, "the display", "plug it"),
                         0.05)
    assert not opening.ok and opening.problem == "cannot open: OSError: [Errno 19] No such device: plug it"

    def read():
        raise ValueError("report of 3 bytes")

    device = _Device()
    reading = _run_probe(_Probe("display", device, read, 10.0, "the display", "plug it"), 0.05)
    assert reading.problem == "failed while read: ValueError: report of 3 bytes: plug it" and device.closed
    fine = _run_probe(_Probe("gripper", _BrokenClose(), lambda: [time.monotonic()], None, "the gripper", "fix"), 0.05)
    assert fine.ok and "gripper: closing it failed: OSError: [Errno 5] Input/output error" in caplog.text


# --------------------------------------------------------------------------- the bus


def _free_port() -> int:
    probe = socket.create_server(("127.0.0.1", 0))
    port = probe.getsockname()[1]
    probe.close()
    return port


def _endpoint(endpoint: str) -> Check:
    return doctor._endpoint_check("robot_pub", endpoint)


def test_a_free_port_on_every_interface_is_ready_and_bound_here():
    check = _endpoint(f"tcp://*:{_free_port()}")
    assert check.ok and check.detail["here"] and check.detail["probed"]


def test_a_free_ipv6_loopback_port_is_ready():
    try:
        with socket.create_server(("::1", 0), family=socket.AF_INET6) as held:
            port = held.getsockname()[1]
    except OSError:
        pytest.skip("no IPv6 loopback here")
    check = _endpoint(f"tcp://[::1]:{port}")
    assert check.ok and check.detail["here"], check.problem


def test_a_port_whose_last_connection_is_in_time_wait_is_free_for_the_session():
    server = socket.create_server(("127.0.0.1", 0))
    port = server.getsockname()[1]
    client = socket.create_connection(("127.0.0.1", port))
    accepted, _ = server.accept()
    accepted.close()  # the server's end closes first: its port waits in TIME_WAIT
    client.close()
    server.close()
    check = _endpoint(f"tcp://127.0.0.1:{port}")
    assert check.ok, check.problem


def test_a_host_that_does_not_resolve_is_not_taken_for_this_one():
    check = _endpoint("tcp://no-such-host.invalid:5550")
    assert not check.ok and check.detail["here"] is False


def test_an_endpoint_on_another_host_is_tried_for_a_bounded_time(monkeypatch):
    timeouts = []

    def connect(address, timeout=None):
        timeouts.append(timeout)
        raise ConnectionRefusedError

    monkeypatch.setattr(socket, "create_connection", connect)
    assert _endpoint("tcp://192.0.2.1:5550").ok
    assert timeouts and timeouts[0] is not None and 0 < timeouts[0] <= 5.0


# --------------------------------------------------------------------------- calibrations and the model


def _model_age(tmp_path, metadata) -> Check:
    model = tmp_path / "model"
    model.mkdir()
    (model / "model.onnx").write_bytes(b"")
    (model / "metadata.json").write_text(json.dumps(metadata))
    path = rig_settings(tmp_path, {"estimator.model_path": str(model)})
    return {c.name: c for c in doctor.check_calibrations(load_settings(path), path)}["model"]


@pytest.mark.parametrize(("created", "days"), [
    ("{days_ago}+05:00", 10.0),  # an offset other than UTC's
    ("{days_ago_1_5}", 1.5),  # a day and a half: ages are to a tenth of a day
])
def test_a_models_age_reads_the_stamps_offset_and_keeps_a_tenth_of_a_day(tmp_path, created, days):
    from datetime import UTC, datetime, timedelta

    now = datetime.now(UTC)
    stamps = {"days_ago": (now + timedelta(hours=5) - timedelta(days=10)).replace(tzinfo=None).isoformat(),
              "days_ago_1_5": (now - timedelta(days=1.5)).isoformat()}
    check = _model_age(tmp_path, {"created_utc": created.format(**stamps)})
    assert check.ok and check.detail["age_days"] == pytest.approx(days, abs=0.05)


def test_a_stamp_without_an_offset_is_utc_whatever_the_hosts_time_zone(tmp_path, monkeypatch):
    from datetime import UTC, datetime, timedelta

    naive = (datetime.now(UTC) - timedelta(days=10)).replace(tzinfo=None).isoformat()
    monkeypatch.setenv("TZ", "Asia/Kolkata")  # UTC+05:30
    time.tzset()
    try:
        check = _model_age(tmp_path, {"created_utc": naive})
    finally:
        monkeypatch.undo()
        time.tzset()
    assert check.detail["age_days"] == pytest.approx(10.0, abs=0.05)


def test_a_stamp_seconds_ahead_is_age_zero_not_minus_zero(tmp_path):
    from datetime import UTC, datetime, timedelta

    soon = (datetime.now(UTC) + timedelta(seconds=20)).isoformat()
    age = _model_age(tmp_path, {"created_utc": soon}).detail["age_days"]
    assert age == 0.0 and math.copysign(1.0, age) == 1.0  # "-0 days old" in the table otherwise


def test_model_metadata_that_is_not_an_object_dates_the_model_by_its_file(tmp_path):
    check = _model_age(tmp_path, [1, 2])
    assert check.ok and check.detail["age_days"] == 0.0


def test_no_model_at_all_is_ready_on_the_analytical_fits(tmp_path, monkeypatch):
    import estimator.inference.infer as infer

    monkeypatch.setattr(infer, "default_model_dir", lambda: tmp_path / "no-model")
    path = rig_settings(tmp_path, {"estimator.model_path": ""})
    check = {c.name: c for c in doctor.check_calibrations(load_settings(path), path)}["model"]
    assert check.ok and check.detail == {"path": None, "note": "none: analytical fits only"}


def test_a_calibration_for_another_image_grid_is_not_ready(tmp_path):
    from teleop.settings import config_dir

    shipped = str(config_dir() / "calibration" / "sim-wedge-left.npz")
    path = rig_settings(tmp_path, {"sensors.left.crop_px": 30, "sensors.left.calibration": shipped})
    check = {c.name: c for c in doctor.check_calibrations(load_settings(path), path)}["calibration left"]
    assert not check.ok and "the calibration is for" in check.problem and "run `estimator calibrate" in check.problem


def test_a_model_stamped_past_the_last_representable_year_is_a_future_stamp_warning_not_a_crash(tmp_path):
    # 9999-12-31 23:59:59 at UTC-5 is in the year 10000 in UTC: the report's UTC text of it raised ValueError.
    check = _model_age(tmp_path, {"created_utc": "9999-12-31T23:59:59-05:00"})
    assert check.ok and "age_days" not in check.detail
    assert check.warning.startswith("stamped in the future (created_utc ") and "253402318799" in check.warning


def test_a_device_that_cannot_be_set_up_is_a_line_saying_why_and_the_others_are_still_probed(tmp_path, monkeypatch):
    settings = load_settings(rig_settings(tmp_path, {"sensors.right.camera_backend": "opencv"}))  # and no source
    probes = _probes(monkeypatch, settings)
    camera = probes["camera right"]
    assert isinstance(camera, Check) and not camera.ok and camera.problem.startswith("cannot be set up: ")
    assert "no source (set camera_source" in camera.problem
    assert isinstance(probes["camera left"], _Probe) and isinstance(probes["display"], _Probe)


# --------------------------------------------------------------------------- the report


def test_a_port_in_use_makes_the_whole_report_not_ready(monkeypatch):
    monkeypatch.setattr(doctor, "check_devices", lambda settings, duration_s: [Check("gripper", True)])
    monkeypatch.setattr(doctor, "check_calibrations", lambda settings, path: [Check("model", True)])
    with socket.create_server(("127.0.0.1", 0)) as held:
        bus = BusSettings(robot_pub=f"tcp://127.0.0.1:{held.getsockname()[1]}")
        monkeypatch.setattr(doctor, "load_settings", lambda path: Settings(bus=bus))
        report = doctor.diagnose(SHIPPED, duration_s=1.0)
    assert not report["ok"] and not report["endpoints"][0]["ok"]


def _row(check: Check, ok: bool = True) -> str:
    report = {"ok": ok, "devices": [dataclasses.asdict(check)], "endpoints": [], "calibrations": []}
    return doctor._table(report).splitlines()


def test_the_table_gives_a_rate_against_its_configuration_an_age_and_a_warning():
    line = _row(Check("camera left", True, 29.5, 12.0, detail={"expected_hz": 30.0}))[1]
    assert line.split()[2:6] == ["yes", "29.5", "/", "30"] and "12.0" in line
    assert _row(Check("model", True, detail={"age_days": 3.5}))[1].endswith("3.5 days old")
    lines = _row(Check("calibration left", True, detail={"age_days": 3.5}, warning="made for another sensor"))
    assert lines[1].split()[2] == "warn" and lines[1].endswith("made for another sensor")
    assert lines[-1] == "ready for a session; see the lines marked warn"
    assert _row(Check("gripper", False, problem="no data"), ok=False)[-1] == "NOT ready: fix the lines marked NO"


def test_a_device_that_sent_only_unreadable_lines_is_told_apart_from_a_silent_one():
    from collections import Counter

    babbling = type("Cell", (), {"skipped": Counter({"not a number": 3, "too long": 1})})()
    probe = _Probe("load cell", babbling, list, 80.0, "/dev/ttyUSB0", "check the cable")
    check = _judge(probe, [], [], 1.0)
    assert not check.ok and check.problem.startswith("no valid reading from /dev/ttyUSB0 within 1 s, 4 unreadable "
                                                     "skipped (not a number, too long)")
    silent = type("Cell", (), {"skipped": Counter({"not a number": 0})})()
    check = _judge(_Probe("load cell", silent, list, 80.0, "/dev/ttyUSB0", "check the cable"), [], [], 1.0)
    assert check.problem == "no data from /dev/ttyUSB0 within 1 s: check the cable"


def test_a_password_in_a_devices_problem_is_hidden_in_the_report(monkeypatch):
    problem = "cannot open: http://admin:Hunter2Pass@10.0.0.7/?action=stream"
    monkeypatch.setattr(doctor, "check_devices", lambda settings, duration_s: [Check("camera left", False, problem=problem)])
    monkeypatch.setattr(doctor, "check_endpoints", lambda settings: [])
    monkeypatch.setattr(doctor, "check_calibrations", lambda settings, path: [])
    report = doctor.diagnose(SHIPPED, duration_s=1.0)
    assert report["devices"][0]["problem"] == "cannot open: http://admin:***@10.0.0.7/?action=stream"


@pytest.mark.parametrize(("ok", "code"), [(True, 0), (False, 1)])
@pytest.mark.parametrize("as_json", [False, True])
def test_the_command_prints_the_table_or_the_json_and_exits_1_when_not_ready(monkeypatch, capsys, ok, code, as_json):
    import argparse

    report = {"ok": ok, "settings": str(SHIPPED), "devices": [dataclasses.asdict(Check("gripper", ok))],
              "endpoints": [], "calibrations": []}
    monkeypatch.setattr(doctor, "diagnose", lambda path, duration_s: report)
    args = argparse.Namespace(settings=str(SHIPPED), duration_s=1.0, json=as_json)
    assert doctor.run(args) == code
    out = capsys.readouterr().out
    if as_json:
        assert json.loads(out) == report
    else:
        assert out.splitlines()[-1] == ("ready for a session" if ok else "NOT ready: fix the lines marked NO")
