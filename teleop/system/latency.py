"""``teleop bench-latency``: how fast the live system shows a grasp's estimate on the display.

Runs the live system (:class:`~teleop.system.live_system.LiveSystem`: robot node on simulated hardware,
estimator service, haptic renderer on the simulated display; no session recorder unless
``--record``) on loopback for ``--grasps`` grasps of a scene's objects in turn, and reports:

``p50_ms``, ``p99_ms``
    Latency of each FINAL estimate: from the capture of the grasp's last loading frame (the
    final estimate's ``t_capture_s``: the segmentation's last loading frame, which once the
    loading is over is its peak frame, the first frame captured after the force peak) to the
    renderer's HID report that shows it (the display report written after the final estimate
    arrived; renderer report), on this host's monotonic clock. With the robot's loading-end
    marker (the gripper's grasp command completed: the fingers stopped at the target force) the
    estimator takes the final estimate as that frame arrives; without one, once the force has
    settled :data:`~estimator.stream.LOADING_SETTLED_S` past its peak and a width sample newer
    than the peak has come (widths arrive at 10 Hz). It is the sum of two parts:

    ``decision_p50_ms``, ``decision_p99_ms``
        Last loading frame captured -> final estimate published (estimator report): the frame's
        way to the estimator, its depth, and the final computation.
    ``delivery_p50_ms``, ``delivery_p99_ms``
        Final estimate published -> HID report written.

    For grasps ended by the marker, how the loading end relates to it:

    ``peak_frame_after_stop_p50_ms``, ``peak_frame_after_stop_p99_ms``
        Loading end (the marker's time, the fingers stopped) -> the last loading frame's
        capture: the camera's frame phase against the stop, up to a frame period (33 ms at
        30 Hz); no software waits in it, and it is not part of the latency above.
    ``loading_end_to_report_p50_ms``, ``loading_end_to_report_p99_ms``
        Loading end -> HID report: what the operator waits from the fingers stopping (the
        frame phase plus the latency above).
    ``final_compute_p50_ms``, ``final_compute_p99_ms``
        The estimator's computation of the final estimate (segmentation, model input from the
        cached depths, fits, model).
    ``finals_by``
        How many finals each trigger gave: ``loading_end`` (marker), ``settled`` (fallback),
        ``grasp_end``.
``provisional_hz``
    Provisional estimates per second while grasps load (count minus one over the span from
    the first to the last, summed over grasps with at least two); the camera gives 30 Hz.
``compute_p50_ms``, ``compute_p99_ms``
    Per estimate (provisional and final), from the estimator receiving the message that
    triggered it to publishing it (the message's ``latency_s``).

``frame_baseline_ms``, ``frame_baseline_before_ms``, ``frame_baseline_after_ms``
    The machine's speed at the time, measured in this (the benchmark's) process while the live
    system is not running, before and after it: the median time of one tactile frame's
    perception as the estimator does it for the peak frame (JPEG decode, warp, depth and contact
    features of a simulated 2 mm ball press on the estimator's finger), over
    :data:`BASELINE_REPEATS` frames each time; ``frame_baseline_ms`` is the median of both sets.
    On a shared or throttled machine it moves with the latencies (the final estimate is mostly
    this work), so runs taken at different times compare through the latencies in its units:
``p50_in_baselines``, ``p99_in_baselines``
    The latency quantiles divided by ``frame_baseline_ms``.

``per_grasp``
    Each measured grasp in run order: ``grasp_id``, ``object``, ``latency_ms``,
    ``decision_ms``, ``final_compute_ms``, ``delivery_ms`` and ``final_by``. The text
    report names the slowest ones and splits their decision into the final computation and
    everything before it (the peak frame's way to the estimator, its decode, and any wait
    for data the final needed); ``--plot`` draws every grasp that way against the 15 ms aim.

The quantiles are of the measured grasps (with 20 grasps p99 is close to the maximum).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from estimator.settings import estimator_settings
from teleop.bus.wire import Message
from teleop.clikit import PLOT_SUFFIXES, output_file
from teleop.errors import TeleopError
from teleop.settings import Settings, load_settings
from teleop.staging import staged
from teleop.system.demo import (
    LiveView,
    add_run_arguments,
    prepare_run,
    run_grasps,
    scene_plan,
)
from teleop.system.live_system import LiveSystem
from teleop.system.outcome import GraspOutcome

if TYPE_CHECKING:
    from estimator.perception.calibration import Calibration

__all__ = ["baseline_figures", "baseline_press", "frame_baseline_ms", "latency_summary", "plot", "slowest"]

P99_AIM_MS = 15.0  # the aim for the last loading frame -> HID report p99
SLOWEST_SHOWN = 3
BASELINE_REPEATS = 30  # frames timed before and after the run
BASELINE_BALL_RADIUS_M = 2e-3
BASELINE_PRESS_DEPTH_M = 6e-4


def baseline_press(settings: Settings, *, seed: int = 0) -> tuple[bytes, bytes]:
    """JPEG captures (pressed, untouched) of the estimator's finger by its simulated camera: a
    :data:`BASELINE_BALL_RADIUS_M` ball pressed :data:`BASELINE_PRESS_DEPTH_M` into the gel's centre."""
    from teleop.sim.optics import OpticsRenderer
    from teleop.sim.presses import sphere_press_height

    sensor = settings.sensor(settings.sensing.finger)
    camera = OpticsRenderer(sensor, sim=settings.simulation, rng=np.random.default_rng(seed))
    rows, cols = sensor.image_shape
    press = sphere_press_height(sensor.image_shape, center_px=((cols - 1) / 2.0, (rows - 1) / 2.0),
                                ball_radius_m=BASELINE_BALL_RADIUS_M, depth_m=BASELINE_PRESS_DEPTH_M,
                                pixel_pitch_m=sensor.pixel_pitch_m)
    return camera.capture(press), camera.capture(np.zeros(sensor.image_shape))


