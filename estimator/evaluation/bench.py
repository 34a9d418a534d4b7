"""Latency and error of every estimator configuration, with the Pareto frontier.

Configurations
--------------
``<method>``
    An analytical method over every loading frame: :func:`~estimator.measure.estimate_grasp`,
    the live analytical path (depth reconstructed for all loading frames).
``<method>@<N>f``
    An analytical method over ``N`` frames sampled across the loading phase
    (:func:`~estimator.inference.sampling.sample_grasp`, depth for those frames
    only; the four fits run together, so these share their cost). The widths' times are taken
    as stamped, as the hybrid samples its analytical inputs (the sampler corrects no lag).
``<method>/bin<K>`` (for each ``binning`` K)
    An analytical method over every loading frame with depth measured on the image grid binned
    by K instead of the settings' ``estimator.depth_binning`` (:mod:`estimator.perception.grid`;
    K = 1 is the full grid): speed against error of a coarser or finer measurement.
``<hybrid|cnn>[<variant> <N>f <rows>x<cols>]`` and ``auto[...]``
    A trained model (each of ``models``), and its ``auto`` mode
    (:mod:`estimator.inference.hybrid`).

Latency is measured in-process on one core (the process is pinned to one CPU;
OpenCV and onnxruntime run single-threaded) from decoded frames to the
estimate: every record's frames are decoded once beforehand, as a live camera
delivers them (at the size each configuration's depth binning reads), each
configuration runs once per grasp as warm-up and then ``repeats`` times; a
configuration's ``latency_ms_p50`` is the median over grasps of each grasp's
median time. It includes building the no-contact
reference from the frames before the onset, which ``reference_ms_p50``
reports alone (a live estimator can build it before contact).

Error is scored as ``estimator evaluate`` scores it, over the labelled records
given (the analytical methods over all loading frames, binned or not, with each record's
width lag estimated and corrected, as ``evaluate`` does unless ``--no-width-lag``; the
estimate is part of their latency): ``felt_log10_error`` the mean |log10 error| of what the softness display
renders against the label clipped to the display's range (the error the operator
feels; the frontier's error), ``felt_within_2x`` the share within a factor 2,
``log10_error`` the paper's mean |log10 E_hat - log10 E| of the estimates that
are not refusals (a bound counts with its value), ``within_10x`` the share
within one decade, ``refusals`` the count of ``insufficient_data``; for ``auto``,
``answered_by`` counts which branch answered each grasp (``model``, ``series``,
``no_tactile``, ...).
A configuration is on the Pareto frontier (``pareto: true``) when no other is
at least as fast, at least as accurate and refuses no more grasps, and better in
one of the three: the error is over the grasps a configuration answers, so one
that refuses the hard grasps (no loading frame to sample) must not dominate one
that answers them (``auto``, with its force/width fallback).

The records not benched (unreadable, unlabelled, or naming a calibration file that is gone) are
listed under ``skipped_records``, each ``{"path", "cause"}`` with the
cause ``estimator evaluate`` gives (``unreadable: ...``, ``unlabelled: ...``, ``calibration missing: ...``), and counted by
cause under ``skipped``; with none left to bench, :class:`NothingToBench` carries that list.
"""

from __future__ import annotations

import contextlib
import os
import time
from collections import Counter
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from estimator.analytical import METHODS
from estimator.errors import EstimatorError, PerceptionError
from estimator.estimate import Estimate
from estimator.evaluation.evaluate import (
    answered_by,
    cause_kind,
    result_row,
    unlabelled,
)
from estimator.evaluation.metrics import summarise
from estimator.inference.hybrid import HybridEstimator
from estimator.inference.infer import CompliancePredictor
from estimator.inference.sampling import calibration_for, decoded, sample_grasp
from estimator.measure import estimate_grasp, finger_sensor, measure_grasp, no_contact_reference
from estimator.measurements import TACTILE_METHODS, missing_calibration
from estimator.perception.calibration import Calibration
from estimator.settings import estimator_settings
from haptics.settings import display_range_pa
from teleop.errors import RecordError, SettingsError
from teleop.progress import progress_bar
from teleop.record import GraspRecord, read_record
from teleop.settings import Settings

__all__ = ["BenchConfig", "NothingToBench", "bench", "configurations", "pareto_front"]


@dataclass(frozen=True)
class BenchConfig:
    """One configuration: a name and a function from a record decoded ``binning`` times smaller to an
    estimate; ``markers``: it also reads the marker finger (a model variant with markers)."""

    name: str
    kind: str  # "analytical", "sampled", "model" or "auto"
    method: str
    n_frames: int | None
    size_px: tuple[int, int] | None
    run: Callable[[GraspRecord], Estimate]
    binning: int
    markers: bool = False


