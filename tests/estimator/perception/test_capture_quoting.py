"""The command ``estimator calibrate --capture`` suggests for a simulated camera can be pasted into a shell."""

from __future__ import annotations

import shlex
import shutil

from estimator.cli import main
from teleop.settings import default_settings_path


def test_the_suggested_simulate_presses_command_quotes_a_settings_path_with_spaces(tmp_path, capsys):
    settings = tmp_path / "my rig" / "settings.toml"
    settings.parent.mkdir()
    shutil.copy(default_settings_path(), settings)  # the shipped simulated rig
    assert main(["calibrate", "--capture", "--presses", str(tmp_path / "new"), "--settings", str(settings),
                 "--finger", "left", "--ball-radius-mm", "2", "--out", str(tmp_path / "c.npz")]) == 2
    err = capsys.readouterr().err
    suggested = err.partition("simulate the presses instead (")[2].partition(", then")[0]
    assert shlex.split(suggested) == ["teleop", "simulate-presses", "--settings", str(settings),
                                      "--finger", "left", "--out", "P.npz"]
