"""The figures of ``teleop report``: PNGs drawn with matplotlib's Agg canvas (no display, no pyplot).

Per grasp, a tactile sheet (each finger's frame before contact, mid-loading and at the peak
force, with the depth reconstructed from it) and a timeline (force, width, the estimates with
their intervals against the label, and what the display rendered, on one time axis); for the
session, the final estimates against their labels.

Text from the log (grasp ids, object names) is drawn with ``parse_math=False``: a ``$`` in it is
a dollar sign, not the start of matplotlib's mathtext.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
from matplotlib.axes import Axes
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from teleop.record import GRASP_DONE_EVENT
from teleop.system.report_data import MOMENTS, GraspView

__all__ = ["DPI", "predictions_figure", "tactile_figure", "timeline_figure"]

DPI = 100
WIDTH_IN = 13.0  # 1300 px: the page's content width
# Estimate states: marker and colour (as `estimator evaluate` draws them).
STATE_STYLE = {"ok": ("o", "C0"), "lower_bound": ("^", "C3"), "upper_bound": ("v", "C2")}
LOADING_COLOUR = "#fde9c9"
# The depth colour scale reaches at least this far (mm): a soft object barely dents the gel, and
# its contact patch still shows; the noise of an untouched gel stays dark.
DEPTH_FLOOR_MM = 0.02
# The timeline's zoom on the loading phase: from this long before contact to this long after the peak (s).
ZOOM_BEFORE_S, ZOOM_AFTER_S = 0.2, 0.5


def _save(fig: Figure, path: Path) -> tuple[int, int]:
    """Write ``fig`` to ``path``; its size in pixels (width, height)."""
    FigureCanvasAgg(fig)
    fig.savefig(path, dpi=DPI)
    width, height = fig.get_size_inches() * DPI
    return int(round(width)), int(round(height))


def _micrometres(depth_m: float) -> str:
    """A gel depth in micrometres, with the digits that show it (``3.4 µm``, ``120 µm``)."""
    um = round(depth_m * 1e6, 1) + 0.0
    return f"{um:.1f} µm" if abs(um) < 100 else f"{um:.0f} µm"


def tactile_figure(view: GraspView, path: Path) -> tuple[int, int]:
    """Each finger's frames at :data:`MOMENTS` (on the depth grid) with their depth (µm) beside
    them, one row per finger, one depth colour scale per finger; returns the PNG's size (px)."""
    fingers = list(dict.fromkeys(m.finger for m in view.moments))
    fig = Figure(figsize=(WIDTH_IN, 2.1 * len(fingers) + 0.3), layout="constrained")
    grid = fig.add_gridspec(len(fingers), 2 * len(MOMENTS))
    for row, finger in enumerate(fingers):
        moments = [m for m in view.moments if m.finger == finger]
        depths = [m.depth_m for m in moments if m.depth_m is not None]
        top_um = max(DEPTH_FLOOR_MM * 1e3, *(float(d.max()) * 1e6 for d in depths)) if depths else 1e3
        shown, row_axes = None, []
        for col, moment in enumerate(moments):
            ax = fig.add_subplot(grid[row, 2 * col])
            row_axes.append(ax)
            ax.imshow(moment.image_bgr[..., ::-1])
            ax.set_title(f"{finger}: {moment.name}\nt = {moment.t_s - view.t0_s:+.2f} s, "
                         f"F = {round(moment.force_n, 2) + 0.0:.2f} N", fontsize=8, parse_math=False)
            ax.axis("off")
            ax = fig.add_subplot(grid[row, 2 * col + 1])
            row_axes.append(ax)
            ax.axis("off")
            if moment.depth_m is None:
                ax.text(0.5, 0.5, "no depth:\nno calibration\nin the log", ha="center", va="center", fontsize=8)
                continue
            shown = ax.imshow(moment.depth_m * 1e6, cmap="viridis", vmin=0.0, vmax=top_um)
            ax.set_title(f"depth, max {_micrometres(float(moment.depth_m.max()))}", fontsize=8)
        if shown is not None:
            fig.colorbar(shown, ax=row_axes, fraction=0.02, pad=0.01, label="depth (µm)")
    fig.suptitle(f"grasp {view.grasp_id}: tactile frames (warped and cropped) and reconstructed depth",
                 fontsize=9, parse_math=False)
    return _save(fig, path)


