"""``teleop bench-latency``'s figures at their edges: grasps without a measured final or without a part
of their report, the count of finals by trigger, the slowest lines, the figure's axis, aim and cut bars,
and the command's output (stdout the JSON alone under ``--json``, the latency in frame baselines)."""

from __future__ import annotations

import json

import matplotlib.pyplot as plt
import pytest
from support.outcomes import fake_bench_latency, outcome

from teleop.system.latency import P99_AIM_MS, latency_summary, plot, slowest


def _measured(name: str, latency_ms: float, **report):
    return outcome(name, 1e6, {"E_pa": 1e6, "state": "ok"}, 0.1, latency_ms, **report)


def test_finals_are_counted_by_trigger_and_a_zero_compute_time_is_a_time():
    grasps = [_measured("a", 20.0, final_by="loading_end", final_compute_s=0.0),
              _measured("b", 30.0, final_by="loading_end", final_compute_s=0.004),
              _measured("c", 40.0, final_by="grasp_end")]
    summary = latency_summary(grasps, [])
    assert summary["finals_by"] == {"loading_end": 2, "grasp_end": 1}
    assert [r["final_compute_ms"] for r in summary["per_grasp"]] == [0.0, 4.0, None]
    assert summary["final_compute_p50_ms"] == pytest.approx(2.0)


def test_a_grasp_without_a_measured_final_does_not_stop_the_later_ones_being_measured():
    lost = outcome("foam", 5e3, None, None, None, final_by="grasp_end")
    later = _measured("duck", 25.0, final_sent_s=10.02, t_last_loading_frame_s=10.0)
    summary = latency_summary([lost, later], [])
    assert [r["object"] for r in summary["per_grasp"]] == ["duck"] and summary["finals_measured"] == 1
    assert summary["p50_ms"] == pytest.approx(25.0) and summary["decision_p50_ms"] == pytest.approx(20.0)
    assert summary["finals_by"] == {"grasp_end": 1}  # its trigger still counts


def test_only_grasps_the_marker_ended_relate_to_the_loading_end():
    # A final taken once the force settled, with a marker after it: not a marker grasp.
    settled = _measured("a", 50.0, final_sent_s=10.04, t_last_loading_frame_s=10.0, t_loading_end_s=9.9,
                        final_by="settled")
    summary = latency_summary([settled], [])
    assert summary["peak_frame_after_stop_p50_ms"] is None and summary["loading_end_to_report_p50_ms"] is None


def test_a_grasp_without_the_time_its_final_was_sent_has_no_decision_and_no_delivery():
    unsent = _measured("a", 30.0, t_last_loading_frame_s=10.0, final_compute_s=0.005)
    sent = _measured("b", 20.0, final_sent_s=20.015, t_last_loading_frame_s=20.0, final_compute_s=0.005)
    summary = latency_summary([unsent, sent], [])
    assert [(r["decision_ms"], r["delivery_ms"]) for r in summary["per_grasp"]][0] == (None, None)
    assert summary["decision_p50_ms"] == pytest.approx(15.0) and summary["decision_p99_ms"] == pytest.approx(15.0)
    assert summary["delivery_p50_ms"] == pytest.approx(5.0)
    assert summary["p50_ms"] == pytest.approx(25.0)  # its latency still counts


def test_the_slowest_lines_of_grasps_without_the_split_or_the_trigger():
    unsent = _measured("a", 30.0, t_last_loading_frame_s=10.0, final_compute_s=0.005)
    uncomputed = _measured("b", 20.0, final_sent_s=20.015, t_last_loading_frame_s=20.0)
    lines = slowest(latency_summary([unsent, uncomputed], []))
    assert lines == ["  g (a, final by ?): 30.0 ms", "  g (b, final by ?): 20.0 ms"]


def _row(grasp_id: str, latency_ms: float, *, decided: bool = True) -> dict:
    return {"grasp_id": grasp_id, "object": "duck", "latency_ms": latency_ms,
            "decision_ms": latency_ms - 2.0 if decided else None, "final_compute_ms": 1.0,
            "delivery_ms": 2.0 if decided else None, "final_by": "loading_end"}


