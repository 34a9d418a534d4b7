"""Settings: the shipped file, every class of bad input, and the mapping round trip."""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
from pathlib import Path

import pytest

from estimator.settings import estimator_settings
from haptics.settings import DisplaySettings, display_settings
from teleop.errors import SettingsError
from teleop.live import bus_from_args
from teleop.settings import (
    BusSettings,
    SensorSettings,
    Settings,
    config_dir,
    default_settings_path,
    load_settings,
    package_tables,
    resolve_path,
    settings_from_mapping,
    settings_to_mapping,
)


def write(tmp_path, text: str, name: str = "settings.toml"):
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    return path


def load_all(path) -> Settings:
    """Load ``path`` as the packages read it: the base's tables, then the estimator's and the display's."""
    settings = load_settings(path)
    estimator_settings(settings), display_settings(settings)
    return settings


def error_for(tmp_path, text: str) -> str:
    path = write(tmp_path, text)
    with pytest.raises(SettingsError) as info:
        load_all(path)
    message = str(info.value)
    assert str(path) in message, message  # every file error names the file
    return message


def test_shipped_settings_load_with_the_documented_values():
    settings = load_settings()
    assert settings == load_settings(default_settings_path())
    assert [s.finger for s in settings.sensors] == ["left", "right"]
    left, right = settings.sensor("left"), settings.sensor("right")
    assert (left.markers, right.markers) == (False, True)
    assert left.gel_modulus_pa == 275e3 and left.gel_poisson == 0.48
    assert left.image_shape == (250, 350)
    rows_m, cols_m = left.pad_size_m
    assert rows_m == pytest.approx(250 * 9.0909e-5) and cols_m == pytest.approx(350 * 9.0909e-5)
    assert left.gel_compliance_per_pa == pytest.approx((1 - 0.48**2) / 275e3)
    assert right.warp_corners_px[0] == (92.0, 103.0)
    assert settings.gripper.max_width_m == 0.08 and settings.load_cell.sample_rate_hz == 80.0
    assert display_settings(settings).vendor_id == 0x1209


def test_unknown_keys_are_named_with_the_allowed_ones(tmp_path):
    message = error_for(tmp_path, "[gripper]\nspeed = 0.01\n")
    assert "'speed'" in message and "[gripper]" in message and "closing_speed_m_s" in message
    message = error_for(tmp_path, "[camera]\nfps = 30\n")
    assert "'camera'" in message and "top level" in message
    message = error_for(tmp_path, "[sensors.left]\nmodulus = 1.0\n")
    assert "'modulus'" in message and "[sensors.left]" in message and "gel_modulus_pa" in message


def test_a_misspelt_table_is_named_with_every_allowed_table_the_packages_own_included(tmp_path):
    message = error_for(tmp_path, "[displya]\nbackend = 'sim'\n")
    allowed = message.split("allowed keys: ")[1].split(", ")
    assert "'displya'" in message and "top level" in message
    assert {"display", "estimator", "operator"} <= set(allowed) and set(package_tables()) <= set(allowed)
    assert {"bus", "gripper", "load_cell", "sensing", "sensors", "simulation"} <= set(allowed)
    assert allowed == sorted(allowed)


@pytest.mark.parametrize(
    ("endpoint", "expected"),
    [
        ("tcp://127.0.0.1", "no port: expected tcp://HOST:PORT"),
        ("tcp://127.0.0.1:abc", "port 'abc': expected an integer in 1..65535"),
        ("tcp://127.0.0.1:99999", "port '99999': expected an integer in 1..65535"),  # ZeroMQ would bind 34463
        ("tcp://127.0.0.1:0", "port '0'"),
        ("tcp://127.0.0.1:", "port ''"),
        ("tcp://:5550", "no host: expected tcp://HOST:PORT"),
        ("127.0.0.1:5550", "not a ZeroMQ endpoint: expected tcp://HOST:PORT, ipc://PATH or inproc://NAME"),
        ("tpc://127.0.0.1:5550", "not a ZeroMQ endpoint"),
        ("ws://127.0.0.1:5550/bus", "expected tcp://HOST:PORT, ipc://PATH or inproc://NAME"),
    ],
)
def test_a_malformed_bus_endpoint_is_refused_naming_the_key(tmp_path, endpoint, expected):
    message = error_for(tmp_path, f'[bus]\nestimate_pub = "{endpoint}"\n')
    assert f"[bus] BusSettings.estimate_pub = {endpoint!r}: {expected}" in message, message


