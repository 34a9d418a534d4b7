"""Scenes: the shipped ones load, bad ones are refused naming the file and the key, the settings are read late."""

from __future__ import annotations

import pytest

from teleop.bus.pubsub import Publisher
from teleop.cli import main
from teleop.errors import SettingsError
from teleop.scene import SCENE_DIR, load_scene
from teleop.settings import load_settings


def scene_file(tmp_path, extra: str = "", objects: str = '["stress_ball"]'):
    path = tmp_path / "scene.toml"
    path.write_text(f'description = "test"\nobjects = {objects}\nseed = 1\n{extra}', encoding="utf-8")
    return path


@pytest.mark.parametrize("name", sorted(p.stem for p in SCENE_DIR.glob("*.toml")))
def test_the_shipped_scenes_load_with_the_shipped_settings(name):
    scene = load_scene(name)
    assert scene.objects and scene.settings == load_settings()


@pytest.mark.parametrize(("extra", "expected"), [
    # Scenes once named backends and estimate methods; nothing read them: they are the settings file's.
    ('backends = "sim"\n', "'backends' is no longer a scene key: the device backends are the settings file's"),
    ('[backends]\ncamera = "opencv"\n', "'backends' is no longer a scene key"),
    ('estimator = "x"\n', "'estimator' is no longer a scene key: the estimate methods are the settings file's "
                          "[estimator] methods"),
    ("[estimator]\nmethods = 5\n", "'estimator' is no longer a scene key"),
    ("speed = 3\n", "unknown key 'speed'; allowed keys: catalogue, description"),
    ("[extra]\nx = 1\n", "unknown key 'extra'"),
    ("catalogue = 3\n", "catalogue must be a file path (a string), got 3"),
    ("settings = []\n", "settings must be a file path (a string), got []"),
    ("grasps_per_object = 0\n", "grasps_per_object must be an integer >= 1"),
])
def test_a_bad_key_is_refused_naming_the_file_and_the_key(tmp_path, extra, expected):
    path = scene_file(tmp_path, extra)
    with pytest.raises(SettingsError, match="scene.toml: ") as raised:
        load_scene(str(path))
    assert expected in str(raised.value)


def test_a_description_that_is_no_string_is_refused(tmp_path):
    path = tmp_path / "scene.toml"
    path.write_text('description = {a = 1}\nobjects = ["stress_ball"]\n', encoding="utf-8")
    with pytest.raises(SettingsError, match="description must be a string"):
        load_scene(str(path))


def test_an_object_named_twice_is_refused_naming_it(tmp_path):
    path = scene_file(tmp_path, objects='["stress_ball", "rubber_duck", "stress_ball"]')
    with pytest.raises(SettingsError, match="objects lists 'stress_ball' twice.*grasps_per_object"):
        load_scene(str(path))


def test_a_missing_catalogue_is_named_with_the_scene_file_and_key(tmp_path):
    path = scene_file(tmp_path, 'catalogue = "nosuch.toml"\n')
    with pytest.raises(SettingsError) as raised:
        load_scene(str(path))
    assert str(raised.value).startswith(f'{path}: catalogue = "nosuch.toml": cannot read catalogue '
                                        f'{tmp_path / "nosuch.toml"}')


def test_objects_not_in_the_catalogue_name_the_catalogue(tmp_path):
    catalogue = tmp_path / "objects.toml"
    catalogue.write_text('[[objects]]\nname = "a"\nshape = "sphere"\nmaterial = "rubber"\nmodulus_pa = 1e6\n'
                         'size_m = [0.03, 0.03, 0.03]\n', encoding="utf-8")
    path = scene_file(tmp_path, 'catalogue = "objects.toml"\n', objects='["a", "b"]')
    with pytest.raises(SettingsError) as raised:
        load_scene(str(path))
    assert str(raised.value) == f"{path}: objects ['b'] are not in the catalogue {catalogue}"


def test_a_missing_settings_file_is_named_with_the_scene_file_and_key(tmp_path):
    path = scene_file(tmp_path, 'settings = "nosuch.toml"\n')
    scene = load_scene(str(path))
    with pytest.raises(SettingsError) as raised:
        _ = scene.settings
    assert str(raised.value).startswith(f'{path}: settings = "nosuch.toml": ')
    assert str(tmp_path / "nosuch.toml") in str(raised.value)


def test_the_scenes_settings_are_read_when_first_used(tmp_path):
    path = scene_file(tmp_path, 'settings = "absent.toml"\n')
    scene = load_scene(str(path))
    assert [o.name for o in scene.objects] == ["stress_ball"]
    with pytest.raises(SettingsError, match="absent.toml"):
        _ = scene.settings


def test_the_node_runs_with_its_own_settings_whatever_the_scenes_say(tmp_path, capsys):
    path = scene_file(tmp_path, 'settings = "absent.toml"\n')
    with Publisher("tcp://127.0.0.1:*", lossless=True, source="operator") as operator:
        code = main(["node", "--scene", str(path), "--robot-pub", "tcp://127.0.0.1:*",
                     "--command", operator.endpoint, "--duration-s", "0.05"])
    assert code == 0, capsys.readouterr().err
    assert "robot node: 0 grasps" in capsys.readouterr().err


@pytest.mark.parametrize("value", ["0", "-1", "nan"])
def test_the_node_refuses_a_duration_that_is_no_positive_time(value, capsys):
    with pytest.raises(SystemExit) as raised:
        main(["node", "--duration-s", value])
    assert raised.value.code == 2 and "--duration-s" in capsys.readouterr().err
