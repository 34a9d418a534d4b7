"""The rig's settings tables (teleop.settings) at their edges: each safety-relevant limit refused just
past it and kept at it, the sensor geometry checks, and where a file's paths and tables end up."""

from __future__ import annotations

import os

import pytest
from support.rig_settings import rig_settings

from teleop.errors import SettingsError
from teleop.settings import (
    BusSettings,
    GripperSettings,
    LoadCellSettings,
    SensingSettings,
    SensorSettings,
    Settings,
    SimulationSettings,
    load_settings,
)

# (class, field, a value just past the limit, the limit itself or a value just inside it)
LIMITS = [
    (GripperSettings, "target_force_n", 140.0001, 140.0),
    (GripperSettings, "target_force_n", 0.0, 1e-3),
    (GripperSettings, "max_width_m", 0.3001, 0.3),
    (GripperSettings, "max_width_m", 0.0, 1e-3),
    (GripperSettings, "closing_speed_m_s", 0.2001, 0.2),
    (GripperSettings, "hold_s", -1e-3, 0.0),
    (GripperSettings, "width_read_hz", 0.09, 0.1),
    (GripperSettings, "finger_stiffness_n_per_m", 999.0, 1000.0),
    (LoadCellSettings, "timeout_s", 0.0, 1e-3),
    (LoadCellSettings, "counts_per_n", 0.0, 1e-3),
    (LoadCellSettings, "tare_counts", 2**23, 2**23 - 1),
    (LoadCellSettings, "tare_counts", -(2**23) - 1, -(2**23)),
    (BusSettings, "heartbeat_s", 0.0, 1e-3),
    (BusSettings, "max_message_bytes", 1023, 1024),
    (SensorSettings, "camera_hz", 0.99, 1.0),
    (SensorSettings, "gel_modulus_pa", 1e3, 1.001e3),
    (SensorSettings, "gel_poisson", 0.5001, 0.5),
    (SensingSettings, "object_poisson", 0.5001, 0.5),
    (SimulationSettings, "jpeg_quality", 101, 100),
    (SimulationSettings, "force_noise_n", -1e-3, 0.0),
]


@pytest.mark.parametrize(("cls", "name", "past", "at"), LIMITS)
def test_a_value_past_a_limit_is_refused_and_the_limit_itself_kept(cls, name, past, at):
    with pytest.raises(SettingsError, match=rf"{cls.__name__}\.{name} = "):
        cls(**{name: past})
    assert getattr(cls(**{name: at}), name) == at


def test_a_grasp_force_past_the_maximum_in_a_file_is_refused_naming_file_key_and_range(tmp_path):
    path = tmp_path / "rig.toml"
    path.write_text("[gripper]\ntarget_force_n = 140.5\n", encoding="utf-8")
    with pytest.raises(SettingsError) as info:
        load_settings(path)
    message = str(info.value)
    assert str(path) in message and "GripperSettings.target_force_n = 140.5" in message, message
    assert "(0.0, 140.0]" in message
    assert load_settings(rig_settings(tmp_path, {"gripper.target_force_n": 140.0})).gripper.target_force_n == 140.0


@pytest.mark.parametrize("crop_px", [150, 160])  # 400 x 300 warped: half the shorter side or more
def test_a_crop_that_leaves_nothing_of_the_shorter_side_is_refused(crop_px):
    with pytest.raises(SettingsError, match="crops the whole 400x300 warped image away"):
        SensorSettings(crop_px=crop_px)
    assert SensorSettings(crop_px=149).image_shape == (2, 102)


def test_a_corner_below_the_raw_frame_is_refused_though_inside_its_width():
    corners = ((46.0, 87.0), (439.0, 121.0), (52.0, 500.0), (446.0, 368.0))  # y 500 of a 640x480 frame
    with pytest.raises(SettingsError, match=r"the bottom-left corner \(52, 500\) is outside the 640x480 raw frame"):
        SensorSettings(warp_corners_px=corners)


def test_corners_bent_inward_at_the_top_left_are_refused():
    # convex at the other three corners: only the turn at the top-left shows the fold
    with pytest.raises(SettingsError, match="convex quadrilateral"):
        SensorSettings(warp_corners_px=((60.0, 60.0), (100.0, 0.0), (0.0, 100.0), (100.0, 100.0)))
    assert SensorSettings(warp_corners_px=((40.0, 40.0), (100.0, 0.0), (0.0, 100.0), (100.0, 100.0)))


def test_a_table_no_package_registered_is_refused_when_settings_are_built_in_code():
    with pytest.raises(SettingsError, match="Settings.tables names 'nope'"):
        Settings(tables={"nope": {}})


def test_a_package_table_that_is_not_a_table_is_refused_naming_the_file(tmp_path):
    path = tmp_path / "rig.toml"
    path.write_text("estimator = 3\n", encoding="utf-8")
    with pytest.raises(SettingsError, match=rf"{path}: \[estimator\] must be a table, got int"):
        load_settings(path)


def test_a_relative_simulation_background_resolves_against_the_settings_files_folder(tmp_path):
    path = rig_settings(tmp_path, {"simulation.background": "frames/empty.png"})
    assert load_settings(path).simulation.background == str(tmp_path / "frames/empty.png")


def test_a_file_named_relative_to_the_working_folder_is_recorded_by_its_absolute_path(tmp_path, monkeypatch):
    rig_settings(tmp_path, {})
    monkeypatch.chdir(tmp_path)
    settings = load_settings("rig.toml")
    assert settings.source == tmp_path / "rig.toml" and settings.source.is_absolute()
    os.chdir(tmp_path.parent)  # a later change of folder moves nothing the settings point at
    assert settings.folder == tmp_path
