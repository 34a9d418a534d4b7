"""``teleop bench-latency``'s pieces: the latency summary, the frame baseline, and the figure (read on
the matplotlib objects)."""

from __future__ import annotations

import json
from pathlib import Path

import matplotlib.pyplot as plt
import pytest
from support.outcomes import fake_bench_latency, outcome

from estimator.settings import estimator_settings
from teleop.errors import TeleopError
from teleop.settings import default_settings_path, load_settings
from teleop.system.latency import (
    BASELINE_PRESS_DEPTH_M,
    baseline_figures,
    baseline_press,
    frame_baseline_ms,
    latency_summary,
    plot,
    slowest,
)


def _row(grasp_id: str, obj: str, latency_ms: float) -> dict:
    return {"grasp_id": grasp_id, "object": obj, "latency_ms": latency_ms, "decision_ms": latency_ms - 2.0,
            "final_compute_ms": 6.0, "delivery_ms": 2.0, "final_by": "loading_end"}


def test_latency_plot_names_each_bar_by_grasp_id_and_object_and_labels_the_x_axis(monkeypatch, tmp_path):
    rows = [_row("bench-001", "stress_ball", 10.4), _row("bench-002", "rubber_duck", 8.0),
            _row("bench-003", "stress_ball", 14.3)]
    monkeypatch.setattr(plt, "close", lambda *args, **kwargs: None)
    plot({"per_grasp": rows, "p50_ms": 10.4, "p99_ms": 14.2}, tmp_path / "latency.png")
    fig = plt.gcf()
    ax = fig.axes[0]
    ticks = [t.get_text() for t in ax.get_xticklabels()]
    assert len(set(ticks)) == 3  # the two stress_ball grasps are told apart
    for text, row in zip(ticks, rows, strict=True):
        assert row["grasp_id"] in text and row["object"] in text
    assert "grasp" in ax.get_xlabel()
    plt.close(fig)


def test_latency_plot_axis_reaches_three_times_the_median_of_slow_runs(monkeypatch, tmp_path):
    # runs near 100 ms are drawn whole, not cut at twice the 15 ms aim
    rows = [_row(f"bench-{i:03d}", "duck", latency_ms) for i, latency_ms in enumerate([90.0, 100.0, 110.0])]
    monkeypatch.setattr(plt, "close", lambda *args, **kwargs: None)
    plot({"per_grasp": rows, "p50_ms": 100.0, "p99_ms": 110.0}, tmp_path / "latency.png")
    fig = plt.gcf()
    try:
        assert fig.axes[0].get_ylim()[1] == 300.0
    finally:
        plt.close(fig)


def test_latency_summary_splits_decision_and_delivery():
    o1 = outcome("a", 1e6, {"E_pa": 1e6, "state": "ok"}, 0.1, 150.0, final_sent_s=10.14, t_last_loading_frame_s=10.0,
                 provisional_span_s=0.5, provisional=16)
    o2 = outcome("b", 1e6, {"E_pa": 1e6, "state": "ok"}, 0.1, 110.0, final_sent_s=20.1, t_last_loading_frame_s=20.0,
                 provisional_span_s=None, provisional=1)
    summary = latency_summary([o1, o2], [0.01, 0.02, 0.03])
    assert summary["p50_ms"] == pytest.approx(130.0) and summary["finals_measured"] == 2
    assert summary["provisional_hz"] == pytest.approx(15 / 0.5)
    assert summary["decision_p50_ms"] == pytest.approx(120.0) and summary["delivery_p50_ms"] == pytest.approx(10.0)
    assert summary["compute_p50_ms"] == pytest.approx(20.0)
    assert summary["loading_end_to_report_p50_ms"] is None and summary["finals_by"] == {}
    assert latency_summary([], [])["p99_ms"] is None
    # no grasp with two provisionals: the rate is unknown (printed "-"), not a stalled estimator's 0 Hz
    assert latency_summary([o2], [])["provisional_hz"] is None


def test_latency_summary_relates_marker_grasps_to_the_loading_end():
    # The fingers stopped at 9.98 s; the peak frame came at 10.0 s; the report 30 ms later.
    marked = outcome("a", 1e6, {"E_pa": 1e6, "state": "ok"}, 0.1, 30.0, final_sent_s=10.029,
                     t_last_loading_frame_s=10.0, t_loading_end_s=9.98, final_by="loading_end",
                     final_compute_s=0.004, provisional_span_s=0.5, provisional=16)
    settled = outcome("b", 1e6, {"E_pa": 1e6, "state": "ok"}, 0.1, 150.0, final_sent_s=20.14,
                      t_last_loading_frame_s=20.0, t_loading_end_s=None, final_by="settled",
                      final_compute_s=0.006, provisional_span_s=None, provisional=1)
    summary = latency_summary([marked, settled], [])
    assert summary["p50_ms"] == pytest.approx(90.0) and summary["finals_by"] == {"loading_end": 1, "settled": 1}
    assert summary["peak_frame_after_stop_p50_ms"] == pytest.approx(20.0)  # the marker grasp alone
    assert summary["loading_end_to_report_p99_ms"] == pytest.approx(50.0)
    assert summary["decision_p50_ms"] == pytest.approx((29.0 + 140.0) / 2)
    assert summary["final_compute_p99_ms"] == pytest.approx(5.98)