def frame_baseline_ms(settings: Settings, calibration: Calibration, *, repeats: int = BASELINE_REPEATS,
                      seed: int = 0) -> list[float]:
    """Times (ms) this process takes for one tactile frame's perception, ``repeats`` times.

    Each repeat takes the :func:`baseline_press` capture as the estimator takes the peak frame
    (:class:`~estimator.stream.GraspStream`): :func:`~estimator.perception.grid.frame_on_grid` (decoded and
    warped onto the depth grid of the settings' ``estimator.depth_binning``), then
    :func:`~estimator.measurements.measure_frame` against the untouched capture (depth and contact features).
    """
    from estimator.measurements import measure_frame
    from estimator.perception.grid import depth_grid, frame_on_grid, grid_calibration

    if repeats < 1:
        raise TeleopError(f"frame baseline repeats {repeats}: expected at least 1")
    sensor = settings.sensor(settings.sensing.finger)
    binning = estimator_settings(settings).depth_binning
    grid, grid_cal = depth_grid(sensor, binning), grid_calibration(calibration, binning)
    pressed, untouched = baseline_press(settings, seed=seed)
    reference = frame_on_grid(untouched, "jpeg", sensor, binning=binning)
    times = []
    for _ in range(repeats):
        started = time.perf_counter()
        measure_frame(frame_on_grid(pressed, "jpeg", sensor, binning=binning), reference, grid_cal, grid)
        times.append((time.perf_counter() - started) * 1e3)
    return times


def _quantiles(values: Sequence[float], prefix: str) -> dict[str, float | None]:
    if not values:
        return {f"{prefix}p50_ms": None, f"{prefix}p99_ms": None}
    p50, p99 = np.percentile(np.asarray(values, dtype=np.float64), [50, 99])
    return {f"{prefix}p50_ms": float(p50), f"{prefix}p99_ms": float(p99)}


