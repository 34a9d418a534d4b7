"""A demo grasp's outcome (:mod:`teleop.system.outcome`): what it takes from the bus messages it
observes, what it reads from the renderer's report and the final estimate, and the reports' reader."""

from __future__ import annotations

import time
from types import SimpleNamespace

import numpy as np
import pytest
from support.outcomes import outcome

import teleop.system.outcome as outcome_module
from teleop.bus.messages import RobotNoticeBody
from teleop.system.demo_table import closing_table, display_cell
from teleop.system.outcome import ReportReader, display_felt_pa

RANGE_PA = (5e3, 6.75e6)


def _message(kind: str, t_capture_s: float = 0.0, **body) -> SimpleNamespace:
    return SimpleNamespace(type=kind, t_capture_s=t_capture_s, fields=SimpleNamespace(**body))


def _notice(event: str, grasp_id: str | None) -> SimpleNamespace:
    body = RobotNoticeBody(event=event, action="follow", grasp_id=grasp_id, reason=f"{event} reason")
    return SimpleNamespace(type="robot_notice", t_capture_s=0.0, fields=body)


def test_a_display_without_a_modulus_is_felt_at_its_soft_end_unless_it_showed_unknown():
    assert display_felt_pa(2e5, unknown=False, e_soft_pa=5e3) == 2e5
    assert display_felt_pa(None, unknown=False, e_soft_pa=5e3) == 5e3  # stiffness 0: free, the soft end
    assert display_felt_pa(None, unknown=False, e_soft_pa=None) is None
    assert display_felt_pa(2e5, unknown=True, e_soft_pa=5e3) is None
    assert display_felt_pa(None, unknown=True, e_soft_pa=5e3) is None


def test_the_display_track_keeps_the_soft_end_for_a_free_display_and_none_for_unknown():
    duck = outcome("duck", 1e6, None, None, None, display_range=RANGE_PA)
    duck.observe(_message("display", 10.0, phase="active", unknown=False, E_pa=None))
    duck.observe(_message("display", 10.1, phase="active", unknown=True, E_pa=3e5))
    duck.observe(_message("display", 10.2, phase="active", unknown=False, E_pa=8e5))
    assert duck.display_track == [(10.0, 5e3), (10.1, None), (10.2, 8e5)]
    no_range = outcome("duck", 1e6, None, None, None)
    no_range.observe(_message("display", 10.0, phase="active", unknown=False, E_pa=None))
    assert no_range.display_track == [(10.0, None)]


def test_contact_is_the_first_sample_at_the_contact_force_and_later_messages_do_not_move_it():
    duck = outcome("duck", 1e6, None, None, None)
    duck.contact_force_n = 1.0
    duck.observe(_message("force", t_s=np.array([10.0, 10.1, 10.2]), value_n=np.array([0.5, 1.0, 2.0])))
    assert duck.t_contact_s == 10.1  # at the contact force exactly: contact
    duck.observe(_message("force", t_s=np.array([11.0]), value_n=np.array([3.0])))
    assert duck.t_contact_s == 10.1


def test_the_first_notice_that_ends_the_grasp_is_kept_and_another_grasps_is_not():
    grasp = outcome("duck", 1e6, None, None, None)
    grasp.observe(_notice("watchdog", "other"))  # another grasp's
    assert grasp.ended_by is None
    grasp.observe(_notice("force_limit", "g"))  # leaves the grasp running
    assert grasp.ended_by is None
    grasp.observe(_notice("watchdog", "g"))
    grasp.observe(_notice("device", "g"))
    assert grasp.ended_by is not None and grasp.ended_by.event == "watchdog"


def test_a_grasp_is_done_once_both_the_robot_and_the_estimator_ended_it():
    grasp = outcome("duck", 1e6, None, None, None)
    assert not grasp.done
    grasp.robot_ended = True
    assert not grasp.done
    grasp.robot_ended, grasp.estimator_ended = False, True
    assert not grasp.done
    grasp.robot_ended = True
    assert grasp.done


def test_the_renderers_report_of_a_free_display_wins_over_mapping_the_final():
    # The renderer showed the display free (fraction 0): that, not the final mapped here (1e6 Pa).
    duck = outcome("duck", 1e6, {"E_pa": 1e6, "state": "ok"}, 0.1, 150.0, display_range=RANGE_PA)
    duck.renderer_report = {"latency_ms": 150.0, "display_fraction": 0.0, "rigid": False, "unknown": False}
    assert duck.display_fraction == 0.0 and duck.display_e_pa == pytest.approx(RANGE_PA[0])
    assert display_cell(duck) == f"0.00 ~{RANGE_PA[0]:.3g}"


