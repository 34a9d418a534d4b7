"""Fixtures of the simulator's tests: a small catalogue and fast settings."""

from __future__ import annotations

import dataclasses

import pytest
from support.catalogue_toml import object_toml

from teleop.cli import main
from teleop.settings import default_settings_path, load_settings


@pytest.fixture(scope="module")
def settings():
    """The simulator tests' settings (in place of the root conftest's): the shipped ones with 10 Hz
    cameras, a third of the frames to render, which keeps the tests quick."""
    shipped = load_settings()
    return dataclasses.replace(shipped, sensors=tuple(dataclasses.replace(s, camera_hz=10.0) for s in shipped.sensors))


@pytest.fixture
def ball_toml() -> str:
    """A catalogue (TOML text) of one small rubber ball."""
    return object_toml("small rubber ball", "sphere", "rubber", 8.0e5, size_m=[0.02, 0.02, 0.02])


@pytest.fixture
def quick_settings(tmp_path):
    """The shipped settings with 10 Hz cameras (a third of the frames to render), calibrations and all."""
    text = default_settings_path().read_text().replace("camera_hz = 30.0", "camera_hz = 10.0")
    # The shipped calibration files, not files beside this copy (teleop simulate warns of missing ones).
    text = text.replace('calibration = "calibration/', f'calibration = "{default_settings_path().parent}/calibration/')
    text = text.replace("[sensors.right]", "[sensors.right]\ncamera_hz = 10.0")
    path = tmp_path / "settings.toml"
    path.write_text(text)
    assert all(s.camera_hz == 10.0 for s in load_settings(path).sensors)
    return path


@pytest.fixture
def catalogue(tmp_path, ball_toml):
    """The one-ball catalogue as a file."""
    path = tmp_path / "objects.toml"
    path.write_text(ball_toml)
    return path


@pytest.fixture
def simulate_cli(capsys, catalogue, quick_settings):
    """``simulate_cli(out, *options, seed=3)``: ``teleop simulate`` of :func:`catalogue` with
    :func:`quick_settings` into ``out``; the one record's path."""

    def run(out, *extra, seed: int = 3):
        code = main(["simulate", "--objects", str(catalogue), "--seed", str(seed), "--out", str(out),
                     "--settings", str(quick_settings), *extra])
        assert code == 0, capsys.readouterr().err
        (path,) = out.glob("*.grasp")
        return path

    return run