def latency_summary(outcomes: Sequence[GraspOutcome], compute_s: Sequence[float]) -> dict[str, Any]:
    """The figures of the module docstring from the grasps' outcomes and reports.

    ``compute_s`` holds the ``latency_s`` of every estimate message seen.
    """
    frame_after_stop, after_end, final_compute = [], [], []
    per_grasp: list[dict[str, Any]] = []
    finals_by: dict[str, int] = {}
    spans, counts = 0.0, 0
    for o in outcomes:
        report = o.estimator_report or {}
        if report.get("final_by"):
            finals_by[report["final_by"]] = finals_by.get(report["final_by"], 0) + 1
        computed_ms = None if report.get("final_compute_s") is None else report["final_compute_s"] * 1e3
        if computed_ms is not None:
            final_compute.append(computed_ms)
        if report.get("provisional_span_s"):
            spans += report["provisional_span_s"]
            counts += report["provisional"] - 1
        frame_s = report.get("t_last_loading_frame_s")
        if o.latency_ms is None:
            continue
        row = {"grasp_id": o.grasp_id, "object": o.obj.name, "latency_ms": o.latency_ms, "decision_ms": None,
               "final_compute_ms": computed_ms, "delivery_ms": None, "final_by": report.get("final_by")}
        per_grasp.append(row)
        if frame_s is not None:
            if report.get("final_sent_s") is not None:
                decision_ms = (report["final_sent_s"] - frame_s) * 1e3
                row.update(decision_ms=decision_ms, delivery_ms=o.latency_ms - decision_ms)
            if report.get("final_by") == "loading_end":
                frame_after = (frame_s - report["t_loading_end_s"]) * 1e3
                frame_after_stop.append(frame_after)
                after_end.append(o.latency_ms + frame_after)
    decided = [r for r in per_grasp if r["decision_ms"] is not None]
    return {
        "grasps": len(outcomes),
        "finals_measured": len(per_grasp),
        **_quantiles([r["latency_ms"] for r in per_grasp], ""),
        "provisional_hz": counts / spans if spans > 0 else None,
        **_quantiles([r["decision_ms"] for r in decided], "decision_"),
        **_quantiles([r["delivery_ms"] for r in decided], "delivery_"),
        **_quantiles(frame_after_stop, "peak_frame_after_stop_"),
        **_quantiles(after_end, "loading_end_to_report_"),
        **_quantiles(final_compute, "final_compute_"),
        "finals_by": finals_by,
        **_quantiles([s * 1e3 for s in compute_s], "compute_"),
        "per_grasp": per_grasp,
    }


def baseline_figures(before_ms: Sequence[float], after_ms: Sequence[float]) -> dict[str, float]:
    """``frame_baseline_ms`` (median of both sets), ``frame_baseline_before_ms`` and ``..._after_ms``."""
    if not before_ms or not after_ms:
        raise TeleopError("frame baseline: expected timings before and after the run")
    return {"frame_baseline_ms": float(np.median([*before_ms, *after_ms])),
            "frame_baseline_before_ms": float(np.median(before_ms)),
            "frame_baseline_after_ms": float(np.median(after_ms))}


def slowest(summary: dict[str, Any], count: int = SLOWEST_SHOWN) -> list[str]:
    """Lines naming the ``count`` slowest grasps and where their time went."""
    rows = sorted(summary["per_grasp"], key=lambda r: r["latency_ms"], reverse=True)[:count]
    lines = []
    for r in rows:
        parts = f"{r['latency_ms']:.1f} ms"
        if r["decision_ms"] is not None and r["final_compute_ms"] is not None:
            parts += (f" = {r['decision_ms'] - r['final_compute_ms']:.1f} before the final computation + "
                      f"{r['final_compute_ms']:.1f} computing it + {r['delivery_ms']:.1f} delivery")
        lines.append(f"  {r['grasp_id']} ({r['object']}, final by {r['final_by'] or '?'}): {parts}")
    return lines