class NothingToBench(EstimatorError):
    """No labelled, readable record among those given; ``skipped``: each one ``{"path", "cause"}``."""

    def __init__(self, message: str, skipped: Sequence[dict[str, str]]) -> None:
        super().__init__(message)
        self.skipped = list(skipped)


def skip_counts(skipped: Sequence[dict[str, str]]) -> dict[str, int]:
    """Skipped records counted by the kind of their cause (``unreadable``, ``unlabelled``), most first."""
    return dict(Counter(cause_kind(entry["cause"]) for entry in skipped).most_common())


def configurations(
    *, settings: Settings, calibration: str | None, frames: Sequence[int], models: Sequence[CompliancePredictor],
    binning: Sequence[int] = (),
    correct_width_lag: bool = True,
) -> list[BenchConfig]:
    """Every analytical method on all loading frames and on each of ``frames``, the tactile ones on each
    ``binning`` of the depth grid, and every model with ``auto``. ``correct_width_lag``: the methods over
    all loading frames correct each record's width lag (:func:`~estimator.measure.measure_grasp`), as
    :func:`~estimator.evaluation.evaluate.evaluate_record` does by default.

    Raises SettingsError for a binning the estimator finger's grid does not take."""
    finger = settings.sensing.finger
    # A bad factor fails here, before any record is read.
    rebinned = {}
    for k in binning:
        try:
            rebinned[k] = settings.with_section(replace(estimator_settings(settings), depth_binning=k))
        except SettingsError as exc:  # the settings name their file, but the factor is the caller's
            raise SettingsError(f"binning {k} (--binning), refused as the depth binning: {exc}") from exc
    own = estimator_settings(settings).depth_binning

    def calibrated(record: GraspRecord) -> Calibration:
        return calibration_for(record.sensor(finger), calibration)

    def analytical(method: str) -> Callable[[GraspRecord], Estimate]:
        return lambda record: estimate_grasp(record, method, settings=settings, calibration=calibrated(record),
                                             correct_width_lag=correct_width_lag)

    def sampled(method: str, n: int) -> Callable[[GraspRecord], Estimate]:
        def run(record: GraspRecord) -> Estimate:
            s = sample_grasp(record, settings=settings, calibration=calibrated(record), n_frames=n, size_px=None)
            return next(e for e in s.estimates if e.method == method) if s else Estimate.refuse(method, s.reason)
        return run

    def binned(method: str, k: int) -> Callable[[GraspRecord], Estimate]:
        return lambda record: estimate_grasp(record, method, settings=rebinned[k], calibration=calibrated(record),
                                             correct_width_lag=correct_width_lag)

    configs = [BenchConfig(m, "analytical", m, None, None, analytical(m), own) for m in METHODS]
    configs += [BenchConfig(f"{m}/bin{k}", "analytical", m, None, None, binned(m, k), k)
                for k in binning for m in TACTILE_METHODS]
    configs += [BenchConfig(f"{m}@{n}f", "sampled", m, n, None, sampled(m, n), own)
                for n in frames for m in TACTILE_METHODS]
    for predictor in models:
        estimator = HybridEstimator(predictor, settings=settings, calibration=calibration)
        v = predictor.variant
        label = f"[{v.name} {v.n_frames}f {v.size_px[0]}x{v.size_px[1]}]"
        for mode, kind, method in (("model", "model", v.method), ("auto", "auto", "auto")):
            configs.append(BenchConfig(f"{method}{label}", kind, method, v.n_frames, v.size_px,
                                       lambda record, e=estimator, m=mode: e.estimate(record, mode=m), own,
                                       v.markers))
    return configs


def pareto_front(points: Sequence[tuple[float | None, ...]]) -> list[bool]:
    """Whether each point (latency, error, refusals, ...) is on the Pareto frontier.

    Every objective is minimised; a point with a None objective (no error: it answered nothing)
    is never on it and dominates nothing.
    """
    known = [None not in p for p in points]

    def dominates(a: tuple[float, ...], b: tuple[float, ...]) -> bool:
        return all(x <= y for x, y in zip(a, b, strict=True)) and any(x < y for x, y in zip(a, b, strict=True))

    return [ok and not any(known[j] and j != i and dominates(points[j], p) for j in range(len(points)))
            for i, (p, ok) in enumerate(zip(points, known, strict=True))]


@contextlib.contextmanager
def one_core() -> Iterator[bool]:
    """Pin this process to one CPU and OpenCV to one thread; yields whether pinning was possible."""
    threads = cv2.getNumThreads()
    cv2.setNumThreads(1)
    affinity = os.sched_getaffinity(0) if hasattr(os, "sched_getaffinity") else None
    try:
        if affinity:
            os.sched_setaffinity(0, {min(affinity)})
        yield bool(affinity)
    finally:
        cv2.setNumThreads(threads)
        if affinity:
            os.sched_setaffinity(0, affinity)