def _drawn(monkeypatch, tmp_path, rows: list[dict], p50_ms: float):
    monkeypatch.setattr(plt, "close", lambda *args, **kwargs: None)
    plot({"per_grasp": rows, "p50_ms": p50_ms, "p99_ms": max(r["latency_ms"] for r in rows)}, tmp_path / "l.png")
    return plt.gcf()


def test_the_figure_of_fast_runs_reaches_twice_the_aim_and_draws_the_aim(monkeypatch, tmp_path):
    fig = _drawn(monkeypatch, tmp_path, [_row("bench-001", 4.0), _row("bench-002", 5.0)], 4.5)
    try:
        ax = fig.axes[0]
        assert ax.get_ylim() == (0.0, 2 * P99_AIM_MS)
        assert [list(line.get_ydata()) for line in ax.get_lines()] == [[P99_AIM_MS, P99_AIM_MS]]
    finally:
        plt.close(fig)


def test_the_figure_cuts_a_bar_above_its_axis_and_labels_it_and_leaves_out_undecided_grasps(monkeypatch,
                                                                                             tmp_path):
    rows = [_row("bench-001", 5.0), _row("bench-002", 6.0), _row("bench-003", 250.0),
            _row("bench-004", 40.0, decided=False)]
    fig = _drawn(monkeypatch, tmp_path, rows, 6.0)
    try:
        ax = fig.axes[0]
        assert [t.get_text() for t in ax.get_xticklabels()] == [f"bench-00{i} duck" for i in (1, 2, 3)]
        assert ax.get_ylim() == (0.0, 30.0)
        assert [(a.get_text(), a.xy) for a in ax.texts] == [("250", (2, 30.0))]
    finally:
        plt.close(fig)


def test_a_plot_is_written_in_the_format_its_name_ends_in(tmp_path):
    rows = [_row("bench-001", 5.0)]
    plot({"per_grasp": rows, "p50_ms": 5.0, "p99_ms": 5.0}, tmp_path / "latency.svg")
    plot({"per_grasp": rows, "p50_ms": 5.0, "p99_ms": 5.0}, tmp_path / "latency.pdf")
    assert b"<svg" in (tmp_path / "latency.svg").read_bytes()[:1000]
    assert (tmp_path / "latency.pdf").read_bytes()[:5] == b"%PDF-"


def test_under_json_stdout_is_the_json_alone_with_the_latency_in_frame_baselines(monkeypatch, tmp_path, capsys):
    from teleop.cli import main

    fake_bench_latency(monkeypatch, tmp_path, [_measured("a", 11.0, final_sent_s=10.009, t_last_loading_frame_s=10.0),
                                        _measured("b", 22.0, final_sent_s=20.02, t_last_loading_frame_s=20.0)])
    assert main(["bench-latency", "--grasps", "2", "--json"]) == 0
    out, err = capsys.readouterr()
    assert len(out.strip().splitlines()) == 1
    summary = json.loads(out)
    assert summary["frame_baseline_ms"] == 5.5
    assert summary["p50_in_baselines"] == pytest.approx(16.5 / 5.5)
    assert summary["p99_in_baselines"] == pytest.approx(summary["p99_ms"] / 5.5)
    assert "2 of 2 final estimates measured on the display" in err and "the latency in those frames" in err


def test_without_a_measured_final_the_latency_in_baselines_is_null(monkeypatch, tmp_path, capsys):
    from teleop.cli import main

    fake_bench_latency(monkeypatch, tmp_path, [outcome("foam", 5e3, None, None, None)])
    assert main(["bench-latency", "--grasps", "1", "--json"]) == 0
    out, err = capsys.readouterr()
    summary = json.loads(out)
    assert (summary["p50_in_baselines"], summary["p99_in_baselines"]) == (None, None)
    assert "the latency in those frames" not in err and "slowest grasps" not in err


def test_no_grasps_to_run_is_refused_before_anything_starts(monkeypatch, tmp_path, capsys):
    import teleop.system.latency as latency
    from teleop.cli import main

    fake_bench_latency(monkeypatch, tmp_path, [])

    def started(*args, **kwargs):
        raise AssertionError("the run was prepared")

    monkeypatch.setattr(latency, "prepare_run", started)
    assert main(["bench-latency", "--grasps", "0"]) == 2
    assert "teleop bench-latency: error: --grasps 0: expected at least 1" in capsys.readouterr().err
