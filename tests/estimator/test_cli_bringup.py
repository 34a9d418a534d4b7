"""``estimator``'s command line at bring-up: a Ctrl-C while a command's modules import, and a
calibration of another sensor named to ``estimator reconstruct``."""

from __future__ import annotations

import importlib

import pytest

from estimator.cli import main
from teleop.settings import config_dir, default_settings_path


@pytest.mark.parametrize("argv, said", [(["-v", "bench", "--help"], "estimator bench: interrupted\n"),
                                        (["reconstruct"], "estimator reconstruct: interrupted\n")])
def test_ctrl_c_while_the_command_imports_ends_in_one_line_and_130(monkeypatch, capsys, argv, said):
    real = importlib.import_module

    def slow_import(name, *args, **kwargs):
        if name.startswith("estimator.") and name.endswith("_cli"):  # the command's module, seconds in numpy
            raise KeyboardInterrupt
        return real(name, *args, **kwargs)

    monkeypatch.setattr(importlib, "import_module", slow_import)
    try:
        code = main(argv)
    except KeyboardInterrupt:  # not let through: it would end the whole test session
        pytest.fail("the Ctrl-C came through as KeyboardInterrupt (a traceback on the command line)")
    assert code == 130
    assert capsys.readouterr().err == said


def test_reconstruct_warns_of_a_calibration_made_for_another_finger(tmp_path, capsys):
    from teleop.cli import main as teleop_main

    pack = str(tmp_path / "presses.npz")
    assert teleop_main(["simulate-presses", "--out", pack, "--finger", "left", "--n", "2", "--seed", "3"]) == 0
    common = ["reconstruct", "--presses", pack, "--settings", str(default_settings_path()), "--finger", "left", "--all"]
    capsys.readouterr()
    assert main([*common, "--calibration", str(config_dir() / "calibration" / "sim-wedge-right.npz")]) == 0
    err = capsys.readouterr().err
    assert ("warning: the calibration was made for another sensor than wedge 'sim-wedge-left': finger 'right' "
            "(this sensor: 'left')") in err, err
    assert "[sensors.left]'s own --calibration" in err
    assert main([*common, "--calibration", str(config_dir() / "calibration" / "sim-wedge-left.npz")]) == 0
    assert "warning" not in capsys.readouterr().err
