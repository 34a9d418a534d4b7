"""``teleop report``'s figures, read back from matplotlib: the frames' colours, the modulus axis's
reach, the display's modulus drawn over the estimates, the legend, one finger's moments marked, and
the predictions plot's points and names."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
from matplotlib.colors import to_rgba

import teleop.system.report_figures as figures
from teleop.system.report_data import MOMENTS, DisplayPoint, EstimatePoint, GraspView, TactileMoment

T0, ONSET_S, PEAK_S = 100.0, 7.0, 7.5


def _series(t_s: np.ndarray, value: np.ndarray) -> SimpleNamespace:
    return SimpleNamespace(t_s=t_s, value=value)


def _view(*, onset_s: float = ONSET_S) -> GraspView:
    """9 s of a grasp, loading from ``onset_s`` to 7.5 s; a provisional and a final estimate."""
    t = np.linspace(0.0, 9.0, 901)
    force = np.clip((t - onset_s) / (PEAK_S - onset_s), 0.0, 1.0) * 20.0
    record = SimpleNamespace(force_n=_series(T0 + t, force), width_m=_series(T0 + t, 0.08 - 0.006 * t), events={})
    view = GraspView("g-1", object_name="rubber_duck", record=record, label_pa=3e6, start_s=T0)
    view.segment = SimpleNamespace(t_onset_s=T0 + onset_s, t_peak_s=T0 + PEAK_S)
    view.estimates = [EstimatePoint(T0 + 7.3, 2e6, (1e6, 4e6), "ok", "test", True, "series"),
                      EstimatePoint(T0 + 7.6, 2.5e6, (2e6, 3e6), "ok", "test", False, "auto")]
    return view


def _moduli(fig):
    """The estimates panels (log y axes), the whole grasp's first."""
    return [ax for ax in fig.axes if ax.get_yscale() == "log"]


def _moments(finger: str, t0_s: float) -> list[TactileMoment]:
    return [TactileMoment(finger, name, t0_s + 0.25 * k, 5.0 * k, np.zeros((4, 6, 3), np.uint8), None)
            for k, name in enumerate(MOMENTS)]


# --------------------------------------------------------------------------- tactile


def test_a_tactile_frame_stored_as_bgr_is_shown_in_its_own_colours(drawn, tmp_path):
    view = _view()
    blue = np.zeros((4, 6, 3), np.uint8)
    blue[..., 0] = 255  # blue, in OpenCV's BGR order
    view.moments = [TactileMoment("left", name, T0 + 7.0, 1.0, blue, None) for name in MOMENTS]
    figures.tactile_figure(view, tmp_path / "tactile.png")
    (fig,) = drawn
    frames = [ax.get_images()[0].get_array() for ax in fig.axes if ax.get_title().startswith("left:")]
    assert len(frames) == len(MOMENTS)
    for shown in frames:  # drawn as RGB: the blue channel last
        assert (shown[..., 2] == 255).all() and (shown[..., 0] == 0).all()


# --------------------------------------------------------------------------- timeline


def test_the_modulus_axis_reaches_the_label_and_the_displays_modulus_beyond_the_estimates(drawn, tmp_path):
    view = _view()
    view.label_pa = 2e9  # far above every estimate
    view.display = [DisplayPoint(T0 + 7.6, "active", 0.1, 1e4, False, False, False)]  # far below
    figures.timeline_figure(view, tmp_path / "t.png", display_recorded=True)
    (fig,) = drawn
    assert _moduli(fig)[0].get_ylim() == pytest.approx((1e4 / 3, 2e9 * 3))


def test_the_displays_modulus_is_a_held_step_broken_where_it_rendered_none(drawn, tmp_path):
    view = _view()
    view.display = [DisplayPoint(T0 + 7.6, "active", 0.4, 2.5e6, False, False, False),
                    DisplayPoint(T0 + 8.0, "active", 0.0, None, False, True, False),
                    DisplayPoint(T0 + 8.2, "active", 0.5, 3e6, False, False, False)]
    figures.timeline_figure(view, tmp_path / "t.png", display_recorded=True)
    (fig,) = drawn
    ax = _moduli(fig)[0]
    (step,) = [line for line in ax.get_lines() if len(line.get_xdata()) == 3 and line.get_color() == "C1"]
    assert step.get_drawstyle() == "steps-post"
    assert np.allclose(step.get_xdata(), [7.6, 8.0, 8.2])
    y = np.asarray(step.get_ydata(), float)
    assert y[0] == 2.5e6 and np.isnan(y[1]) and y[2] == 3e6
    (legend,) = [a.get_legend() for a in _moduli(fig) if a.get_legend() is not None]
    assert "display ~E" in [text.get_text() for text in legend.get_texts()]


