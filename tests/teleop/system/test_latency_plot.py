"""The latency figure of ``teleop bench-latency --plot``, read on the matplotlib objects."""

from __future__ import annotations

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from teleop.system.latency import plot  # noqa: E402


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