def test_latency_summary_keeps_each_grasp_and_names_the_slowest_with_where_the_time_went(tmp_path):
    fast = outcome("duck", 1e6, {"E_pa": 1e6, "state": "ok"}, 0.1, 12.0, final_sent_s=10.010,
                   t_last_loading_frame_s=10.0, final_by="loading_end", t_loading_end_s=9.99,
                   final_compute_s=0.006, provisional_span_s=0.5, provisional=16)
    slow = outcome("oak", 1e10, {"E_pa": 1e9, "state": "ok"}, 0.1, 160.0, final_sent_s=20.158,
                   t_last_loading_frame_s=20.0, final_by="loading_end", t_loading_end_s=20.02,
                   final_compute_s=0.008, provisional_span_s=0.5, provisional=16)
    lost = outcome("foam", 5e3, None, None, None, provisional_span_s=0.5, provisional=11)
    summary = latency_summary([fast, slow, lost], [])
    assert [r["object"] for r in summary["per_grasp"]] == ["duck", "oak"]  # measured grasps, run order
    assert (summary["finals_measured"], summary["grasps"]) == (2, 3)  # "2 of 3": the lost final counts as run
    row = summary["per_grasp"][1]
    assert row["decision_ms"] == pytest.approx(158.0) and row["final_compute_ms"] == pytest.approx(8.0)
    assert row["delivery_ms"] == pytest.approx(2.0) and row["final_by"] == "loading_end"
    assert summary["provisional_hz"] == pytest.approx(40 / 1.5)  # the unmeasured grasp's estimates count too
    lines = slowest(summary, count=1)
    assert len(lines) == 1 and "oak" in lines[0]
    assert "160.0 ms = 150.0 before the final computation + 8.0 computing it + 2.0 delivery" in lines[0]
    png = tmp_path / "latency.png"
    plot(summary, png)
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    with pytest.raises(TeleopError, match="no grasp has a measured final"):
        plot(latency_summary([lost], []), tmp_path / "none.png")


def test_the_frame_baseline_times_the_perception_of_a_press_the_estimator_sees():
    from estimator.measurements import measure_frame, resolve_calibration
    from estimator.perception.grid import depth_grid, frame_on_grid, grid_calibration

    settings = load_settings(default_settings_path())
    sensor, binning = settings.sensor(settings.sensing.finger), estimator_settings(settings).depth_binning
    calibration = resolve_calibration(sensor, None)
    pressed, untouched = baseline_press(settings)
    frame, reference = (frame_on_grid(data, "jpeg", sensor, binning=binning) for data in (pressed, untouched))
    _, features = measure_frame(frame, reference, grid_calibration(calibration, binning),
                                depth_grid(sensor, binning))
    # The timed frame is a real contact: its depth is the press's, within the simulator's optics.
    assert features.peak_depth_m[0] == pytest.approx(BASELINE_PRESS_DEPTH_M, rel=0.5)
    assert not features.touches_edge[0]
    times = frame_baseline_ms(settings, calibration, repeats=3)
    assert len(times) == 3 and all(0 < t < 10_000 for t in times)
    with pytest.raises(TeleopError, match="repeats 0"):
        frame_baseline_ms(settings, calibration, repeats=0)


def test_baseline_figures_are_the_medians_before_after_and_of_both():
    figures = baseline_figures([4.0, 5.0, 9.0], [6.0, 7.0, 8.0])
    assert figures == {"frame_baseline_ms": 6.5, "frame_baseline_before_ms": 5.0, "frame_baseline_after_ms": 7.0}
    with pytest.raises(TeleopError, match="before and after"):
        baseline_figures([], [1.0])


def _measured() -> list:
    return [outcome("stress_ball", 1e6, {"E_pa": 1e6, "state": "ok"}, 0.1, 12.0, final_sent_s=10.01,
                    t_last_loading_frame_s=10.0, final_compute_s=0.006, final_by="settled")]


def test_a_plot_that_cannot_be_written_loses_no_results_and_leaves_no_truncated_png(monkeypatch, tmp_path, capsys):
    import errno

    import matplotlib.figure

    from teleop.cli import main

    formats = []

    def full_disk(self, fname, **kwargs):
        formats.append(kwargs.get("format"))
        Path(fname).write_bytes(b"\x89PNG\r\n")  # a start, then the file size limit
        raise OSError(errno.EFBIG, "File too large")

    fake_bench_latency(monkeypatch, tmp_path, _measured())
    monkeypatch.setattr(matplotlib.figure.Figure, "savefig", full_disk)
    png = tmp_path / "latency.png"
    code = main(["bench-latency", "--grasps", "1", "--json", "--plot", str(png)])
    out, err = capsys.readouterr()
    assert code == 2
    assert json.loads(out.strip().splitlines()[-1])["finals_measured"] == 1  # the results are out
    assert f"teleop bench-latency: error: --plot {png}: File too large" in err
    assert formats == ["png"]  # told, since the temporary's name does not end in .png
    assert sorted(p.name for p in tmp_path.iterdir()) == []  # no truncated PNG, no temporary


def test_a_run_without_a_measured_final_prints_its_results_before_the_plot_error(monkeypatch, tmp_path, capsys):
    from teleop.cli import main

    fake_bench_latency(monkeypatch, tmp_path, [])
    png = tmp_path / "latency.png"
    code = main(["bench-latency", "--grasps", "1", "--json", "--plot", str(png)])
    out, err = capsys.readouterr()
    assert code == 2
    assert json.loads(out.strip().splitlines()[-1])["finals_measured"] == 0
    assert "no grasp has a measured final estimate to draw" in err and not png.exists()
