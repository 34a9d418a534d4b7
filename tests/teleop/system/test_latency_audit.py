"""``teleop bench-latency`` (teleop.system.latency) where its other tests leave off: the frame baseline's
timing, the figures of grasps missing a time, the figure's bars, and what the command passes and prints."""

from __future__ import annotations

import json

import matplotlib.pyplot as plt
import numpy as np
import pytest
from support.outcomes import fake_bench_latency, outcome

import teleop.system.latency as latency
from teleop.cli import main
from teleop.settings import default_settings_path, load_settings
from teleop.system.latency import frame_baseline_ms, latency_summary, plot


def _measured(name: str, latency_ms: float, **report):
    return outcome(name, 1e6, {"E_pa": 1e6, "state": "ok"}, 0.1, latency_ms, **report)


# --------------------------------------------------------------------------- the frame baseline


def test_the_frame_baseline_times_each_pressed_frame_in_milliseconds(monkeypatch):
    import estimator.measurements
    from estimator.measurements import resolve_calibration

    settings = load_settings(default_settings_path())
    calibration = resolve_calibration(settings.sensor(settings.sensing.finger), None)
    measured = []
    monkeypatch.setattr(estimator.measurements, "measure_frame", lambda *args: measured.append(args))
    ticks = iter(range(100))
    monkeypatch.setattr(latency.time, "perf_counter", lambda: 0.004 * next(ticks))  # 4 ms a call
    times = frame_baseline_ms(settings, calibration, repeats=3)
    assert times == pytest.approx([4.0, 4.0, 4.0])
    assert len(measured) == 3
    frame, reference = measured[0][:2]
    assert frame is not reference and not np.array_equal(frame, reference)  # the press, against the untouched


def test_the_baseline_press_is_at_the_gels_centre(monkeypatch):
    import teleop.sim.presses

    settings = load_settings(default_settings_path())
    sensor = settings.sensor(settings.sensing.finger)
    rows, cols = sensor.image_shape
    assert rows != cols  # so that a centre with its axes swapped is told apart
    centres = []
    real = teleop.sim.presses.sphere_press_height

    def recorded(shape, *, center_px, **kwargs):
        centres.append(center_px)
        return real(shape, center_px=center_px, **kwargs)

    monkeypatch.setattr(teleop.sim.presses, "sphere_press_height", recorded)
    latency.baseline_press(settings)
    assert centres == [((cols - 1) / 2.0, (rows - 1) / 2.0)]  # (x, y)


# --------------------------------------------------------------------------- the summary


def test_a_grasp_with_its_final_sent_but_no_loading_frame_time_has_no_decision():
    summary = latency_summary([_measured("a", 30.0, final_sent_s=10.02, t_last_loading_frame_s=None,
                                         final_by="loading_end", t_loading_end_s=9.9)], [])
    row = summary["per_grasp"][0]
    assert (row["decision_ms"], row["delivery_ms"]) == (None, None) and summary["decision_p50_ms"] is None
    assert summary["peak_frame_after_stop_p50_ms"] is None and summary["p50_ms"] == pytest.approx(30.0)


# --------------------------------------------------------------------------- the figure


def _row(grasp_id: str, latency_ms: float, compute_ms: float = 1.0, delivery_ms: float = 2.0) -> dict:
    return {"grasp_id": grasp_id, "object": "duck", "latency_ms": latency_ms, "decision_ms": latency_ms - delivery_ms,
            "final_compute_ms": compute_ms, "delivery_ms": delivery_ms, "final_by": "loading_end"}


def _figure(monkeypatch, tmp_path, rows, p50_ms):
    monkeypatch.setattr(plt, "close", lambda *args, **kwargs: None)
    plot({"per_grasp": rows, "p50_ms": p50_ms, "p99_ms": max(r["latency_ms"] for r in rows)}, tmp_path / "l.png")
    return plt.gcf()


def test_each_bar_stacks_before_the_computation_the_computation_and_the_delivery(monkeypatch, tmp_path):
    fig = _figure(monkeypatch, tmp_path, [_row("bench-001", 10.0, compute_ms=3.0, delivery_ms=2.0)], 10.0)
    try:
        bars = [(p.get_y(), p.get_height()) for p in fig.axes[0].patches]
        assert bars == [pytest.approx((0.0, 5.0)), pytest.approx((5.0, 3.0)), pytest.approx((8.0, 2.0))]
    finally:
        plt.close(fig)


