"""``teleop export --json``: one JSON object on stdout, with ``error``, even when the export is refused."""

from __future__ import annotations

import json

import teleop.cli

KEYS = {"log", "out", "session_id", "complete", "refused", "mendable", "exported", "records", "written", "unlabelled", "skipped",
        "dropped", "stray_labels", "replaced", "error"}


def _only_json(out: str) -> dict:
    lines = out.strip().splitlines()
    assert len(lines) == 1, out
    return json.loads(lines[0])


def test_a_refused_second_export_still_prints_the_json_object(recorded, tmp_path, capsys):
    out = tmp_path / "records"
    assert teleop.cli.main(["export", str(recorded.path), "--out", str(out), "--json"]) == 0
    first = _only_json(capsys.readouterr().out)
    assert set(first) == KEYS and first["error"] is None

    assert teleop.cli.main(["export", str(recorded.path), "--out", str(out), "--json"]) == 2
    captured = capsys.readouterr()
    assert "teleop export: error:" in captured.err and "--overwrite" in captured.err
    report = _only_json(captured.out)
    assert set(report) == KEYS
    assert "already exists" in report["error"] and "--overwrite" in report["error"]
    assert report["error"] in captured.err
    assert report["log"] == str(recorded.path) and report["out"] == str(out)
    assert report["exported"] is None and report["records"] is None and report["session_id"] is None


def test_a_log_too_short_to_read_still_prints_the_json_object(recorded, tmp_path, capsys):
    short = tmp_path / "short.mcap"
    short.write_bytes(recorded.path.read_bytes()[:1234])
    assert teleop.cli.main(["export", str(short), "--out", str(tmp_path / "out"), "--json"]) == 2
    captured = capsys.readouterr()
    report = _only_json(captured.out)
    assert set(report) == KEYS and report["error"] and report["error"] in captured.err
    assert "teleop export: error:" in captured.err and report["complete"] is None


def test_without_json_an_error_prints_nothing_on_stdout(tmp_path, capsys):
    assert teleop.cli.main(["export", str(tmp_path / "absent.mcap"), "--out", str(tmp_path / "out")]) == 2
    captured = capsys.readouterr()
    assert captured.out == "" and "cannot read session log" in captured.err