def _estimate_range(view: GraspView) -> tuple[float, float]:
    values = [v for e in view.estimates for v in (e.e_pa, *e.interval_pa) if v]
    values += [d.e_pa for d in view.display if d.e_pa] + ([view.label_pa] if view.label_pa else [])
    if not values:
        return 1e3, 1e12
    return min(values) / 3, max(values) * 3


def _estimates_panel(ax: Axes, view: GraspView, t0: float, *, legend: bool = True) -> None:
    """The estimates with their intervals, the label and the display's modulus on a log axis;
    refusals are not drawn here (no modulus: :func:`_refusals_strip`)."""
    lo, hi = _estimate_range(view)
    final = view.final
    for e in view.estimates:
        if e.e_pa is None:
            continue
        t = e.t_s - t0
        marker, colour = STATE_STYLE.get(e.state, ("o", "C0"))
        big = e is final
        low, high = (v if v else end for v, end in zip(e.interval_pa, (lo, hi), strict=True))
        ax.vlines(t, low, high, color=colour, lw=2.5 if big else 1, alpha=0.9 if big else 0.35)
        ax.plot(t, e.e_pa, marker, color=colour, ms=9 if big else 4, mec="k" if big else colour,
                alpha=1 if big else 0.6)
    if view.label_pa:
        ax.axhline(view.label_pa, color="k", ls="--", lw=1)
        ax.text(0.005, view.label_pa, f" label {view.label_pa:.3g} Pa", transform=ax.get_yaxis_transform(),
                va="bottom", fontsize=8)
    shown = any(d.e_pa for d in view.display)
    if shown:  # NaN breaks the line where the display renders no modulus (unknown, fading)
        ax.step([d.t_s - t0 for d in view.display], [d.e_pa or np.nan for d in view.display], where="post",
                color="C1", lw=1, alpha=0.8)
    ax.set(yscale="log", ylim=(lo, hi), ylabel="E (Pa)")
    if not legend:
        return
    states = {e.state for e in view.estimates if e.e_pa is not None}
    handles = [ax.plot([], [], m, color=c, ls="", label=s)[0] for s, (m, c) in STATE_STYLE.items() if s in states]
    if any(e.e_pa is None for e in view.estimates):
        handles.append(ax.plot([], [], "x", color="0.3", ls="", label="refused (strip below)")[0])
    if final is not None and final.e_pa:
        handles.append(ax.plot([], [], "o", color="0.6", mec="k", ms=9, ls="", label="final (big)")[0])
    if shown:
        handles.append(ax.plot([], [], color="C1", label="display ~E")[0])
    if handles:
        ax.legend(handles=handles, fontsize=7, loc="lower right", bbox_to_anchor=(1.0, 1.0),
                  ncols=len(handles), frameon=False, borderaxespad=0.1)


def _refusals_strip(ax: Axes, view: GraspView, t0: float) -> None:
    """The estimator's refusals (no modulus) as marks on a strip of their own, off the modulus axis."""
    ax.plot([e.t_s - t0 for e in view.estimates if e.e_pa is None],
            [0.5] * sum(e.e_pa is None for e in view.estimates), "x", color="0.3", ms=5)
    ax.set(ylim=(0, 1), yticks=[])
    ax.set_ylabel("refused", rotation=0, ha="right", va="center", fontsize=8)


