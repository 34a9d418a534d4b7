"""What ``teleop report``'s figures draw, read back from the matplotlib figures: the tactile sheet's
times, forces and depth scale, the timeline's panels, units, label, intervals, marks and zoom, and the
predictions plot's axes, points, band and limits; and that a figure's size is the PNG's."""

from __future__ import annotations

from types import SimpleNamespace

import cv2
import numpy as np
import pytest
from matplotlib.colors import to_rgba
from matplotlib.figure import Figure

import teleop.system.report_figures as figures
from teleop.record import GRASP_DONE_EVENT
from teleop.system.report_data import MOMENTS, DisplayPoint, EstimatePoint, GraspView, TactileMoment

T0, ONSET_S, PEAK_S, DONE_S = 100.0, 7.0, 7.5, 7.6  # the grasp's start; since it: contact, peak, gripper done


def _series(t_s: np.ndarray, value: np.ndarray) -> SimpleNamespace:
    return SimpleNamespace(t_s=t_s, value=value)


def _view(*, done: bool = True, onset_s: float = ONSET_S) -> GraspView:
    """9 s of a grasp: approach, 0.5 s of loading to 20 N, a hold; a provisional and a final estimate."""
    t = np.linspace(0.0, 9.0, 901)
    force = np.clip((t - onset_s) / (PEAK_S - onset_s), 0.0, 1.0) * 20.0
    events = {GRASP_DONE_EVENT: T0 + DONE_S} if done else {}
    record = SimpleNamespace(force_n=_series(T0 + t, force), width_m=_series(T0 + t, 0.08 - 0.006 * t), events=events)
    view = GraspView("g-1", object_name="rubber_duck", record=record, label_pa=3e6, start_s=T0)
    view.segment = SimpleNamespace(t_onset_s=T0 + onset_s, t_peak_s=T0 + PEAK_S)
    view.estimates = [EstimatePoint(T0 + 7.3, 2e6, (1e6, 4e6), "ok", "test", True, "series"),
                      EstimatePoint(T0 + 7.6, 2.5e6, (2e6, 3e6), "ok", "test", False, "auto")]
    return view


def _axis(fig: Figure, ylabel: str):
    return next(ax for ax in fig.axes if ax.get_ylabel() == ylabel)


def _moduli(fig: Figure):
    """The whole grasp's estimates panel (the first with a log y axis)."""
    return next(ax for ax in fig.axes if ax.get_yscale() == "log")


def _segments(ax) -> list[tuple[float, float, float]]:
    """The vertical bars of ``ax``: (x, low, high)."""
    out = []
    for collection in ax.collections:
        for segment in getattr(collection, "get_segments", list)():
            (x0, y0), (x1, y1) = segment[0], segment[-1]
            if x0 == x1:
                out.append((float(x0), float(min(y0, y1)), float(max(y0, y1))))
    return out


# --------------------------------------------------------------------------- tactile


def test_micrometres_switch_to_whole_numbers_at_100_and_never_read_minus_zero():
    assert figures._micrometres(99.94e-6) == "99.9 µm"
    assert figures._micrometres(100e-6) == "100 µm"
    assert figures._micrometres(1234.4e-6) == "1234 µm"
    assert figures._micrometres(-1e-8) == "0.0 µm"  # reconstruction noise just below the gel's surface


def _moments(depth_max_m: float | None, *, force_n=(-0.001, 6.0, 20.0)) -> list[TactileMoment]:
    out = []
    for k, name in enumerate(MOMENTS):
        depth = None
        if depth_max_m is not None:
            depth = np.zeros((20, 30))
            depth[8:12, 10:20] = depth_max_m * k / 2
        out.append(TactileMoment("left", name, T0 + ONSET_S + 0.25 * k, force_n[k], np.zeros((20, 30, 3), np.uint8),
                                 depth))
    return out


def test_tactile_titles_give_time_since_the_grasps_start_and_the_force_never_minus_zero(drawn, tmp_path):
    view = _view()
    view.moments = _moments(5e-6)
    figures.tactile_figure(view, tmp_path / "tactile.png")
    (fig,) = drawn
    titles = [ax.get_title() for ax in fig.axes if ax.get_title().startswith("left:")]
    assert titles == ["left: before contact\nt = +7.00 s, F = 0.00 N", "left: mid-loading\nt = +7.25 s, F = 6.00 N",
                      "left: peak force\nt = +7.50 s, F = 20.00 N"]


def test_a_shallow_dent_is_drawn_in_micrometres_on_a_scale_of_at_least_20(drawn, tmp_path):
    view = _view()
    view.moments = _moments(5e-6)  # a soft object's 5 µm at the peak
    figures.tactile_figure(view, tmp_path / "tactile.png")
    (fig,) = drawn
    depths = [ax.get_images()[0] for ax in fig.axes if ax.get_title().startswith("depth")]
    assert len(depths) == len(MOMENTS)
    assert {image.get_clim() for image in depths} == {(0.0, figures.DEPTH_FLOOR_MM * 1e3)}
    assert float(np.max(depths[-1].get_array())) == pytest.approx(5.0)  # µm