@pytest.mark.parametrize(
    "endpoint",
    ["tcp://127.0.0.1:6000", "tcp://[::1]:6000", "tcp://robot.lab:6000", "tcp://*:6000", "tcp://127.0.0.1:*",
     "tcp://127.0.0.1;127.0.0.1:6000", "ipc:///tmp/teleop-robot", "inproc://robot"],
)
def test_the_endpoints_the_bus_binds_and_connects_load(endpoint):
    assert BusSettings(robot_pub=endpoint).robot_pub == endpoint


def test_a_command_line_endpoint_is_checked_as_the_files_are():
    settings = load_settings()
    args = argparse.Namespace(bus_robot_pub="tcp://127.0.0.1:99999")
    with pytest.raises(SettingsError, match=r"command-line endpoint: BusSettings.robot_pub = .*port '99999'"):
        bus_from_args(settings, args)


def test_two_endpoints_bound_by_different_processes_may_not_be_one(tmp_path):
    message = error_for(tmp_path, '[bus]\nrobot_pub = "tcp://127.0.0.1:6000"\nestimate_pub = "tcp://127.0.0.1:6000"\n')
    assert "[bus] BusSettings.estimate_pub = 'tcp://127.0.0.1:6000': the same endpoint as robot_pub" in message
    # however the port is written, and whatever the transport
    with pytest.raises(SettingsError, match="BusSettings.control = 'tcp://127.0.0.1:05552': the same endpoint as command"):
        BusSettings(control="tcp://127.0.0.1:05552")
    with pytest.raises(SettingsError, match="BusSettings.display_pub = 'ipc:///tmp/b': the same endpoint as command"):
        BusSettings(command="ipc:///tmp/b", display_pub="ipc:///tmp/b")
    # "*": each binds a free port of its own; one port on two hosts is two endpoints
    BusSettings(command="tcp://127.0.0.1:*", control="tcp://127.0.0.1:*")
    BusSettings(robot_pub="tcp://10.0.0.1:5550", estimate_pub="tcp://10.0.0.2:5550")


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ('[gripper]\nmax_width_m = "wide"\n', "gripper.max_width_m must be a number"),
        ("[gripper]\nmax_width_m = true\n", "gripper.max_width_m must be a number"),
        ("[load_cell]\nbaud = true\n", "load_cell.baud must be an integer"),
        ("[load_cell]\nbaud = 9600.5\n", "load_cell.baud must be an integer"),
        ("[sensors.left]\nmarkers = 1\n", "sensors.left.markers must be true or false"),
        ("[bus]\nrobot_pub = 5550\n", "bus.robot_pub must be a string"),
        ('[estimator]\nmethods = "hertz"\n', "estimator.methods must be an array"),
        ("[estimator]\nmethods = [1, 2]\n", "estimator.methods[0] must be a string"),
        ("gripper = 3\n", "[gripper] must be a table"),
    ],
)
def test_wrong_types_are_named(tmp_path, text, expected):
    assert expected in error_for(tmp_path, text)


def test_an_integer_too_large_for_a_number_is_refused_naming_the_key(tmp_path):
    message = error_for(tmp_path, "[gripper]\ntarget_force_n = 1" + "0" * 400 + "\n")
    assert "gripper.target_force_n is an integer too large for a number" in message
    # Past Python's 4300-digit limit the TOML reader itself refuses it.
    assert "not valid TOML" in error_for(tmp_path, "[gripper]\ntarget_force_n = 1" + "0" * 5000 + "\n")


@pytest.mark.parametrize(
    ("text", "key", "allowed"),
    [
        ("[sensors.right]\ngel_poisson = 0.7\n", "gel_poisson", "[0.0, 0.5]"),
        ("[gripper]\nclosing_speed_m_s = 0.0\n", "closing_speed_m_s", "(0.0, 0.2]"),
        ("[gripper]\ntarget_force_n = 500\n", "target_force_n", "(0.0, 140.0]"),
        ("[load_cell]\nsample_rate_hz = 20.0\n", "sample_rate_hz", "one of 10.0, 80.0"),
        ('[sensors.left]\nmodel = "gelsight9"\n', "model", "one of 'wedge', 'mini'"),
        ("[simulation]\ncamera_noise = inf\n", "camera_noise", "[0.0, 50.0]"),
        ("[simulation]\nforce_noise_n = nan\n", "force_noise_n", "[0.0, 10.0]"),
        ("[sensors.left]\nwarp_corners_px = [[0, 0], [1, 0], [0, 1], [1e5, 1]]\n", "warp_corners_px", "8192"),
    ],
)
def test_out_of_range_values_name_the_key_and_the_allowed_range(tmp_path, text, key, allowed):
    message = error_for(tmp_path, text)
    assert key in message and allowed in message, message