def _display_panel(ax: Axes, view: GraspView, t0: float, *, note: bool = True) -> None:
    t = [d.t_s - t0 for d in view.display]
    ax.step(t, [d.stiffness for d in view.display], where="post", color="C1", lw=1.5)
    band = ax.get_xaxis_transform()  # bands span the panel's height
    for flag, colour in (("rigid", "C3"), ("unknown", "0.5")):
        # Each run of flagged renderings, held until the next message as the step line holds it
        # (fill_between's ``where`` would stop the band at the run's last message).
        flags = np.array([getattr(d, flag) for d in view.display])
        for run in np.split(np.arange(flags.size), np.flatnonzero(np.diff(flags)) + 1):
            if run.size and flags[run[0]]:
                ax.fill_between(t[run[0]: run[-1] + 2], 0, 1, step="post", color=colour, alpha=0.2, lw=0,
                                transform=band)
    ax.set(ylim=(-0.05, 1.1), ylabel="display\nstiffness (0..1)")
    if note:
        ax.text(0.005, 0.95, "line: fraction of the display's range; red: rendered rigid; grey: unknown (free)",
                transform=ax.transAxes, va="top", fontsize=7)


def _zoom_window(view: GraspView) -> tuple[float, float] | None:
    """The loading phase with a margin (contact - 0.2 s to peak + 0.5 s, since the grasp's start),
    when it is short beside the whole grasp (under 60 % of it); None otherwise."""
    segment, record = view.segment, view.record
    if not segment or not np.isfinite(segment.t_onset_s) or not np.isfinite(segment.t_peak_s):
        return None
    start, stop = segment.t_onset_s - view.t0_s - ZOOM_BEFORE_S, segment.t_peak_s - view.t0_s + ZOOM_AFTER_S
    times = np.concatenate([record.force_n.t_s, record.width_m.t_s]) - view.t0_s
    span = float(times.max() - times.min()) if times.size else 0.0
    return (start, stop) if span > 0 and stop - start < 0.6 * span else None


def timeline_figure(view: GraspView, path: Path, *, display_recorded: bool) -> tuple[int, int]:
    """Force, width, estimates (log scale, intervals, label), the refusals on a strip of their own
    and, when the log recorded the display, what it rendered, over seconds since the grasp's start;
    the loading phase shaded and the tactile moments marked. When the loading phase is short beside
    the whole grasp, a second column shows it zoomed (contact - 0.2 s to peak + 0.5 s). Returns the
    PNG's size (px)."""
    record, t0 = view.record, view.t0_s
    panels = ["force", "width", "estimates"]
    if any(e.e_pa is None for e in view.estimates):
        panels.append("refused")
    if display_recorded and view.display:
        panels.append("display")
    heights = {"force": 1, "width": 1, "estimates": 1.4, "refused": 0.22, "display": 1}
    zoom = _zoom_window(view)
    height_in = 1.9 * (len(panels) - ("refused" in panels)) + 0.4 * ("refused" in panels) + 0.7
    fig = Figure(figsize=(WIDTH_IN, round(height_in, 2)), layout="constrained")  # whole pixels
    grid = fig.subplots(len(panels), 2 if zoom else 1, sharex="col", sharey="row", squeeze=False,
                        height_ratios=[heights[p] for p in panels], width_ratios=[1, 2] if zoom else None)
    segment = view.segment
    for col, column in enumerate(grid.T):
        axes = dict(zip(panels, column, strict=True))
        axes["force"].plot(record.force_n.t_s - t0, record.force_n.value, color="C0", lw=1.2)
        axes["width"].plot(record.width_m.t_s - t0, record.width_m.value * 1e3, ".-", color="C2", lw=1, ms=3)
        _estimates_panel(axes["estimates"], view, t0, legend=col == len(grid.T) - 1)
        if "refused" in axes:
            _refusals_strip(axes["refused"], view, t0)
        if "display" in axes:
            _display_panel(axes["display"], view, t0, note=col == len(grid.T) - 1)
        for ax in column:
            if segment:
                ax.axvspan(segment.t_onset_s - t0, segment.t_peak_s - t0, color=LOADING_COLOUR, zorder=0)
            for moment in view.moments[: len(MOMENTS)]:  # one finger's moments; the others' are within a frame
                ax.axvline(moment.t_s - t0, color="0.6", ls=":", lw=1)
            if GRASP_DONE_EVENT in record.events:
                ax.axvline(record.events[GRASP_DONE_EVENT] - t0, color="C4", ls="--", lw=1)
            ax.grid(alpha=0.3)
        column[-1].set_xlabel("time since the grasp's start event (s)")
    if zoom:
        for ax in grid[:, 1]:
            ax.set_ylabel("")  # the rows share their y axis with the whole grasp's
        grid[0, 1].set_xlim(*zoom)
        grid[0, 0].set_title("whole grasp", fontsize=8)
        grid[0, 1].set_title(f"zoom on the loading phase: contact - {ZOOM_BEFORE_S:g} s to peak + "
                             f"{ZOOM_AFTER_S:g} s", fontsize=8)
    grid[0, 0].set_ylabel("force (N)")
    grid[1, 0].set_ylabel("width (mm)")
    stop = ("dashed purple = gripper reported loading done" if GRASP_DONE_EVENT in record.events
            else "no gripper stop reported (an operator's grasp)")
    fig.suptitle(f"grasp {view.grasp_id}: shaded = loading phase (onset to peak force); dotted = the "
                 f"tactile frames shown; {stop}", fontsize=8, parse_math=False)
    return _save(fig, path)


