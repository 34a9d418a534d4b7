"""An interrupted ``teleop report`` into an existing report folder leaves the earlier report whole."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

import teleop.system.report as report_module
from teleop.settings import load_settings

_spec = importlib.util.spec_from_file_location("_report_tests", Path(__file__).with_name("test_report.py"))
_report_tests = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(_report_tests)


def test_an_interrupted_report_leaves_the_earlier_page_and_figures(tmp_path, monkeypatch):
    items = [(1.0, 0, "grasp_event", {"grasp_id": "g", "event": "start", "object_name": "rubber_duck"}),
             (1.5, 3, "estimate", {"grasp_id": "g", "method": "auto", "E_pa": 2e6, "interval_pa": [1e6, 4e6],
                                   "state": "ok", "reason": "test", "provisional": False, "latency_s": 0.0}),
             (2.0, 5, "grasp_event", {"grasp_id": "g", "event": "end", "object_name": None})]
    log = _report_tests._record(tmp_path / "s.mcap", items, load_settings())
    out = tmp_path / "report"
    first = report_module.build_report(log, out)
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    (out / "notes.txt").write_text("mine")

    def interrupted(views, path, **options):
        Path(path).write_bytes(b"half a figure")
        raise KeyboardInterrupt

    monkeypatch.setattr(report_module, "predictions_figure", interrupted)
    with pytest.raises(KeyboardInterrupt):
        report_module.build_report(log, out)
    assert {p.name: p.read_bytes() for p in out.iterdir() if p.name != "notes.txt"} == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["report", "s.mcap"]
    monkeypatch.undo()
    again = report_module.build_report(log, out)
    assert (out / "notes.txt").read_text() == "mine" and again.index == first.index and again.index.exists()