def test_out_of_range_sensor_value_names_the_finger(tmp_path):
    message = error_for(tmp_path, "[sensors.right]\ngel_poisson = 0.7\n")
    assert "[sensors.right]" in message


def test_array_lengths_are_checked(tmp_path):
    message = error_for(tmp_path, "[sensors.left]\nwarp_corners_px = [[0, 0], [1, 0], [0, 1]]\n")
    assert "warp_corners_px" in message and "exactly 4" in message
    message = error_for(tmp_path, "[sensors.left]\nwarp_corners_px = [[0, 0, 5], [1, 0], [0, 1], [1, 1]]\n")
    assert "sensors.left.warp_corners_px[0] must have 2 entries" in message


def test_cross_field_checks(tmp_path):
    message = error_for(tmp_path, "[sensors.left]\ncrop_px = 200\n")
    assert "crop_px" in message and "crops the whole" in message
    message = error_for(tmp_path, "[display]\ne_soft_pa = 2e9\ne_rigid_pa = 1e9\n")
    assert "e_rigid_pa" in message and "e_soft_pa" in message


def test_the_depth_binning_must_tile_the_estimator_fingers_grid(tmp_path):
    assert estimator_settings(load_settings()).depth_binning == 2
    # A 250 x 350 px grid from 640 x 480 frames: 3 and 4 leave remainders (5 would tile both).
    for binning in (3, 4):
        message = error_for(tmp_path, f"[estimator]\ndepth_binning = {binning}\n")
        assert f"depth_binning = {binning}" in message and "250 x 350" in message and "640" in message
    for binning in (1, 5):
        text = f"[estimator]\ndepth_binning = {binning}\n"
        assert estimator_settings(load_settings(write(tmp_path, text))).depth_binning == binning
    # Marker dots are found on the full grid: a binned marker finger is refused, naming the fix.
    message = error_for(tmp_path, '[sensing]\nfinger = "right"\n')
    assert "has markers" in message and "depth_binning = 1" in message
    text = '[sensing]\nfinger = "right"\n[estimator]\ndepth_binning = 1\n'
    assert load_all(write(tmp_path, text)).sensing.finger == "right"


def test_the_target_force_must_be_above_the_contact_force(tmp_path):
    # A commanded grasp squeezes to the target: at 0.5 N it never reaches the 0.75 N contact force.
    for table in ("[gripper]\ntarget_force_n = 0.5\n", "[gripper]\ntarget_force_n = 0.75\n",
                  "[gripper]\ntarget_force_n = 4\n[estimator]\ncontact_force_n = 5\n"):
        message = error_for(tmp_path, table)
        assert "gripper.target_force_n = " in message and "estimator.contact_force_n = " in message, message
        assert "is not above" in message
    assert "0.5 N" in error_for(tmp_path, "[gripper]\ntarget_force_n = 0.5\n")
    text = "[gripper]\ntarget_force_n = 1.5\n"  # a delicate rig's: above the contact force
    assert load_all(write(tmp_path, text)).gripper.target_force_n == 1.5


def test_each_package_table_is_checked_by_its_owner_naming_the_file_and_key(tmp_path):
    # The base keeps [estimator] and [display] as read; their owners build and check them.
    path = write(tmp_path, '[estimator]\nmethods = ["series", "hertzz"]\n[display]\nbackend = "usb"\n')
    settings = load_settings(path)
    with pytest.raises(SettingsError, match=r"settings.toml: \[estimator\] EstimatorSettings.methods\[1\] = 'hertzz': "
                                            r"expected one of 'no_tactile', 'elastic', 'hertz', 'series'"):
        estimator_settings(settings)
    with pytest.raises(SettingsError, match=r"settings.toml: \[display\] .*backend = 'usb'"):
        display_settings(settings)
    message = error_for(tmp_path, "[estimator]\nspeed = 1\n")
    assert "unknown key 'speed' in [estimator]" in message and "depth_binning" in message
    # Keys that moved to [sensing] say where they are now.
    message = error_for(tmp_path, '[estimator]\nfinger = "left"\n')
    assert "[estimator] finger is now [sensing] finger" in message
    message = error_for(tmp_path, "[display]\n[estimator]\nobject_poisson = 0.3\n")
    assert "[sensing] object_poisson" in message