def test_the_renderers_report_says_rigid_and_unknown():
    steel = outcome("steel", 2e11, {"E_pa": 1e6, "state": "ok"}, 0.1, 150.0, display_range=RANGE_PA)
    steel.renderer_report = {"latency_ms": 150.0, "display_fraction": 1.0, "rigid": True, "unknown": False}
    assert steel.rendered.rigid and display_cell(steel) == f"rigid >={RANGE_PA[1]:.3g}"
    assert steel.to_json()["display_rigid"] is True
    refused = outcome("foam", 5e3, {"E_pa": 1e6, "state": "ok"}, 0.1, 150.0, display_range=RANGE_PA)
    refused.renderer_report = {"latency_ms": 150.0, "display_fraction": 0.0, "rigid": False, "unknown": True}
    assert refused.rendered.unknown and display_cell(refused) == "unknown"
    assert refused.display_fraction is None and refused.felt_log10_offset is None
    assert refused.to_json()["display_unknown"] is True


def test_a_final_whose_interval_spans_the_display_range_is_shown_unknown():
    vague = outcome("duck", 1e6, {"E_pa": 1e6, "interval_pa": [1e3, 1e8], "state": "ok"}, 0.1, None,
                    display_range=RANGE_PA)
    assert vague.rendered.unknown and display_cell(vague) == "unknown" and vague.display_fraction is None


def test_a_final_the_display_cannot_map_renders_nothing():
    # An interval whose low is above its high: no rendering, rather than an error in the closing table.
    broken = outcome("duck", 1e6, {"E_pa": 1e6, "interval_pa": [2e6, 1e5], "state": "ok"}, 0.1, None,
                     display_range=RANGE_PA)
    assert broken.rendered is None and display_cell(broken) == "-"
    assert broken.to_json()["display_fraction"] is None and broken.to_json()["display_rigid"] is None
    assert closing_table([broken]).splitlines()[-2] == "the display rendered none of 1 grasps"


def test_a_display_within_2x_before_the_contact_time_counts_as_felt_at_contact():
    # The load cell's contact sample can be captured after a display report already within 2x.
    duck = outcome("duck", 1e6, None, None, None, display_range=RANGE_PA)
    duck.t_contact_s, duck.display_track = 10.5, [(10.4, 9e5), (10.6, 1.1e6)]
    assert duck.t_felt_within_2x_s == 0.0


def test_the_json_gives_the_operators_style():
    operated = outcome("duck", 1e6, None, None, None)
    operated.style, operated.operator_style = "operator", "quick, firm, one pause"
    assert operated.to_json()["operator_style"] == "quick, firm, one pause"


def test_report_reader_reads_each_complete_line_once_and_skips_blank_lines(tmp_path):
    path = tmp_path / "r.jsonl"
    reader = ReportReader(path)
    path.write_text('{"grasp_id": "g1"}\n')
    assert reader.poll() == [{"grasp_id": "g1"}]
    with path.open("a") as fh:
        fh.write('\n{"grasp_id": "g2"}\n  \n')
    assert reader.poll() == [{"grasp_id": "g2"}]
    with path.open("a") as fh:
        fh.write('{"grasp_id": "g3"}\n')
    assert reader.poll() == [{"grasp_id": "g3"}]
    assert reader.poll() == []
    assert reader.records == [{"grasp_id": "g1"}, {"grasp_id": "g2"}, {"grasp_id": "g3"}]


def test_report_reader_skips_a_broken_line_naming_it_and_keeps_the_records_around_it(tmp_path, caplog):
    """A service killed mid-line and started again appends its next record to the torn one."""
    path = tmp_path / "r.jsonl"
    path.write_bytes(b'{"grasp_id": "g1"}\n{"grasp_id": "g2", "fin{"grasp_id": "g3"}\n[1, 2]\n\xff\n{"grasp_id": "g4"}\n')
    reader = ReportReader(path)
    with caplog.at_level("WARNING", logger="teleop.system.outcome"):
        assert reader.poll() == [{"grasp_id": "g1"}, {"grasp_id": "g4"}]
    assert f"{path} line 2: not a JSON object, skipped" in caplog.text
    assert f"{path} line 3: not a JSON object, skipped" in caplog.text
    assert f"{path} line 4: not a JSON object, skipped" in caplog.text
    with path.open("a") as fh:
        fh.write('{"grasp_id": "g5"}\n{\n')
    with caplog.at_level("WARNING", logger="teleop.system.outcome"):
        assert reader.poll() == [{"grasp_id": "g5"}]
    assert f"{path} line 7: not a JSON object, skipped" in caplog.text  # counted on from the first poll


def test_report_reader_returns_a_record_it_has_without_waiting(tmp_path, monkeypatch):
    path = tmp_path / "r.jsonl"
    path.write_text('{"grasp_id": "g1", "x": 1}\n')

    def no_wait(seconds):
        raise AssertionError(f"waited {seconds} s for a record already written")

    monkeypatch.setattr(outcome_module, "time", SimpleNamespace(monotonic=time.monotonic, sleep=no_wait))
    assert ReportReader(path).find("g1", timeout_s=60.0) == {"grasp_id": "g1", "x": 1}