def test_the_display_panel_holds_each_rendering_until_the_next_message(drawn, tmp_path):
    view = _view()
    view.display = [DisplayPoint(T0 + 7.6, "active", 0.4, 2.5e6, False, False, False),
                    DisplayPoint(T0 + 8.0, "fading", 0.0, None, False, False, False)]
    figures.timeline_figure(view, tmp_path / "t.png", display_recorded=True)
    (fig,) = drawn
    ax = next(ax for ax in fig.axes if ax.get_ylabel().startswith("display"))
    (line,) = [line for line in ax.get_lines() if line.get_color() == "C1"]
    assert line.get_drawstyle() == "steps-post" and list(line.get_ydata()) == [0.4, 0.0]


def test_display_messages_are_not_drawn_when_the_log_is_said_not_to_record_them(drawn, tmp_path):
    view = _view()
    view.display = [DisplayPoint(T0 + 7.6, "active", 0.4, 2.5e6, False, False, False)]
    figures.timeline_figure(view, tmp_path / "t.png", display_recorded=False)
    (fig,) = drawn
    assert not any(ax.get_ylabel().startswith("display") for ax in fig.axes)


def test_the_timeline_legend_lists_the_states_drawn_the_refusals_and_the_final_once(drawn, tmp_path):
    view = _view()
    view.estimates.insert(0, EstimatePoint(T0 + 7.1, None, (None, None), "insufficient_data", "why", True, "auto"))
    figures.timeline_figure(view, tmp_path / "t.png", display_recorded=False)
    (fig,) = drawn
    legends = [ax.get_legend() for ax in fig.axes if ax.get_legend() is not None]
    assert len(legends) == 1  # above the zoomed column only
    assert [text.get_text() for text in legends[0].get_texts()] == ["ok", "refused (strip below)", "final (big)"]
    zoomed = next(ax for ax in _moduli(fig) if ax.get_legend() is not None)
    assert zoomed.get_xlim() == pytest.approx((ONSET_S - 0.2, PEAK_S + 0.5))


def test_only_the_first_fingers_moments_are_marked_on_the_timeline(drawn, tmp_path):
    view = _view(onset_s=2.0)  # not zoomed: one column
    view.moments = _moments("left", T0 + 7.0) + _moments("right", T0 + 7.02)
    figures.timeline_figure(view, tmp_path / "t.png", display_recorded=False)
    (fig,) = drawn
    for ax in fig.axes:
        dotted = [line for line in ax.get_lines() if line.get_linestyle() == ":"]
        assert sorted(round(float(line.get_xdata()[0]), 3) for line in dotted) == [7.0, 7.25, 7.5]


def test_the_loading_phase_is_shaded_in_seconds_since_the_start_on_every_panel(drawn, tmp_path):
    figures.timeline_figure(_view(onset_s=2.0), tmp_path / "t.png", display_recorded=False)
    (fig,) = drawn
    for ax in fig.axes:
        (shaded,) = [p for p in ax.patches if to_rgba(p.get_facecolor()) == to_rgba(figures.LOADING_COLOUR)]
        xs = shaded.get_path().transformed(shaded.get_patch_transform()).vertices[:, 0]
        assert (xs.min(), xs.max()) == pytest.approx((2.0, PEAK_S))


# --------------------------------------------------------------------------- predictions


def _final(grasp_id: str, label_pa, e_pa, interval, state="ok", object_name=None) -> GraspView:
    view = GraspView(grasp_id, object_name=object_name, label_pa=label_pa)
    view.estimates.append(EstimatePoint(1.0, e_pa, interval, state, "test", False, "auto"))
    return view


def test_a_final_refusal_is_left_out_of_the_predictions_and_counted(drawn, tmp_path):
    views = [_final("a", 1e5, 2e5, (1e5, 4e5)), _final("b", 1e6, None, (None, None), "insufficient_data")]
    figures.predictions_figure(views, tmp_path / "p.png")
    (fig,) = drawn
    (ax,) = fig.axes
    points = [line for line in ax.get_lines() if len(line.get_xdata()) == 1]
    assert [(float(p.get_xdata()[0]), float(p.get_ydata()[0])) for p in points] == [(1e5, 2e5)]
    assert "1 grasps" in ax.get_title() and "1 without a label or estimate left out" in ax.get_title()


def test_predictions_are_named_by_their_object_else_their_grasp_id(drawn, tmp_path):
    views = [_final("g-1", 1e5, 2e5, (1e5, 4e5), object_name="duck"), _final("g-2", 1e6, 2e6, (1e6, 4e6))]
    figures.predictions_figure(views, tmp_path / "p.png")
    (fig,) = drawn
    assert [text.get_text() for text in fig.axes[0].texts] == ["duck", "g-2"]