def test_settings_naming_the_series_fit_split_still_load(tmp_path):
    # "split" was the series fit's name until the word was left to the dataset split; older
    # settings files and session logs' settings say it.
    old = write(tmp_path, default_settings_path().read_text().replace('methods = ["series",', 'methods = ["split",'))
    assert '"split"' in old.read_text()
    assert estimator_settings(load_settings(old)).methods == estimator_settings(load_settings()).methods


def test_sensor_tables(tmp_path):
    message = error_for(tmp_path, '[sensors.left]\nfinger = "right"\n')
    assert "[sensors.left]" in message and "'right'" in message
    message = error_for(tmp_path, "sensors = 3\n")
    assert "[sensors]" in message
    message = error_for(tmp_path, "[sensors]\nleft = 3\n")
    assert "[sensors.left] must be a table" in message
    message = error_for(tmp_path, "[sensors]\n")
    assert "at least one" in message
    # Fingers are what the tables are called; a table of its own makes one sensor. The estimating
    # finger must then be one with a sensor.
    message = error_for(tmp_path, "[sensors.thumb]\nmarkers = true\n")
    assert "SensingSettings.finger = 'left'" in message and "['thumb']" in message
    text = '[sensors.thumb]\nmarkers = true\n[sensing]\nfinger = "thumb"\n[estimator]\ndepth_binning = 1\n'
    settings = load_all(write(tmp_path, text, "one.toml"))
    assert [s.finger for s in settings.sensors] == ["thumb"] and settings.sensor("thumb").markers
    with pytest.raises(SettingsError, match=r"no sensor on finger 'left'.*\['thumb'\]"):
        settings.sensor("left")


def test_missing_broken_and_undecodable_files(tmp_path):
    missing = tmp_path / "absent.toml"
    with pytest.raises(SettingsError, match=f"cannot read settings file {missing}"):
        load_settings(missing)
    with pytest.raises(SettingsError, match=f"{tmp_path}.*not valid TOML"):
        load_settings(write(tmp_path, "[gripper\nmax_width_m = 0.08\n"))
    path = tmp_path / "latin1.toml"
    path.write_bytes(b"# \xe9\xe9\n[gripper]\n")
    with pytest.raises(SettingsError, match="not valid TOML"):
        load_settings(path)
    with pytest.raises(SettingsError, match="cannot read settings file"):
        load_settings(tmp_path)  # a directory


def test_missing_keys_take_their_defaults(tmp_path):
    settings = load_settings(write(tmp_path, "[gripper]\nhold_s = 1.5\n"))
    assert settings.gripper.hold_s == 1.5
    assert settings.gripper.max_width_m == Settings().gripper.max_width_m
    assert settings.sensors == Settings().sensors


def test_construction_validates_too():
    with pytest.raises(SettingsError, match="SensorSettings.gel_modulus_pa"):
        SensorSettings(gel_modulus_pa=-1.0)
    with pytest.raises(SettingsError, match="e_rigid_pa"):
        DisplaySettings(e_soft_pa=1e6, e_rigid_pa=1e6)
    with pytest.raises(SettingsError, match="names a finger twice"):
        Settings(sensors=(SensorSettings(finger="left"), SensorSettings(finger="left")))


CORNERS = ((1.0, 2.0), (600.5, 3.0), (4.0, 470.0), (630.0, 460.25))  # not the shipped ones, in the frame


def test_round_trip_through_a_mapping():
    shipped = load_settings()
    mapping = settings_to_mapping(shipped)
    json.dumps(mapping)  # plain data only
    assert settings_from_mapping(mapping) == shipped
    # A changed value in every section survives the round trip too.
    changed = dataclasses.replace(
        shipped,
        gripper=dataclasses.replace(shipped.gripper, hold_s=2.0),
        simulation=dataclasses.replace(shipped.simulation, jpeg_quality=75),
        sensors=(dataclasses.replace(shipped.sensors[0], warp_corners_px=CORNERS),),
    )
    back = settings_from_mapping(settings_to_mapping(changed))
    assert back == changed and back != shipped
    assert back.sensors[0].warp_corners_px == CORNERS
    assert all(math.isfinite(v) for v in back.sensors[0].warp_corners_px[0])