def timed(run: Callable[[GraspRecord], Estimate], record: GraspRecord, repeats: int) -> tuple[Estimate, float]:
    """The estimate of a warm-up run and the median time of ``repeats`` more (ms)."""
    estimate = run(record)
    times = []
    for _ in range(repeats):
        started = time.perf_counter()
        run(record)
        times.append(time.perf_counter() - started)
    return estimate, float(np.median(times)) * 1e3


def _reference_ms(record: GraspRecord, settings: Settings, repeats: int) -> float | None:
    finger, binning = settings.sensing.finger, estimator_settings(settings).depth_binning
    segment = measure_grasp(record, settings=settings, tactile=False).segment
    if not segment:
        return None
    return timed(lambda r: no_contact_reference(r, finger, segment, binning=binning), record, repeats)[1]


def bench(
    paths: Sequence[Path],
    *,
    settings: Settings,
    configs: Sequence[BenchConfig],
    calibration: str | None = None,
    repeats: int = 5,
    progress: bool = True,
) -> dict[str, Any]:
    """Time and score ``configs`` over the labelled records in ``paths`` (module notes); a record
    whose own calibration file is gone (unless ``calibration``, the one the configs were given for
    every record, serves it), or the marker finger's where a config reads it, is skipped, as
    ``estimator evaluate`` skips it (:func:`~estimator.measurements.missing_calibration`).

    Raises NothingToBench when none of ``paths`` is readable and labelled (its message counts
    the causes; its ``skipped`` names each record and its cause)."""
    rows: list[dict[str, Any]] = []
    latency: dict[str, list[float]] = {c.name: [] for c in configs}
    reference: list[float] = []
    skipped: list[dict[str, str]] = []
    markers = any(c.markers for c in configs)
    with one_core() as pinned:
        for path in progress_bar(paths, desc="bench", unit="grasp", enabled=progress):
            try:
                record = read_record(path)
            except RecordError as exc:
                skipped.append({"path": str(path), "cause": f"unreadable: {exc}"})
                continue
            finger = settings.sensing.finger
            missing = (missing_calibration(record, finger, calibration, markers=markers)
                       if finger in {s.finger for s in record.sensors} else "")  # off-finger: unreadable below
            if cause := unlabelled(record) or missing:
                skipped.append({"path": str(path), "cause": cause})
                continue
            label = record.label
            try:  # as evaluate: no sensor or frames on the finger, or frames that do not decode
                finger_sensor(record, finger)
                by_binning = {k: decoded(record, reduce=k) for k in sorted({c.binning for c in configs})}
            except (RecordError, PerceptionError) as exc:
                skipped.append({"path": str(path), "cause": f"unreadable: {exc}"})
                continue
            ref_ms = _reference_ms(by_binning[estimator_settings(settings).depth_binning], settings, repeats)
            if ref_ms is not None:
                reference.append(ref_ms)
            for config in configs:
                estimate, ms = timed(config.run, by_binning[config.binning], repeats)
                latency[config.name].append(ms)
                rows.append(result_row(path, label, config.name, estimate))
    if not rows:
        counts = ", ".join(f"{n} {cause}" for cause, n in skip_counts(skipped).items())
        raise NothingToBench(f"no labelled, readable .grasp record to bench: {len(skipped)} of {len(paths)} "
                             "records skipped"
                             + (f" ({counts})" if counts else ""), skipped)
    summary = summarise(rows, [c.name for c in configs],
                        display_range_pa=display_range_pa(settings))
    out = []
    for config in configs:
        s = summary[config.name]
        out.append({
            "name": config.name, "kind": config.kind, "method": config.method, "n_frames": config.n_frames,
            "size_px": list(config.size_px) if config.size_px else None,
            "latency_ms_p50": float(np.median(latency[config.name])),
            "latency_ms_p90": float(np.quantile(latency[config.name], 0.9)),
            "felt_log10_error": s["felt_log10_error"], "felt_within_2x": s["felt_within_2x"],
            "log10_error": s["log10_error"], "within_10x": s["within_10x"], "n": s["n"],
            "refusals": s["states"]["insufficient_data"],
        })
        if config.kind == "auto":  # where auto lands: which branch answered each grasp
            out[-1]["answered_by"] = answered_by(rows, config.name)
    objectives = [(c["latency_ms_p50"], c["felt_log10_error"], c["refusals"]) for c in out]
    for entry, flag in zip(out, pareto_front(objectives), strict=True):
        entry["pareto"] = flag
    return {"records": len(paths), "labelled": len(paths) - len(skipped),
            "skipped": skip_counts(skipped), "skipped_records": skipped, "repeats": repeats, "one_core": pinned,
            "reference_ms_p50": float(np.median(reference)) if reference else None, "configs": out}


