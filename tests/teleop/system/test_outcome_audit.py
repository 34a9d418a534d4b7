"""A grasp's outcome: what a service's report file holds besides its records (blank lines) and what the
outcome's figures read when they sit at an edge."""

from __future__ import annotations

import logging

from teleop.system.outcome import ReportReader


def test_blank_lines_in_a_report_are_skipped_without_a_warning(tmp_path, caplog):
    path = tmp_path / "r.jsonl"
    path.write_text('\n{"grasp_id": "g1"}\n   \n\n{"grasp_id": "g2"}\n')
    reader = ReportReader(path)
    with caplog.at_level(logging.WARNING, logger="teleop.system.outcome"):
        assert reader.poll() == [{"grasp_id": "g1"}, {"grasp_id": "g2"}]
    assert caplog.records == []  # a blank line is no torn record