# --------------------------------------------------------------------------- the display's rigid end


def test_the_shipped_rigid_end_is_the_sensors_resolution_limit():
    settings = load_settings()
    assert display_settings(settings).e_rigid_pa == settings.resolution_limit_pa
    assert 3e6 < display_settings(settings).e_rigid_pa < 10e6
    # Its formula (module notes) for the left sensor and the estimator's object Poisson ratio.
    left, nu = settings.sensor("left"), settings.sensing.object_poisson
    expected = 0.15 * (left.gel_thickness_m / left.depth_resolution_m) * (1 - nu**2) / left.gel_compliance_per_pa
    assert settings.resolution_limit_pa == pytest.approx(expected)
    assert DisplaySettings().e_rigid_pa == 0.0  # unresolved until full settings are built
    assert display_settings(Settings()).e_rigid_pa == Settings().resolution_limit_pa


def test_an_explicit_rigid_end_overrides_the_resolution_limit(tmp_path):
    text = default_settings_path().read_text().replace("e_soft_pa = 5000.0", "e_soft_pa = 5000.0\ne_rigid_pa = 1.0e9")
    settings = load_settings(write(tmp_path, text))
    assert display_settings(settings).e_rigid_pa == 1e9 and settings.resolution_limit_pa < 1e9


def test_a_soft_end_above_the_resolution_limit_is_refused_naming_e_soft_pa(tmp_path):
    limit = load_settings().resolution_limit_pa
    message = error_for(tmp_path, f"[display]\ne_soft_pa = {limit * 2}\n")
    assert "e_soft_pa" in message and "resolution limit" in message


def test_the_resolution_limit_in_numbers_and_how_it_moves():
    sensor = load_settings().sensor("left")
    # 275 kPa gel (nu 0.48), 3 mm thick, 20 um depth resolution, object nu 0.4: 0.15 * 150 * 0.84 / k_gel.
    assert sensor.resolution_limit_pa(0.4) == pytest.approx(6.7535e6, rel=1e-4)
    finer = dataclasses.replace(sensor, depth_resolution_m=1e-5)
    stiffer = dataclasses.replace(sensor, gel_modulus_pa=2 * sensor.gel_modulus_pa)
    thinner = dataclasses.replace(sensor, gel_thickness_m=sensor.gel_thickness_m / 2)
    assert finer.resolution_limit_pa(0.4) == pytest.approx(2 * sensor.resolution_limit_pa(0.4))
    assert stiffer.resolution_limit_pa(0.4) == pytest.approx(2 * sensor.resolution_limit_pa(0.4))
    assert thinner.resolution_limit_pa(0.4) == pytest.approx(sensor.resolution_limit_pa(0.4) / 2)


def test_a_flat_sensor_works_on_its_raw_frame_whatever_the_warp_fields_say():
    # A GelSight Mini or R1.5 looks straight at the gel: its raw 640 x 480 frame is the image.
    flat = SensorSettings(model="mini", raw_width_px=640, raw_height_px=480, pixel_pitch_m=2.95e-5)
    assert flat.image_shape == (480, 640)
    assert flat.pad_size_m == pytest.approx((480 * 2.95e-5, 640 * 2.95e-5))
    assert SensorSettings().image_shape == (250, 350)  # the Wedge: warped 400 x 300, 25 px cropped