def predictions_figure(views: Sequence[GraspView], path: Path, *, session: str | None = None,
                       display_range_pa: tuple[float, float] | None = None) -> tuple[int, int]:
    """Final estimates against their labels, log-log, with intervals, y = x and the factor-2 band;
    grasps without a label or a final modulus are left out (the title counts them). ``session``
    (the log's name) heads the title; ``display_range_pa`` (the display's ``(e_soft_pa,
    e_rigid_pa)``) is drawn as dashed lines, as ``estimator evaluate``'s plot draws it. The legend
    lists only the states that have a point."""
    points = [v for v in views if v.label_pa and v.final is not None and v.final.e_pa]
    fig = Figure(figsize=(6.5, 5.5), layout="constrained")
    ax = fig.add_subplot()
    values = [v.label_pa for v in points] + [x for v in points for x in (v.final.e_pa, *v.final.interval_pa) if x]
    lo, hi = (min(values) / 5, max(values) * 5) if values else (1e3, 1e12)
    line = np.geomspace(lo, hi, 2)
    ax.fill_between(line, line / 2, line * 2, color="0.88", label="within a factor 2")
    ax.plot(line, line, color="0.4", lw=1)
    for k, end in enumerate(display_range_pa or ()):
        ax.axhline(end, ls="--", color="C1", lw=1, label="display range" if k == 0 else None)
    for v in points:
        final = v.final
        marker, colour = STATE_STYLE.get(final.state, ("o", "C0"))
        low, high = (x if x else end for x, end in zip(final.interval_pa, (lo, hi), strict=True))
        ax.vlines(v.label_pa, low, high, color=colour, lw=1.5, alpha=0.6)
        ax.plot(v.label_pa, final.e_pa, marker, color=colour, ms=8, mec="k")
        ax.annotate(v.object_name or v.grasp_id, (v.label_pa, final.e_pa), xytext=(5, 4),
                    textcoords="offset points", fontsize=7, parse_math=False)
    present = {v.final.state for v in points}
    for state, (marker, colour) in STATE_STYLE.items():
        if state in present:
            ax.plot([], [], marker, color=colour, mec="k", ls="", label=state)
    ax.set(xscale="log", yscale="log", xlim=(lo, hi), ylim=(lo, hi), xlabel="label E (Pa)",
           ylabel="final estimate (Pa)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, loc="upper left")
    left_out = len(views) - len(points)
    head = f"{session}: " if session else ""
    ax.set_title(f"{head}final estimate vs label, {len(points)} grasps (bars: intervals)"
                 + (f";\n{left_out} without a label or estimate left out" if left_out else ""), fontsize=9,
                 parse_math=False)
    return _save(fig, path)
