"""A PNG contact sheet of one simulated grasp, for people to look at.

Rows: frames of each finger at four moments (before touch, a third and two
thirds into loading, the hold); then the true gel depth of both fingers at
peak force (simulator truth, never in the record) and the force and width the
host recorded, over the true curves.

The depth's colours span the 1st to 99th percentile of the gel inside its edge band
(:data:`DEPTH_EDGE`): the gel's rim, held by its frame, reads up to ten times deeper than a soft
object's contact and would otherwise take the whole scale; deeper or shallower pixels are clipped.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from teleop.record import GraspRecord
from teleop.sim.grasp import GraspTruth

__all__ = ["DEPTH_EDGE", "write_preview"]

DEPTH_EDGE = 0.1  # the gel's edge band left out of the depth's colour range: this fraction of each side


def _moments(truth: GraspTruth) -> list[tuple[str, float]]:
    loading = truth.stall_s - truth.touch_s
    return [
        ("before touch", truth.touch_s - 0.1),
        ("loading 1/3", truth.touch_s + loading / 3),
        ("loading 2/3", truth.touch_s + 2 * loading / 3),
        ("hold", 0.5 * (truth.stall_s + truth.release_s)),
    ]


def depth_colour_range(depth: np.ndarray) -> tuple[float, float]:
    """The 1st and 99th percentile of ``depth`` inside its edge band (:data:`DEPTH_EDGE`)."""
    rows, cols = (max(1, int(n * DEPTH_EDGE)) if n > 4 else 0 for n in depth.shape)
    inner = depth[rows: depth.shape[0] - rows, cols: depth.shape[1] - cols]
    low, high = (float(v) for v in np.percentile(inner if inner.size else depth, [1, 99]))
    return low, max(high, low + 1e-9)


def write_preview(record: GraspRecord, truth: GraspTruth, path: str | Path, *, dpi: int = 100) -> Path:
    """Render the contact sheet of ``record`` (with its ``truth``) to the PNG ``path``; returns the path."""
    path = Path(path)
    n_fingers = len(record.frames)
    moments = _moments(truth)
    fig = Figure(figsize=(16, 3.4 * (n_fingers + 1)), layout="constrained")
    FigureCanvasAgg(fig)
    grid = fig.add_gridspec(n_fingers + 1, len(moments))
    for row, stream in enumerate(record.frames):
        for col, (name, t) in enumerate(moments):
            ax = fig.add_subplot(grid[row, col])
            ax.axis("off")
            if len(stream) == 0:
                continue
            index = int(np.argmin(np.abs(stream.t_s - t)))
            ax.imshow(stream.frame(index)[..., ::-1])
            force = float(np.interp(stream.t_s[index], truth.t_s, truth.force_n))
            ax.set_title(f"{stream.finger}: {name}, t={stream.t_s[index]:.2f} s, F={force:.1f} N", fontsize=9)

    for col, (finger, depth) in enumerate(truth.peak_gel_m.items()):
        ax = fig.add_subplot(grid[n_fingers, col])
        low, high = depth_colour_range(depth * 1e3)
        image = ax.imshow(depth * 1e3, cmap="viridis", vmin=low, vmax=high)
        bar = fig.colorbar(image, ax=ax, fraction=0.035, extend="both")
        bar.set_label("depth (mm); colours: 1-99th percentile\ninside the gel's rim (rim clipped)", fontsize=8)
        ax.set_title(f"{finger}: true gel depth at {truth.force_n.max():.1f} N", fontsize=9)
        ax.axis("off")

    ax = fig.add_subplot(grid[n_fingers, len(moments) - 2])
    ax.plot(truth.t_s, truth.force_n, color="0.6", label="true")
    ax.plot(record.force_n.t_s, record.force_n.value, ".", markersize=3, label="load cell")
    ax.set_xlabel("t (s)")
    ax.set_ylabel("force (N)")
    ax.set_xlim(record.force_n.t_s.min(), record.force_n.t_s.max())
    ax.legend(fontsize=8)

    ax = fig.add_subplot(grid[n_fingers, len(moments) - 1])
    ax.plot(truth.t_s, truth.motor_width_m * 1e3, color="0.6", label="true motor")
    ax.plot(truth.t_s, truth.tip_width_m * 1e3, color="C3", linestyle="--", label="true tips")
    ax.plot(record.width_m.t_s, record.width_m.value * 1e3, "o", markersize=3, label="gripper read")
    ax.set_xlabel("t (s)")
    ax.set_ylabel("width (mm)")
    ax.set_xlim(record.force_n.t_s.min(), record.force_n.t_s.max())
    ax.legend(fontsize=8)

    label = record.label
    title = f"{label.object_name}: {label.shape}, {label.material}, E = {label.modulus_pa:.3g} Pa" if label else ""
    fig.suptitle(f"{title}  [{record.provenance.model}]")
    fig.savefig(path, dpi=dpi)
    return path
