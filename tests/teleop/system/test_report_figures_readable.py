"""``teleop report``'s figures read as they should: the timeline zooms on a short loading phase and
keeps refusals off the modulus axis, the tactile depth is given in micrometres, and the predictions'
legend lists only the states drawn, under the session's name, with the display's range."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

import teleop.system.report_figures as figures
from teleop.system.report_data import MOMENTS, EstimatePoint, GraspView, TactileMoment

ONSET_S, PEAK_S = 7.0, 7.5  # since the grasp's start: 7 s of approach, 0.5 s of loading


def _series(t_s: np.ndarray, value: np.ndarray) -> SimpleNamespace:
    return SimpleNamespace(t_s=t_s, value=value)


def _view() -> GraspView:
    """A scripted-like grasp: 7 s of approach at zero force, 0.5 s of loading, a hold; estimates
    during loading, two of them refusals."""
    t = np.linspace(0.0, 9.0, 901)
    force = np.clip((t - ONSET_S) / (PEAK_S - ONSET_S), 0.0, 1.0) * 20.0
    record = SimpleNamespace(force_n=_series(100.0 + t, force), width_m=_series(100.0 + t, 0.08 - 0.006 * t),
                             events={})
    view = GraspView("g-1", object_name="rubber_duck", record=record, label_pa=3e6, start_s=100.0)
    view.segment = SimpleNamespace(t_onset_s=100.0 + ONSET_S, t_peak_s=100.0 + PEAK_S)
    view.estimates = [EstimatePoint(107.1, None, (None, None), "refused", "too little force", True, "auto"),
                      EstimatePoint(107.2, None, (None, None), "refused", "too little force", True, "auto"),
                      EstimatePoint(107.3, 2e6, (1e6, 4e6), "ok", "test", True, "auto"),
                      EstimatePoint(107.6, 2.5e6, (2e6, 3e6), "ok", "test", False, "auto")]
    return view


def _x_markers(ax) -> int:
    return sum(len(line.get_xdata()) for line in ax.get_lines() if line.get_marker() == "x")


def test_the_timeline_zooms_on_a_short_loading_phase(drawn, tmp_path):
    figures.timeline_figure(_view(), tmp_path / "t.png", display_recorded=False)
    (fig,) = drawn
    zoomed = [ax for ax in fig.axes if ax.get_xlim()[1] - ax.get_xlim()[0] < 2.0]
    assert zoomed, [ax.get_xlim() for ax in fig.axes]
    for ax in zoomed:
        assert ax.get_xlim() == pytest.approx((ONSET_S - 0.2, PEAK_S + 0.5))
    assert any("zoom" in ax.get_title() for ax in zoomed)
    # the whole grasp stays drawn beside it
    assert any(ax.get_xlim()[0] < 0.5 and ax.get_xlim()[1] > 8.5 for ax in fig.axes)


def test_refusals_are_not_drawn_on_the_modulus_axis(drawn, tmp_path):
    figures.timeline_figure(_view(), tmp_path / "t.png", display_recorded=False)
    (fig,) = drawn
    moduli = [ax for ax in fig.axes if ax.get_yscale() == "log"]
    assert moduli and all(_x_markers(ax) == 0 for ax in moduli)
    strips = [ax for ax in fig.axes if ax.get_ylabel() == "refused" or _x_markers(ax)]
    assert strips and all(ax.get_yscale() == "linear" and not ax.get_yticks().size for ax in strips)
    assert any(_x_markers(ax) == 2 for ax in strips)
    assert any(ax.get_ylabel() == "refused" for ax in strips)


def test_tactile_depths_are_titled_in_micrometres(drawn, tmp_path):
    depth = np.zeros((20, 30))
    depth[8:12, 10:20] = 7.5e-6  # a soft object's 7.5 µm dent
    view = _view()
    view.moments = [TactileMoment("left", name, 107.0 + k * 0.2, 5.0 * k, np.zeros((20, 30, 3), np.uint8),
                                  depth * k) for k, name in enumerate(MOMENTS)]
    figures.tactile_figure(view, tmp_path / "tactile.png")
    (fig,) = drawn
    titles = [ax.get_title() for ax in fig.axes if ax.get_title().startswith("depth")]
    assert titles == [f"depth, max {7.5 * k:.1f} µm" for k in range(len(MOMENTS))]
    assert any(ax.get_ylabel() == "depth (µm)" for ax in fig.axes)  # the colour bar's


def _predicted() -> list[GraspView]:
    views = []
    for k, state in enumerate(("ok", "lower_bound", "ok")):
        view = GraspView(f"g-{k}", object_name=f"object {k}", label_pa=1e5 * 10 ** k)
        view.estimates.append(EstimatePoint(1.0, 2e5 * 10 ** k, (1e5 * 10 ** k, None if k == 1 else 4e5 * 10 ** k),
                                            state, "test", False, "auto"))
        views.append(view)
    return views


def test_the_predictions_legend_lists_only_the_states_drawn(drawn, tmp_path):
    figures.predictions_figure(_predicted(), tmp_path / "p.png")
    (fig,) = drawn
    legend = [text.get_text() for text in fig.axes[0].get_legend().get_texts()]
    assert "upper_bound" not in legend and {"ok", "lower_bound"} <= set(legend)


def test_the_predictions_name_the_session_and_draw_the_display_range(drawn, tmp_path):
    figures.predictions_figure(_predicted(), tmp_path / "p.png", session="session.mcap",
                               display_range_pa=(1e4, 1e7))
    (fig,) = drawn
    (ax,) = fig.axes
    assert ax.get_title().startswith("session.mcap: ")
    assert "display range" in [text.get_text() for text in ax.get_legend().get_texts()]
    dashed = sorted(line.get_ydata()[0] for line in ax.get_lines() if line.get_linestyle() == "--")
    assert dashed == [1e4, 1e7]
