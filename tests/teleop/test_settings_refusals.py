"""Settings that every check passed but a service then refused or the display could not show: refused
as the file loads, or warned of by `teleop settings` where a valid use remains."""

from __future__ import annotations

import argparse

import numpy as np
import pytest

from haptics.settings import display_settings
from teleop.bus.pubsub import Publisher
from teleop.errors import MessageRejected, SettingsError
from teleop.physics import WEBER_FRACTION
from teleop.settings import (
    BusSettings,
    GripperSettings,
    Settings,
    default_settings_path,
    load_settings,
    missing_calibrations,
)
from teleop.system import live_system
from teleop.system.settings_cli import run as settings_run

# The shipped settings, their calibrations named by absolute path: a copy elsewhere still finds them.
SHIPPED = default_settings_path().read_text(encoding="utf-8").replace(
    'calibration = "calibration/', f'calibration = "{default_settings_path().parent}/calibration/')


def shipped_with(tmp_path, table: str, line: str, *, without: str = ""):
    """A copy of the shipped settings with ``line`` added to ``[table]`` (and the line ``without``
    taken out)."""
    path = tmp_path / "settings.toml"
    text = SHIPPED.replace(f"{without}\n", "") if without else SHIPPED
    path.write_text(text.replace(f"[{table}]\n", f"[{table}]\n{line}\n", 1), encoding="utf-8")
    return path


def test_a_publisher_names_the_message_limit_its_message_is_over():
    with (Publisher("inproc://settings-oversize", lossless=False, max_bytes=1024) as publisher,
          pytest.raises(MessageRejected) as info):
        publisher.send("frame", t_capture_s=0.0, finger="left", grasp_id="g1", index=0, encoding="raw",
                       data=np.zeros((32, 32, 3), np.uint8))
    assert info.value.reason == "oversize"
    assert "at most 1024" in str(info.value) and "bus.max_message_bytes" in str(info.value)


@pytest.mark.parametrize(
    ("first", "second"),
    [
        ("tcp://127.0.0.1:5550", "tcp://localhost:5550"),
        ("tcp://127.0.0.1:5550", "tcp://LOCALHOST:5550"),
        ("tcp://127.0.0.1:5550", "tcp://0.0.0.0:5550"),
        ("tcp://10.0.0.2:5550", "tcp://*:5550"),
        ("tcp://[::1]:5550", "tcp://[::]:5550"),
    ],
)
def test_two_endpoints_on_one_socket_however_written_are_refused(first, second):
    with pytest.raises(SettingsError, match=r"BusSettings.estimate_pub = .*the same endpoint as robot_pub"):
        BusSettings(robot_pub=first, estimate_pub=second)


def test_one_port_on_different_hosts_or_any_free_port_is_no_clash():
    BusSettings(robot_pub="tcp://127.0.0.1:5550", estimate_pub="tcp://127.0.0.2:5550")
    BusSettings(robot_pub="tcp://*:*", estimate_pub="tcp://127.0.0.1:*", command="ipc:///tmp/a:5550")


def test_through_a_link_relative_paths_resolve_against_the_linked_files_folder(tmp_path, capsys):
    link = tmp_path / "link" / "settings.toml"
    link.parent.mkdir()
    link.symlink_to(default_settings_path())
    settings = load_settings(link)
    shipped = load_settings()
    assert settings.sensor("left").calibration == shipped.sensor("left").calibration
    assert settings.folder == default_settings_path().parent
    assert missing_calibrations(settings, link) == []
    assert settings_run(argparse.Namespace(path=str(link), settings=None)) == 0
    assert "warning" not in capsys.readouterr().err


def test_no_calibration_on_the_estimating_finger_is_warned_of(tmp_path):
    empty = tmp_path / "settings.toml"
    empty.write_text("", encoding="utf-8")
    warnings = missing_calibrations(load_settings(empty), empty)
    assert warnings == ["[sensors.left] calibration: none named, and [sensing] finger = 'left' estimates; make "
                        "one with `estimator calibrate` and name it there"]
    assert missing_calibrations(load_settings()) == []  # the shipped file names both


def test_a_grasp_is_given_its_closing_and_its_hold():
    # the shipped gripper closes and holds well within the least timeout
    assert live_system.grasp_timeout_s(Settings()) == live_system.GRASP_TIMEOUT_S
    slow = Settings(gripper=GripperSettings(hold_s=60.0))
    closing_s = slow.gripper.max_width_m / slow.gripper.closing_speed_m_s
    assert live_system.grasp_timeout_s(slow) > closing_s + 60.0


def test_a_display_range_of_under_two_just_noticeable_steps_is_refused_naming_both_keys(tmp_path):
    with pytest.raises(SettingsError) as info:
        display_settings(load_settings(shipped_with(tmp_path, "display", "e_rigid_pa = 5000.000000001")))
    message = str(info.value)
    assert "e_rigid_pa = 5000.000000001" in message and "e_soft_pa = 5000.0" in message, message
    assert "2 just-noticeable steps" in message
    wide_enough = 5e3 * (1 + WEBER_FRACTION) ** 2 * 1.001
    path = shipped_with(tmp_path, "display", f"e_rigid_pa = {wide_enough!r}")
    assert display_settings(load_settings(path)).e_rigid_pa == wide_enough


def test_an_endpoint_other_hosts_reach_without_keys_is_warned_of_not_refused(tmp_path, capsys):
    # Refused where a process opens it; a command line may give loopback endpoints in its place.
    path = shipped_with(tmp_path, "bus", 'robot_pub = "tcp://0.0.0.0:5550"', without='robot_pub = "tcp://127.0.0.1:5550"')
    assert load_settings(path).bus.robot_pub == "tcp://0.0.0.0:5550"
    assert settings_run(argparse.Namespace(path=str(path), settings=None)) == 0
    err = capsys.readouterr().err
    assert "teleop settings: warning: [bus] bus endpoint 'tcp://0.0.0.0:5550' is reachable from other hosts" in err
    assert "keys" in err
    keyed = shipped_with(tmp_path, "bus", 'keys_dir = "keys"\nrobot_pub = "tcp://0.0.0.0:5550"',
                         without='robot_pub = "tcp://127.0.0.1:5550"')
    assert settings_run(argparse.Namespace(path=str(keyed), settings=None)) == 0
    assert "reachable from other hosts" not in capsys.readouterr().err


def test_a_rigid_end_past_the_sensors_resolution_limit_is_warned_of_not_refused(tmp_path, capsys):
    # No estimate goes past the limit: nothing would feel rigid. Logs recorded with one must still read.
    path = shipped_with(tmp_path, "display", "e_rigid_pa = 1.0e9")
    assert display_settings(load_settings(path)).e_rigid_pa == 1e9
    assert settings_run(argparse.Namespace(path=str(path), settings=None)) == 0
    assert "warning: [display] e_rigid_pa = 1e+09 Pa is above the sensor's resolution limit" in capsys.readouterr().err
    at_limit = shipped_with(tmp_path, "display", f"e_rigid_pa = {load_settings().resolution_limit_pa:.4g}")
    assert settings_run(argparse.Namespace(path=str(at_limit), settings=None)) == 0
    assert "resolution limit" not in capsys.readouterr().err
