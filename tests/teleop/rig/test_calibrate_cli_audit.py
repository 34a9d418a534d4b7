"""Audit of :mod:`teleop.rig.calibrate_cli`: each calibration's help is its own, under its own name."""

from __future__ import annotations

import pytest

from teleop.cli import main
from teleop.rig.calibrate_cli import TARGETS


@pytest.mark.parametrize("target", sorted(TARGETS))
def test_a_calibrations_help_is_shown_under_its_own_command_name(target, capsys):
    with pytest.raises(SystemExit) as exited:
        main(["calibrate", target, "--help"])
    assert exited.value.code == 0
    out = capsys.readouterr().out
    assert out.startswith(f"usage: teleop calibrate {target} ")
    assert "--settings FILE" in out


def test_an_unknown_calibration_is_refused_naming_the_choices(capsys):
    with pytest.raises(SystemExit) as exited:
        main(["calibrate", "torque"])
    assert exited.value.code == 2
    assert "invalid choice: 'torque'" in capsys.readouterr().err


def test_a_calibrations_own_option_errors_name_its_command(capsys):
    with pytest.raises(SystemExit) as exited:
        main(["calibrate", "gripper", "--settings", "rig.toml"])  # --object-width-mm is required
    assert exited.value.code == 2
    err = capsys.readouterr().err
    assert "teleop calibrate gripper: error:" in err and "--object-width-mm" in err
