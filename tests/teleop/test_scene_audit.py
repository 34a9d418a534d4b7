"""Scenes, audited by mutation: the objects list, the defaults and values of grasps and seed, the scene's
name and the errors of a scene that names no catalogue or settings file."""

from __future__ import annotations

import pytest

from teleop import scene as scene_module
from teleop.errors import SettingsError
from teleop.scene import current_method, load_scene
from tests.support.catalogue_toml import settings_refusal, toml_file


def _scene(tmp_path, text: str):
    return toml_file(tmp_path, "lab_day.toml", text)


def _refusal(path) -> str:
    return settings_refusal(lambda: load_scene(str(path)))


@pytest.mark.parametrize("objects", ["[]", '"stress_ball"', "[1]", '["stress_ball", 2]'])
def test_objects_that_are_no_non_empty_array_of_names_are_refused(tmp_path, objects):
    path = _scene(tmp_path, f"objects = {objects}\n")
    assert _refusal(path) == f"{path}: objects must be a non-empty array of object names"


def test_an_empty_catalogue_path_is_refused_as_no_file_path(tmp_path):
    path = _scene(tmp_path, 'catalogue = ""\nobjects = ["stress_ball"]\n')
    assert f"{path}: catalogue must be a file path (a string), got ''" in _refusal(path)


def test_grasps_and_seed_default_to_one_grasp_and_seed_0(tmp_path):
    scene = load_scene(str(_scene(tmp_path, 'objects = ["stress_ball"]\n')))
    assert (scene.grasps_per_object, scene.seed) == (1, 0)


@pytest.mark.parametrize(("extra", "expected"), [
    ("grasps_per_object = true\n", "grasps_per_object must be an integer >= 1, got True"),
    ("seed = -1\n", "seed must be an integer >= 0, got -1"),
    ("seed = false\n", "seed must be an integer >= 0, got False"),
])
def test_a_boolean_or_negative_count_is_refused(tmp_path, extra, expected):
    path = _scene(tmp_path, f'objects = ["stress_ball"]\n{extra}')
    assert _refusal(path) == f"{path}: {expected}"


def test_a_scene_keeps_its_file_stem_as_name_its_values_and_the_listed_order(tmp_path):
    path = _scene(tmp_path, 'objects = ["stress_ball", "rubber_duck"]\ngrasps_per_object = 3\nseed = 7\n')
    scene = load_scene(str(path))
    assert scene.name == "lab_day"
    assert [o.name for o in scene.objects] == ["stress_ball", "rubber_duck"]
    assert (scene.grasps_per_object, scene.seed) == (3, 7)


@pytest.mark.parametrize("content", [b"objects = [\n", b"description = \"caf\xe9\"\n"])
def test_a_scene_that_is_no_utf8_toml_is_refused_naming_it(tmp_path, content):
    path = tmp_path / "broken.toml"
    path.write_bytes(content)
    assert _refusal(path).startswith(f"{path}: cannot read scene (")


def test_an_unknown_scene_name_lists_the_shipped_scenes():
    with pytest.raises(SettingsError) as info:
        load_scene("nosuch")
    message = str(info.value)
    assert message.startswith("no scene 'nosuch' (") and "; scenes here: " in message and "default" in message


def test_a_broken_shipped_catalogue_is_named_as_the_one_the_scene_left_to_default(tmp_path, monkeypatch):
    (tmp_path / "objects.toml").write_text("objects = []\n", encoding="utf-8")
    monkeypatch.setattr(scene_module, "config_dir", lambda: tmp_path)
    path = _scene(tmp_path, 'objects = ["stress_ball"]\n')
    assert _refusal(path).startswith(f"{path}: the shipped catalogue (the scene names no catalogue): "
                                     f"{tmp_path / 'objects.toml'}: expected one or more")


def test_a_missing_default_settings_file_is_said_as_the_settings_loader_says_it(tmp_path, monkeypatch):
    absent = tmp_path / "absent.toml"
    monkeypatch.setattr(scene_module, "default_settings_path", lambda: absent)
    scene = load_scene(str(_scene(tmp_path, 'objects = ["stress_ball"]\n')))
    assert scene.settings_path == absent
    with pytest.raises(SettingsError) as info:
        _ = scene.settings
    assert str(info.value).startswith(f"cannot read settings file {absent}")


def test_the_series_fit_once_called_split_is_read_by_its_current_name():
    assert (current_method("split"), current_method("series"), current_method("mean")) == ("series", "series", "mean")