def test_a_deep_dent_sets_the_scale(drawn, tmp_path):
    view = _view()
    view.moments = _moments(800e-6)
    figures.tactile_figure(view, tmp_path / "tactile.png")
    (fig,) = drawn
    depths = [ax.get_images()[0] for ax in fig.axes if ax.get_title().startswith("depth")]
    assert depths[-1].get_clim() == pytest.approx((0.0, 800.0))


def test_frames_without_depth_are_drawn_without_a_colour_bar(drawn, tmp_path):
    view = _view()
    view.moments = _moments(None)
    figures.tactile_figure(view, tmp_path / "tactile.png")
    (fig,) = drawn
    texts = [t.get_text() for ax in fig.axes for t in ax.texts]
    assert texts.count("no depth:\nno calibration\nin the log") == len(MOMENTS)
    assert not any(ax.get_ylabel() == "depth (µm)" for ax in fig.axes)


# --------------------------------------------------------------------------- timeline


def test_the_timeline_plots_force_in_newtons_and_width_in_millimetres_since_the_start(drawn, tmp_path):
    view = _view()
    figures.timeline_figure(view, tmp_path / "t.png", display_recorded=False)
    (fig,) = drawn
    force, width = _axis(fig, "force (N)").get_lines()[0], _axis(fig, "width (mm)").get_lines()[0]
    assert force.get_xdata()[0] == pytest.approx(0.0) and max(force.get_ydata()) == pytest.approx(20.0)
    assert width.get_ydata()[0] == pytest.approx(80.0) and width.get_xdata()[-1] == pytest.approx(9.0)


def test_the_estimates_panel_draws_the_label_intervals_and_the_final_estimate_big(drawn, tmp_path):
    view = _view()
    view.estimates.append(EstimatePoint(T0 + 7.7, 6.75e6, (6.75e6, None), "lower_bound", "test", True, "series"))
    figures.timeline_figure(view, tmp_path / "t.png", display_recorded=False)
    (fig,) = drawn
    ax = _moduli(fig)
    low, high = 1e6 / 3, 6.75e6 * 3  # the panel's limits: the values a factor 3 beyond
    assert ax.get_ylim() == pytest.approx((low, high))
    labels = [tuple(line.get_ydata()) for line in ax.get_lines() if line.get_linestyle() == "--"]
    assert (3e6, 3e6) in labels and len(labels) == 2  # the label; the gripper's stop
    bars = sorted(_segments(ax))
    assert np.allclose(bars, [(7.3, 1e6, 4e6), (7.6, 2e6, 3e6), (7.7, 6.75e6, high)])  # open end: to the top
    points = {round(float(line.get_xdata()[0]), 3): line for line in ax.get_lines()
              if len(line.get_xdata()) == 1 and line.get_linestyle() in ("None", "")}
    assert points[7.6].get_markersize() > points[7.3].get_markersize()  # the final one is big
    assert points[7.7].get_marker() == "^"  # a lower bound points up


def test_the_timeline_shades_loading_marks_the_moments_and_the_grippers_stop(drawn, tmp_path):
    view = _view()
    view.moments = _moments(None)
    figures.timeline_figure(view, tmp_path / "t.png", display_recorded=False)
    (fig,) = drawn
    ax = _axis(fig, "force (N)")
    shaded = [p for p in ax.patches if to_rgba(p.get_facecolor()) == to_rgba(figures.LOADING_COLOUR)]
    assert len(shaded) == 1
    xs = shaded[0].get_path().transformed(shaded[0].get_patch_transform()).vertices[:, 0]
    assert (xs.min(), xs.max()) == pytest.approx((ONSET_S, PEAK_S))
    vertical = {(line.get_linestyle(), round(float(line.get_xdata()[0]), 3)) for line in ax.get_lines()
                if len(line.get_xdata()) == 2 and line.get_xdata()[0] == line.get_xdata()[1]}
    assert vertical == {(":", 7.0), (":", 7.25), (":", 7.5), ("--", DONE_S)}
    assert "dashed purple = gripper reported loading done" in fig.get_suptitle()


def test_an_operators_grasp_without_a_gripper_stop_says_so(drawn, tmp_path):
    figures.timeline_figure(_view(done=False), tmp_path / "t.png", display_recorded=False)
    (fig,) = drawn
    assert "no gripper stop reported (an operator's grasp)" in fig.get_suptitle()
    ax = _axis(fig, "force (N)")
    assert not [line for line in ax.get_lines() if line.get_linestyle() == "--"]