def plot(summary: dict[str, Any], path: str | Path) -> None:
    """Per grasp, the latency stacked as before the final computation, computing it and delivery,
    against the p99 aim; bars above the axis are cut and labelled with their value."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = [r for r in summary["per_grasp"] if r["decision_ms"] is not None and r["final_compute_ms"] is not None]
    if not rows:
        raise TeleopError("bench-latency --plot: no grasp has a measured final estimate to draw")
    x = np.arange(len(rows))
    compute = np.array([r["final_compute_ms"] for r in rows])
    before = np.array([r["decision_ms"] for r in rows]) - compute
    delivery = np.array([r["delivery_ms"] for r in rows])
    total = np.array([r["latency_ms"] for r in rows])
    top = max(P99_AIM_MS * 2.0, float(np.percentile(total, 50)) * 3.0)
    fig, ax = plt.subplots(figsize=(max(6.0, 0.35 * len(rows) + 2.0), 4.5))
    ax.bar(x, before, label="frame to estimator, decode, waiting for data", color="#9ecae1")
    ax.bar(x, compute, bottom=before, label="final computation", color="#3182bd")
    ax.bar(x, delivery, bottom=before + compute, label="delivery to the HID report", color="#fd8d3c")
    ax.axhline(P99_AIM_MS, color="k", linestyle="--", linewidth=1, label=f"p99 aim {P99_AIM_MS:g} ms")
    for i in np.flatnonzero(total > top):
        ax.annotate(f"{total[i]:.0f}", (x[i], top), ha="center", va="top", fontsize=8)
    ax.set_ylim(0, top)
    # The grasp id as the text output prints it, so a repeated object is told apart and matched.
    ax.set_xticks(x, [f"{r['grasp_id']} {r['object']}" for r in rows], rotation=70, ha="right",
                  rotation_mode="anchor", fontsize=7)
    ax.set_xlabel("grasp (id and object, in run order)")
    ax.set_ylabel("last loading frame -> HID report (ms)")
    ax.set_title(f"{len(rows)} grasps: p50 {summary['p50_ms']:.1f} ms, p99 {summary['p99_ms']:.1f} ms")
    ax.legend(fontsize=7, loc="upper left")
    fig.tight_layout()
    try:
        # Written beside ``path`` and renamed over it once complete: a failed write leaves no truncated PNG.
        with staged(path) as temporary:
            fig.savefig(temporary, dpi=120, format=Path(path).suffix.lstrip(".").lower() or "png")
    finally:
        plt.close(fig)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.description = (
        "Measure the live system on loopback: latency from the last loading frame's capture to the HID "
        "report that shows the final estimate (p50, p99, split into decision and delivery; for grasps "
        "ended by the robot's loading-end marker also the peak frame's delay after the stop and the time from "
        "the stop to the report), the rate of provisional estimates while a grasp loads (the camera gives "
        "30 Hz), the estimator's compute time per estimate, and the machine's speed at the time (one tactile "
        "frame's perception timed in this process before and after the run, with the latency in those units, "
        "so runs on a shared machine compare)."
    )
    add_run_arguments(parser, default_scene="default")
    parser.add_argument("--grasps", type=int, default=20, metavar="N",
                        help="grasps to run, the scene's objects in turn")
    parser.add_argument("--record", action="store_true", help="also run the session recorder, as the demo does")
    parser.add_argument("--plot", metavar="PNG", default=None,
                        help="write each grasp's latency as a bar split into what came before the final "
                             f"computation, the computation and the delivery, against the {P99_AIM_MS:g} ms aim")


def run(args: argparse.Namespace) -> int:
    from estimator.perception.calibration import load_calibration

    if args.grasps < 1:
        raise TeleopError(f"--grasps {args.grasps}: expected at least 1")
    output_file("--plot", args.plot, suffixes=PLOT_SUFFIXES)
    plan = scene_plan(args.scene, args.grasps)
    log = sys.stderr
    run_dir, calibration = prepare_run(args, prefix="bench-latency", out=log)
    settings = load_settings(args.settings)
    baseline_calibration = load_calibration(calibration)
    baseline_before = frame_baseline_ms(settings, baseline_calibration)
    compute_s: list[float] = []

    def watch(message: Message) -> None:
        if message.type == "estimate":
            compute_s.append(message.fields.latency_s)

    started = time.monotonic()
    view = LiveView(log, len(plan))
    system = LiveSystem(Path(args.settings), args.scene, run_dir, calibration, record=args.record)
    with system:
        outcomes = list(run_grasps(system, plan, view, "bench", on_message=watch))
    wall_s = time.monotonic() - started
    baseline_after = frame_baseline_ms(settings, baseline_calibration)
    summary = {**latency_summary(outcomes, compute_s), **baseline_figures(baseline_before, baseline_after),
               "scene": args.scene, "run_dir": str(run_dir), "wall_s": wall_s}
    for key in ("p50", "p99"):
        summary[f"{key}_in_baselines"] = (None if summary[f"{key}_ms"] is None
                                          else summary[f"{key}_ms"] / summary["frame_baseline_ms"])

    text = sys.stderr if args.json else sys.stdout  # under --json stdout is the JSON alone

    def say(line: str) -> None:
        print(line, file=text)

    def ms(key: str) -> str:
        return "-" if summary[key] is None else f"{summary[key]:.1f} ms"

    hz = summary["provisional_hz"]
    say(f"{summary['finals_measured']} of {summary['grasps']} final estimates measured on the display")
    say(f"last loading frame -> display report: p50 {ms('p50_ms')}, p99 {ms('p99_ms')}")
    say(f"  decision (frame -> final sent):     p50 {ms('decision_p50_ms')}, p99 {ms('decision_p99_ms')}")
    say(f"  delivery (published -> report):     p50 {ms('delivery_p50_ms')}, p99 {ms('delivery_p99_ms')}")
    say(f"peak frame after the fingers stop:    p50 {ms('peak_frame_after_stop_p50_ms')}, "
        f"p99 {ms('peak_frame_after_stop_p99_ms')} (marker grasps; camera phase, not in the latency)")
    say(f"fingers stop -> display report:       p50 {ms('loading_end_to_report_p50_ms')}, "
        f"p99 {ms('loading_end_to_report_p99_ms')}")
    say(f"final estimate compute:               p50 {ms('final_compute_p50_ms')}, p99 {ms('final_compute_p99_ms')}")
    say(f"finals by trigger: {summary['finals_by']}")
    say(f"estimator compute per estimate:       p50 {ms('compute_p50_ms')}, p99 {ms('compute_p99_ms')}")
    say(f"provisional estimates while loading:  {'-' if hz is None else f'{hz:.1f} Hz'} (camera: 30 Hz)")
    say(f"machine speed: one frame's decode, warp, depth and features take {ms('frame_baseline_ms')} in this "
        f"process (before the run {ms('frame_baseline_before_ms')}, after it {ms('frame_baseline_after_ms')})")
    if summary["p50_in_baselines"] is not None:
        say(f"  the latency in those frames: p50 {summary['p50_in_baselines']:.2f}, "
            f"p99 {summary['p99_in_baselines']:.2f}")
    if summary["per_grasp"]:
        say("slowest grasps:")
        say("\n".join(slowest(summary)))
    if args.json:  # the results first: a plot that cannot be drawn or written loses none of them
        print(json.dumps(summary, allow_nan=False), flush=True)
    if args.plot:
        try:
            plot(summary, args.plot)
        except (OSError, TeleopError) as exc:
            why = exc.strerror or exc if isinstance(exc, OSError) else exc
            print(f"teleop bench-latency: error: --plot {args.plot}: {why} (the results above stand; "
                  "no plot written)", file=sys.stderr)
            return 2
        say(f"plot: {args.plot}")
    return 0