def test_the_shipped_configs_are_found_and_relative_paths_resolve_against_their_file(tmp_path):
    shipped = config_dir()
    assert (shipped / "settings.toml").is_file() and default_settings_path() == shipped / "settings.toml"
    # In a checkout (editable or not) that is the top-level configs/ folder.
    assert shipped == Path(__file__).resolve().parents[2] / "configs"
    assert resolve_path("calibration/sim-wedge-left.npz") == shipped / "calibration/sim-wedge-left.npz"
    assert resolve_path("cal.npz", folder=tmp_path) == tmp_path / "cal.npz"
    assert resolve_path(tmp_path / "cal.npz", folder=shipped) == tmp_path / "cal.npz"
    # Loading resolves every path of a file against the file's folder, package tables' included.
    text = ('[sensors.left]\ncalibration = "mine/left.npz"\n[estimator]\nmodel_path = "../models/m.onnx"\n'
            '[bus]\nkeys_dir = "keys"\n')
    user = load_settings(write(tmp_path, text))
    assert user.sensor("left").calibration == str(tmp_path / "mine/left.npz")
    assert user.bus.keys_dir == str(tmp_path / "keys")
    assert estimator_settings(user).model_path == str(tmp_path.parent / "models/m.onnx")
    for path in [default_settings_path(), *sorted((shipped / "rigs").glob("*.toml"))]:
        for sensor in load_settings(path).sensors:
            assert Path(sensor.calibration).is_absolute() and Path(sensor.calibration).is_file(), path


@pytest.mark.parametrize("corners, expected", [
    ("[[46, 87], [439, 121], [52, 425], [4460, 3680]]", "the bottom-right corner (4460, 3680) is outside the 640x480 raw frame"),
    ("[[-3, 87], [439, 121], [52, 425], [446, 368]]", "the top-left corner (-3, 87) is outside"),
    ("[[46, 87], [439, 121], [446, 368], [52, 425]]", "expected the corners in the order top-left, top-right, "
                                                      "bottom-left, bottom-right of a convex quadrilateral"),
    ("[[439, 121], [46, 87], [446, 368], [52, 425]]", "convex quadrilateral"),  # mirrored: left and right swapped
    ("[[0, 0], [100, 0], [0, 100], [20, 20]]", "convex quadrilateral"),  # the bottom-right bent inward
    ("[[0, 0], [100, 0], [200, 0], [300, 0]]", "convex quadrilateral"),  # on one line
])
def test_wedge_warp_corners_must_lie_in_the_raw_frame_in_their_documented_order(tmp_path, corners, expected):
    for finger in ("left", "right"):
        message = error_for(tmp_path, f"[sensors.{finger}]\nwarp_corners_px = {corners}\n")
        assert f"[sensors.{finger}] SensorSettings.warp_corners_px" in message and expected in message, message
    # the raw frame's own corners (the shipped GelSight rigs), edges included
    path = write(tmp_path, "[sensors.left]\nraw_width_px = 320\nraw_height_px = 240\n"
                           "warp_corners_px = [[0, 0], [320, 0], [0, 240], [320, 240]]\n")
    assert load_all(path).sensor("left").warp_corners_px[3] == (320.0, 240.0)
    message = error_for(tmp_path, "[sensors.left]\nraw_width_px = 320\nraw_height_px = 240\n")  # 640x480 corners
    assert "outside the 320x240 raw frame" in message
    # a flat sensor is not warped: its corners are not read
    path = write(tmp_path, '[sensors.left]\nmodel = "mini"\nwarp_corners_px = [[0, 0], [5000, 0], [0, 1], [1, 1]]\n')
    assert load_all(path).sensor("left").model == "mini"


def test_every_shipped_settings_file_loads():
    files = [default_settings_path(), *sorted((default_settings_path().parent / "rigs").glob("*.toml"))]
    assert len(files) >= 3
    for path in files:
        load_all(path)


def test_a_finger_stiffness_in_n_per_mm_is_refused_saying_so(tmp_path):
    for force in ("", "target_force_n = 10.0\n"):  # whatever the grasp force
        message = error_for(tmp_path, f"[gripper]\nfinger_stiffness_n_per_m = 200.0\n{force}")
        assert "GripperSettings.finger_stiffness_n_per_m = 200.0" in message
        assert "expected at least 1000 N/m" in message and "200 N/mm is 200000 N/m" in message
    path = write(tmp_path, "[gripper]\nfinger_stiffness_n_per_m = 2.0e4\n")  # the softest fingers drawn
    assert load_all(path).gripper.finger_stiffness_n_per_m == 2.0e4


def test_a_settings_file_with_a_byte_order_mark_loads(tmp_path):
    plain, path = tmp_path / "plain.toml", tmp_path / "bom.toml"  # one folder: the same paths resolved
    plain.write_bytes(default_settings_path().read_bytes())
    path.write_bytes(b"\xef\xbb\xbf" + plain.read_bytes())
    assert load_all(path) == load_all(plain)