def test_a_bar_reaching_the_top_of_the_axis_exactly_is_not_labelled_as_cut(monkeypatch, tmp_path):
    fig = _figure(monkeypatch, tmp_path, [_row("bench-001", 5.0), _row("bench-002", 6.0), _row("bench-003", 30.0)], 6.0)
    try:
        assert fig.axes[0].get_ylim() == (0.0, 30.0) and list(fig.axes[0].texts) == []
    finally:
        plt.close(fig)


def test_a_plot_leaves_no_figure_open(tmp_path):
    before = set(plt.get_fignums())
    plot({"per_grasp": [_row("bench-001", 5.0)], "p50_ms": 5.0, "p99_ms": 5.0}, tmp_path / "l.png")
    assert set(plt.get_fignums()) == before


# --------------------------------------------------------------------------- the command


def _bench(monkeypatch, tmp_path, outcomes, *argv: str) -> dict:
    """``teleop bench-latency --json`` on ``outcomes``; what it passed on, by name."""
    fake_bench_latency(monkeypatch, tmp_path, outcomes)
    seen: dict = {}

    class System:
        def __init__(self, *args, **kwargs):
            seen["system"] = kwargs

        def __enter__(self):
            return self

        def __exit__(self, *exc):
            return None

    def grasps(system, plan, view, prefix, *, on_message):
        seen["plan"] = plan
        for kind, seconds in (("estimate", 0.010), ("report", 0.5), ("estimate", 0.030)):
            on_message(type("Message", (), {"type": kind, "fields": type("F", (), {"latency_s": seconds})})())
        return iter(outcomes)

    def prepare(args, *, prefix, out):
        seen["prefix"] = prefix
        return tmp_path / "run", tmp_path / "cal.npz"

    baselines = iter([[5.0], [7.0]])  # before the run, after it
    monkeypatch.setattr(latency, "LiveSystem", System)
    monkeypatch.setattr(latency, "run_grasps", grasps)
    monkeypatch.setattr(latency, "prepare_run", prepare)
    monkeypatch.setattr(latency, "frame_baseline_ms", lambda *args, **kwargs: next(baselines))
    seen["code"] = main(["bench-latency", "--json", *argv])
    return seen


def test_the_estimates_seen_give_the_compute_time_and_other_messages_do_not(monkeypatch, tmp_path, capsys):
    _bench(monkeypatch, tmp_path, [_measured("a", 12.0)], "--grasps", "1")
    summary = json.loads(capsys.readouterr().out)
    assert summary["compute_p50_ms"] == pytest.approx(20.0) and summary["compute_p99_ms"] == pytest.approx(29.8)


def test_the_baselines_before_and_after_the_run_are_both_measured_and_the_latency_is_in_their_median(
        monkeypatch, tmp_path, capsys):
    _bench(monkeypatch, tmp_path, [_measured("a", 12.0)], "--grasps", "1")
    summary = json.loads(capsys.readouterr().out)
    assert (summary["frame_baseline_before_ms"], summary["frame_baseline_after_ms"]) == (5.0, 7.0)
    assert summary["frame_baseline_ms"] == 6.0 and summary["p50_in_baselines"] == pytest.approx(2.0)


@pytest.mark.parametrize("record", [False, True])
def test_the_run_is_of_the_grasps_asked_for_recorded_only_when_asked(monkeypatch, tmp_path, capsys, record):
    seen = _bench(monkeypatch, tmp_path, [_measured("a", 12.0)], "--grasps", "3", *(["--record"] if record else []))
    capsys.readouterr()
    assert seen["code"] == 0 and len(seen["plan"]) == 3
    assert seen["system"]["record"] is record and seen["prefix"] == "bench-latency"


def test_a_plot_name_of_another_format_is_refused_before_anything_runs(monkeypatch, tmp_path, capsys):
    def started(*args, **kwargs):
        raise AssertionError("the run was prepared")

    fake_bench_latency(monkeypatch, tmp_path, [])
    monkeypatch.setattr(latency, "prepare_run", started)
    assert main(["bench-latency", "--grasps", "1", "--plot", str(tmp_path / "latency.txt")]) == 2
    assert "--plot" in capsys.readouterr().err and not (tmp_path / "latency.txt").exists()


def test_a_grasp_without_its_final_computation_time_is_left_out_of_the_figure(monkeypatch, tmp_path):
    uncomputed = {**_row("bench-002", 40.0), "final_compute_ms": None}
    fig = _figure(monkeypatch, tmp_path, [_row("bench-001", 5.0), uncomputed], 5.0)
    try:
        assert [t.get_text() for t in fig.axes[0].get_xticklabels()] == ["bench-001 duck"]
    finally:
        plt.close(fig)
