"""How a ``teleop calibrate`` command ends (:func:`teleop.rig.conclude.conclude`): what it writes
into the settings file, what it prints, and its exit status."""

from __future__ import annotations

import json
import shutil

import pytest

from teleop.rig.conclude import conclude
from teleop.settings import default_settings_path, load_settings


@pytest.fixture
def settings_file(tmp_path):
    path = tmp_path / "rig.toml"
    shutil.copy(default_settings_path(), path)
    return path


def test_a_refusal_writes_nothing_even_with_changes(settings_file, capsys):
    # camera_calibration passes the corners' change along when only the latency is refused.
    before = settings_file.read_bytes()
    code = conclude("camera", settings_file, report={"finger": "left"}, changes={"load_cell.tare_counts": 7},
                    refused="latency: no tap", as_json=True)
    assert code == 1 and settings_file.read_bytes() == before
    out, err = capsys.readouterr()
    assert json.loads(out) == {"finger": "left", "changes": []}
    assert f"camera refused: latency: no tap; {settings_file} not changed" in err


def test_an_accepted_fit_writes_its_changes_and_reports_them(settings_file, capsys):
    code = conclude("load cell", settings_file, report={"ok": True}, changes={"load_cell.tare_counts": 7},
                    summary="tare 7 counts", as_json=True)
    assert code == 0 and load_settings(settings_file).load_cell.tare_counts == 7
    out, err = capsys.readouterr()
    assert [c["key"] for c in json.loads(out)["changes"]] == ["load_cell.tare_counts"]
    assert "tare 7 counts" in err


def test_without_json_the_changes_are_printed_for_the_person(settings_file, capsys):
    assert conclude("load cell", settings_file, report={}, changes={"load_cell.tare_counts": 7}) == 0
    out = capsys.readouterr().out
    assert "load_cell.tare_counts" in out and not out.startswith("{")
