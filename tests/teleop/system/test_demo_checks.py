"""``teleop demo`` refuses, before any process starts, a scene its settings cannot run, saying what to change."""

from __future__ import annotations

import re
import shutil

import teleop.cli
from teleop.scene import scene_path
from teleop.settings import default_settings_path
from teleop.settings_edit import update_settings_file


def _settings(tmp_path, changes):
    path = tmp_path / "rig.toml"
    shutil.copy(default_settings_path(), path)
    update_settings_file(path, changes)
    return path


def test_objects_wider_than_the_open_gripper_are_refused_naming_them_and_the_opening(tmp_path, capsys):
    settings = _settings(tmp_path, {"gripper.max_width_m": 0.03})
    scene = tmp_path / "narrow.toml"
    scene.write_text(f'catalogue = "{default_settings_path().parent / "objects.toml"}"\n'
                     f'objects = ["stress_ball", "rubber_duck", "steel_ball_bearing"]\nsettings = "{settings}"\n')
    run = tmp_path / "run"
    assert teleop.cli.main(["demo", "--scene", str(scene), "--settings", str(settings), "--out", str(run)]) == 2
    err = capsys.readouterr().err
    assert re.search(r"objects 'stress_ball' \(0\.0\d+ m\), 'rubber_duck' \(0\.0\d+ m\) are, at their narrowest, "
                     r"wider than fingers open to gripper\.max_width_m = 0\.03 m take", err), err
    assert "steel_ball_bearing" not in err  # a 1 cm ball fits
    assert not run.exists()  # refused before the run folder, the calibration and the processes


def test_a_scene_for_other_settings_names_its_file_the_settings_it_names_and_both_ways_out(tmp_path, capsys):
    other = _settings(tmp_path, {"gripper.hold_s": 1.0})
    assert teleop.cli.main(["demo", "--scene", "quick", "--settings", str(other), "--out", str(tmp_path / "run")]) == 2
    err = capsys.readouterr().err
    quick = scene_path("quick")
    assert f"{quick} names {default_settings_path()}" in err, err
    assert f"pass --settings {default_settings_path()}" in err
    assert f'set settings = "{other}" in {quick}' in err