def test_a_loading_phase_long_beside_the_grasp_is_not_zoomed(drawn, tmp_path):
    figures.timeline_figure(_view(onset_s=2.0), tmp_path / "t.png", display_recorded=False)  # 5.5 s of 9
    (fig,) = drawn
    assert not any("zoom" in ax.get_title() for ax in fig.axes)
    assert len({ax.get_xlim() for ax in fig.axes}) == 1


def test_a_segment_without_a_finite_onset_is_not_zoomed():
    view = _view()
    view.segment = SimpleNamespace(t_onset_s=float("nan"), t_peak_s=T0 + PEAK_S)
    assert figures._zoom_window(view) is None
    assert figures._zoom_window(_view()) == pytest.approx((ONSET_S - 0.2, PEAK_S + 0.5))


def test_the_display_panel_bands_each_rigid_and_unknown_rendering_until_the_next_message(drawn, tmp_path):
    """Drawn as steps (``where="post"``): a rendering holds until the display's next message, and so
    do the red (rigid) and grey (unknown) bands behind it."""
    view = _view()
    view.display = [DisplayPoint(T0 + 7.6, "active", 0.99, 6.7e6, True, False, False),
                    DisplayPoint(T0 + 7.8, "active", 1.0, 6.75e6, True, False, False),
                    DisplayPoint(T0 + 8.0, "active", 0.0, None, False, True, False),
                    DisplayPoint(T0 + 8.2, "active", 0.4, 2.5e6, False, False, False),
                    DisplayPoint(T0 + 8.5, "fading", 0.0, None, False, False, False)]
    figures.timeline_figure(view, tmp_path / "t.png", display_recorded=True)
    (fig,) = drawn
    ax = next(ax for ax in fig.axes if ax.get_ylabel().startswith("display"))
    bands: dict[tuple, list] = {}
    for collection in ax.collections:
        colour = tuple(np.round(collection.get_facecolor()[0][:3], 3))
        for path in collection.get_paths():
            xs = path.vertices[:, 0]
            if xs.max() > xs.min():
                bands.setdefault(colour, []).append((round(float(xs.min()), 3), round(float(xs.max()), 3)))
    assert bands == {tuple(np.round(to_rgba("C3")[:3], 3)): [(7.6, 8.0)],  # rigid
                     tuple(np.round(to_rgba("0.5")[:3], 3)): [(8.0, 8.2)]}  # unknown


def test_a_figures_size_is_its_pngs_when_its_height_is_not_whole_pixels(tmp_path):
    """Force, width, estimates, refusals and display: 8.7 in tall, 869.99... px in floating point."""
    view = _view()
    view.estimates.insert(0, EstimatePoint(T0 + 7.1, None, (None, None), "insufficient_data", "test", True, "auto"))
    view.display = [DisplayPoint(T0 + 7.6, "active", 0.4, 2.5e6, False, False, False)]
    size = figures.timeline_figure(view, tmp_path / "t.png", display_recorded=True)
    height, width = cv2.imread(str(tmp_path / "t.png")).shape[:2]
    assert size == (width, height) == (1300, 870)


# --------------------------------------------------------------------------- predictions


def _final(grasp_id: str, label_pa: float | None, e_pa: float, interval, state: str = "ok") -> GraspView:
    view = GraspView(grasp_id, object_name=f"object {grasp_id}", label_pa=label_pa)
    view.estimates.append(EstimatePoint(1.0, e_pa, interval, state, "test", False, "auto"))
    return view


def test_the_predictions_plot_estimates_up_against_labels_across_with_open_intervals_to_the_edge(drawn, tmp_path):
    views = [_final("a", 1e5, 2e5, (1e5, 4e5)), _final("b", 1e7, 6.75e6, (6.75e6, None), "lower_bound"),
             _final("c", None, 3e6, (1e6, 9e6))]
    figures.predictions_figure(views, tmp_path / "p.png")
    (fig,) = drawn
    (ax,) = fig.axes
    assert (ax.get_xlabel(), ax.get_ylabel()) == ("label E (Pa)", "final estimate (Pa)")
    low, high = 1e5 / 5, 1e7 * 5
    assert ax.get_xlim() == pytest.approx((low, high)) and ax.get_ylim() == pytest.approx((low, high))
    points = {(float(line.get_xdata()[0]), float(line.get_ydata()[0])): line.get_marker() for line in ax.get_lines()
              if len(line.get_xdata()) == 1}
    assert points == {(1e5, 2e5): "o", (1e7, 6.75e6): "^"}  # the unlabelled grasp is left out
    assert np.allclose(sorted(_segments(ax)), [(1e5, 1e5, 4e5), (1e7, 6.75e6, high)])
    assert "2 grasps" in ax.get_title() and "1 without a label or estimate left out" in ax.get_title()
    band = ax.collections[0].get_paths()[0].vertices  # within a factor 2 of y = x
    assert np.unique(np.round(band[:, 1] / band[:, 0], 6)).tolist() == [0.5, 2.0]
    assert (band[:, 0].min(), band[:, 0].max()) == pytest.approx((low, high))
