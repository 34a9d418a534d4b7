"""Session logs whose settings attachment predates a key's move to another table (``[estimator]
finger`` and ``object_poisson``, now in ``[sensing]``) are read as they ran; settings files are not."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

import teleop.session.recorder as recorder_module
from estimator.settings import EstimatorSettings
from teleop.errors import SettingsError
from teleop.session import LogReader
from teleop.settings import load_settings, migrated, settings_to_mapping
from teleop.system.report import build_report

_spec = importlib.util.spec_from_file_location("_report_tests", Path(__file__).with_name("test_report.py"))
_report_tests = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(_report_tests)


def _before_sensing(settings) -> dict:
    """The settings as a recorder wrote them before [sensing]: its keys in [estimator]."""
    mapping = settings_to_mapping(settings)
    sensing = mapping.pop("sensing")
    return {**mapping, "estimator": {**mapping["estimator"], **sensing}}


def test_a_log_whose_settings_hold_moved_keys_is_reported_with_them_where_they_are_now(tmp_path, monkeypatch):
    settings = load_settings()
    old = _before_sensing(settings)
    # The right finger (markers) estimating: its depth is measured on the full grid.
    old["estimator"].update(finger="right", object_poisson=0.3, depth_binning=1)
    monkeypatch.setattr(recorder_module, "settings_to_mapping", lambda _: old)
    items = [(1.0, 0, "grasp_event", {"grasp_id": "g", "event": "start", "object_name": "rubber_duck"}),
             (1.5, 3, "estimate", {"grasp_id": "g", "method": "auto", "E_pa": 2e6, "interval_pa": [1e6, 4e6],
                                   "state": "ok", "reason": "test", "provisional": False, "latency_s": 0.0}),
             (2.0, 5, "grasp_event", {"grasp_id": "g", "event": "end", "object_name": None})]
    log = _report_tests._record(tmp_path / "s.mcap", items, settings)
    monkeypatch.undo()

    ran = LogReader(log).info().settings()
    assert (ran.sensing.finger, ran.sensing.object_poisson) == ("right", 0.3)
    assert build_report(log, tmp_path / "report").index.is_file()


def test_a_moved_key_is_carried_unless_its_new_table_sets_it():
    data = {"estimator": {"finger": "right", "object_poisson": 0.3}, "sensing": {"finger": "left"}}
    assert migrated(data) == {"estimator": {}, "sensing": {"finger": "left", "object_poisson": 0.3}}
    assert data["estimator"] == {"finger": "right", "object_poisson": 0.3}  # the caller's is left as it was
    assert migrated({"sensing": {"finger": "left"}}) == {"sensing": {"finger": "left"}}


def test_a_settings_file_with_a_moved_key_is_still_refused_naming_where_it_is_now(tmp_path):
    path = tmp_path / "settings.toml"
    path.write_text('[estimator]\nfinger = "left"\n')
    with pytest.raises(SettingsError, match=r"\[estimator\] finger is now \[sensing\] finger: move it there"):
        load_settings(path).section(EstimatorSettings)