def plot(result: dict[str, Any], path: str | Path) -> None:
    """Latency (log x, plain milliseconds) against error per configuration, the Pareto frontier
    joined; the legend outside the axes, every point's label inside them."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import FuncFormatter, LogLocator, NullFormatter

    # Frontier points last, so a dominated configuration drawn at the same place does not hide one.
    points = sorted((c for c in result["configs"] if c["felt_log10_error"] is not None), key=lambda c: c["pareto"])
    fig, ax = plt.subplots(figsize=(11, 5.5))
    frontier = sorted((c for c in points if c["pareto"]), key=lambda c: c["latency_ms_p50"])
    if len(frontier) > 1:
        ax.step([c["latency_ms_p50"] for c in frontier], [c["felt_log10_error"] for c in frontier], where="post",
                color="C3", alpha=0.4, zorder=2)
    labels = []
    for c in points:
        ax.scatter(c["latency_ms_p50"], c["felt_log10_error"], s=36, color="C3" if c["pareto"] else "C0", zorder=3)
        labels.append(ax.annotate(f"{c['name']} ({c['refusals']} refused)", (c["latency_ms_p50"], c["felt_log10_error"]),
                                  fontsize=7, xytext=(5, 2), textcoords="offset points", va="center"))
    ax.scatter([], [], color="C3", label="on the frontier (latency, error, refusals)")
    ax.scatter([], [], color="C0", label="dominated")
    # Outside the axes: inside, wherever it went, it could cover the best (lowest) configurations.
    ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0.0, fontsize=8)
    where = result.get("dir")
    ax.set(xscale="log", xlabel="latency per grasp, median (ms, one core, from decoded frames)",
           ylabel="felt error: mean |log10 E_felt - log10 E| on the display (decades)",
           title=f"Estimator configurations: latency against felt error, {result['labelled']} labelled grasps"
                 + (f"\nrecords: {where}" if where else ""))
    # Plain milliseconds (1, 2, 5, 10, 20, 50...), not only the powers of ten the data may not reach.
    ax.xaxis.set_major_locator(LogLocator(base=10.0, subs=(1.0, 2.0, 5.0)))
    ax.xaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
    ax.xaxis.set_minor_formatter(NullFormatter())
    ax.yaxis.set_major_formatter(FuncFormatter(lambda v, _: "" if v < -1e-9 else f"{v:g}"))  # no negative error
    if points:
        latencies = [c["latency_ms_p50"] for c in points]
        ax.set_xlim(min(latencies) / 1.5, max(latencies) * 1.5)
    ax.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    _place_labels(fig, ax, labels)
    fig.savefig(path, dpi=120)
    plt.close(fig)


def _place_labels(fig: Any, ax: Any, labels: list[Any]) -> None:
    """Keep the point labels inside the axes: a label that would cross the right spine goes on its
    point's left; the labels are separated (:func:`_separate_labels`) and the y limits widened until
    none crosses the bottom or top spine."""
    if not labels:
        return
    renderer = fig.canvas.get_renderer()
    box = ax.get_window_extent(renderer)
    for label in labels:
        if label.get_window_extent(renderer).x1 > box.x1:
            label.xyann = (-5, 2)
            label.set_horizontalalignment("right")
    start = [label.xyann for label in labels]
    for _ in range(8):
        for label, xy in zip(labels, start, strict=True):
            label.xyann = xy
        _separate_labels(fig, labels)
        boxes = [label.get_window_extent(renderer) for label in labels]
        below = box.y0 + 2 - min(b.y0 for b in boxes)
        above = max(b.y1 for b in boxes) - (box.y1 - 2)
        if below <= 0 and above <= 0:
            return
        y0, y1 = ax.get_ylim()
        per_px = (y1 - y0) / box.height
        ax.set_ylim(y0 - max(below, 0.0) * 1.2 * per_px, y1 + max(above, 0.0) * 1.2 * per_px)


def _separate_labels(fig: Any, labels: list[Any]) -> None:
    """Move point labels down, top to bottom, until none overlaps one placed before it."""
    renderer = fig.canvas.get_renderer()
    placed = []
    for label in sorted(labels, key=lambda t: -t.xy[1]):
        for _ in range(len(labels)):
            box = label.get_window_extent(renderer)
            if not any(box.overlaps(other) for other in placed):
                break
            dx, dy = label.xyann
            label.xyann = (dx, dy - box.height * 72.0 / fig.dpi)
        placed.append(label.get_window_extent(renderer))
