"""``estimator evaluate``: accuracy of the analytical and learned estimators over labelled grasp records.

For every labelled ``.grasp`` under a directory, each method gives an
:class:`~estimator.estimate.Estimate`. The methods are the analytical ones
(:data:`estimator.analytical.METHODS`) and those of trained models
(:mod:`estimator.inference.hybrid`): each model gives the method its variant says,
``hybrid`` (with analytical inputs; also its ``auto`` mode) or ``cnn`` (trained
without them), named ``method`` or, where two models give the same method,
``method[variant]``. Analytical methods measure every loading frame (with the
clock-lag corrections asked for); a model measures a grasp as its training data
was measured (:func:`~estimator.inference.sampling.sample_grasp`).

Per method the summary holds the metrics of :mod:`estimator.evaluation.metrics` (whose
docstring defines them): ``n``, ``log10_error``, ``within_10x``,
``point_log10_error``, ``point_within_10x``, ``ok_only``, what the softness
display renders for the estimate (``felt_log10_error``, ``felt_within_2x``,
``dangerous_misses``: against the label clipped to the display's range, with the
display's own mapping), the intervals (``interval_level``, the nominal coverage a
learned model states; ``interval_coverage``; ``interval_width_decades_median``, widths as
the display shows them), the same over the soft objects the display scales (``soft_n``, ``soft_refused``,
``soft_felt_log10_error``, ``soft_felt_within_2x``, ``soft_interval_coverage``,
``soft_interval_width_decades_median``: labels at or below 3 MPa),
``states``, ``per_material``, ``per_shape`` and ``paper`` (the paper's figure
for the same method and inputs, :data:`~estimator.evaluation.metrics.PAPER`). Beside them,
``inputs`` says what the method reads; a model's entry also names ``model``,
``variant``, ``n_frames``, ``size_px`` and ``measurement_code_matches``, and an
``auto`` entry ``answered_by`` (how many grasps each branch answered).

The methods come in the order of the paper's ablation table (:func:`ablation_order`).
The command line (``--unseen-by``, ``--rows``, the printed table) is
:mod:`estimator.evaluation.evaluate_cli`; the metrics are re-exported here for existing
importers.
"""

from __future__ import annotations

import math
import os
from collections import Counter
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from functools import lru_cache, partial
from pathlib import Path
from typing import Any

from estimator.analytical import METHODS
from estimator.errors import CalibrationError, ModelError, PerceptionError
from estimator.estimate import Estimate
from estimator.evaluation.metrics import E_MAX_PA, E_MIN_PA, PAPER, point_value, summarise
from estimator.inference.hybrid import ALL_METHODS, LEARNED_METHODS, HybridEstimator
from estimator.inference.infer import CompliancePredictor
from estimator.inference.inputs import Variant
from estimator.measure import estimate_grasp, finger_sensor, measure_grasp
from estimator.measurements import TACTILE_METHODS, calibration_path, missing_calibration
from estimator.perception.calibration import Calibration, load_calibration
from teleop.errors import RecordError
from teleop.parallel import progress_map
from teleop.record import GraspRecord, Label, read_record
from teleop.settings import Settings

__all__ = [
    "E_MAX_PA",
    "E_MIN_PA",
    "PAPER",
    "ModelMethod",
    "ablation_order",
    "ablation_table",
    "answered_by",
    "cause_kind",
    "evaluate_records",
    "model_methods",
    "plot",
    "point_value",
    "result_row",
    "skip_cause",
    "summarise",
    "unlabelled",
]

ANALYTICAL_INPUTS = {m: "F, w" if m not in TACTILE_METHODS else "depth, F, w" for m in METHODS}


@dataclass(frozen=True)
class ModelMethod:
    """One learned method to evaluate: a model's own method (``hybrid``/``cnn``) or its ``auto`` mode.

    Attributes
    ----------
    name : str
        The method's name in the summary (``hybrid``, ``auto[depth+analytical]``, ...).
    method : {"hybrid", "cnn", "auto"}
    model_dir : str
    variant : Variant
        The model's inputs.
    measurement_code_matches : bool
        Whether this code measures grasps as the code that built the model's training data.
    interval_level : float or None
        The nominal coverage of the model's intervals (``CompliancePredictor.interval_level``,
        e.g. 0.9); None where the model does not state it.
    """

    name: str
    method: str
    model_dir: str
    variant: Variant
    measurement_code_matches: bool = True
    interval_level: float | None = None

    @property
    def mode(self) -> str:
        """The :meth:`HybridEstimator.estimate` mode that gives this method."""
        return "auto" if self.method == "auto" else "model"

    @property
    def inputs(self) -> str:
        size = self.variant.size_px
        return f"{self.variant.name}, {self.variant.n_frames} frames {size[0]}x{size[1]}"


def model_methods(predictors: Sequence[CompliancePredictor], *,
                  methods: Iterable[str] = LEARNED_METHODS) -> list[ModelMethod]:
    """The learned methods of ``predictors`` that are in ``methods``, named (module notes).

    Each model gives its variant's method (``hybrid`` or ``cnn``) and a hybrid also ``auto``;
    a name is the method, ``method[variant]`` where two models give the method,
    ``method[variant Nf RxC]`` where the variant alone does not tell them apart, and
    ``method[variant MODEL_DIR]`` where frames and size do not either.

    Raises
    ------
    ModelError
        The same model directory is given twice.
    """
    wanted = set(methods)
    found = [(method, p) for p in predictors
             for method in ((p.variant.method, "auto") if p.variant.method == "hybrid" else (p.variant.method,))
             if method in wanted]
    per_method = Counter(method for method, _ in found)
    per_variant = Counter((method, p.variant.name) for method, p in found)
    per_shape = Counter((method, p.variant.name, p.variant.n_frames, p.variant.size_px) for method, p in found)
    out: list[ModelMethod] = []
    for method, p in found:
        v = p.variant
        name = method
        if per_method[method] > 1:
            name = f"{method}[{v.name}]"
        if per_variant[(method, v.name)] > 1:
            name = f"{method}[{v.name} {v.n_frames}f {v.size_px[0]}x{v.size_px[1]}]"
        if per_shape[(method, v.name, v.n_frames, v.size_px)] > 1:  # e.g. a model and its fine-tuned copy
            name = f"{method}[{v.name} {p.model_dir}]"
        if any(e.name == name for e in out):
            other = next(e.model_dir for e in out if e.name == name)
            raise ModelError(f"models {other} and {p.model_dir} both give {name}: give each model once")
        # An older predictor has no interval_level: the model then states no coverage.
        out.append(ModelMethod(name, method, str(p.model_dir), v, p.measurement_code_matches,
                               getattr(p, "interval_level", None)))
    return out


@lru_cache(maxsize=8)
def _calibration(path: str) -> Calibration:
    return load_calibration(path)


@lru_cache(maxsize=8)
def _predictor(model_dir: str) -> CompliancePredictor:
    return CompliancePredictor(model_dir, threads=1)


@lru_cache(maxsize=8)
def _hybrid_estimator(model_dir: str, settings: Settings, calibration: str | None) -> HybridEstimator:
    return HybridEstimator(_predictor(model_dir), settings=settings, calibration=calibration)


def result_row(path: str | Path, label: Label, method: str, estimate: Estimate) -> dict[str, Any]:
    """One scored row: the record, its label and one method's estimate (what :func:`summarise` reads)."""
    low, high = estimate.interval_pa
    return {
        "path": str(path), "object": label.object_name, "material": label.material or "unknown",
        "shape": label.shape or "unknown", "truth_pa": label.modulus_pa, "method": method,
        "state": estimate.state, "e_pa": estimate.e_pa, "low_pa": low, "high_pa": high, "reason": estimate.reason,
    }


def answered_by(rows: Iterable[dict[str, Any]], method: str) -> dict[str, int]:
    """For an ``auto`` method: how many grasps each branch answered (``model``, ``series``, ...,
    ``refused``), read from the reason :class:`HybridEstimator` gives."""
    return dict(Counter("refused" if r["state"] == "insufficient_data" else r["reason"].split(":")[0]
                        for r in rows if r.get("method") == method))


def skip_cause(row: dict[str, Any]) -> str:
    """The kind of a skipped row's cause: ``unreadable``, ``unlabelled``, ``calibration missing``,
    ``calibration unusable`` or ``trained on``."""
    return cause_kind(row["skipped"])


def cause_kind(cause: str) -> str:
    """The kind of a cause of skipping a record, the words before its colon (``unreadable: ...``)."""
    return cause.split(":")[0]


def unlabelled(record: GraspRecord) -> str:
    """Why ``record`` has no modulus to score against (``unlabelled: ...``), or '' when it has one."""
    label = record.label
    if label is None:
        return "unlabelled: no label"
    return f"unlabelled: {label.object_name} has no modulus" if label.modulus_pa is None else ""


def evaluate_record(
    path: Path,
    *,
    settings: Settings,
    methods: Sequence[str],
    calibration: str | None,
    models: Sequence[ModelMethod] = (),
    exclude: frozenset[str] | None = None,
    correct_camera_lag: bool = False,
    correct_width_lag: bool = True,
) -> list[dict[str, Any]]:
    """One row per method (analytical ``methods``, then ``models``) for a labelled record; one
    row without a method for a skipped one, whose ``skipped`` says why: ``unreadable: ...``,
    ``unlabelled`` (no label, or no modulus), ``calibration missing: ...`` (a calibration file the
    record names is absent, the marker finger's included for a model with markers:
    :func:`~estimator.measurements.missing_calibration`), ``calibration unusable: ...`` (one it names does not load), or
    ``trained on: OBJECT`` (its object is in ``exclude``, the objects a model trained on:
    :func:`~estimator.inference.provenance.trained_objects`).

    Raises
    ------
    CalibrationError
        ``calibration`` (given for every record) cannot be used: the run's problem, not one record's.
    """
    try:
        record = read_record(path)
    except RecordError as exc:
        return [{"path": str(path), "skipped": f"unreadable: {exc}"}]
    label = record.label
    if cause := unlabelled(record):
        return [{"path": str(path), "skipped": cause, **({} if label is None else {"object": label.object_name})}]
    if exclude is not None and label.object_name in exclude:
        return [{"path": str(path), "skipped": f"trained on: {label.object_name}", "object": label.object_name}]
    rows = []
    try:  # frames that do not decode, or not of the sensor's size, are read only here
        # A record without the settings' finger is skipped here: the fits' FitError would also
        # stand for a bug, which must not pass for one record's problem.
        sensor = finger_sensor(record, settings.sensing.finger)
        if methods:
            tactile = any(m in TACTILE_METHODS for m in methods)
            cal = None
            if tactile:
                cal = _calibration(str(calibration_path(sensor, calibration)))
            measurements = measure_grasp(record, settings=settings, calibration=cal, tactile=tactile,
                                         correct_camera_lag=correct_camera_lag, correct_width_lag=correct_width_lag)
            rows += [result_row(path, label, m, estimate_grasp(measurements, m, settings=settings)) for m in methods]
        for entry in models:
            estimator = _hybrid_estimator(entry.model_dir, settings, calibration)
            rows.append(result_row(path, label, entry.name, estimator.estimate(record, mode=entry.mode)))
    except (RecordError, PerceptionError) as exc:
        return [{"path": str(path), "skipped": f"unreadable: {exc}", "object": label.object_name}]
    except CalibrationError as exc:
        missing = missing_calibration(record, settings.sensing.finger, calibration,
                                      markers=any(e.variant.markers for e in models))
        if not missing and calibration is not None:
            raise  # the file --calibration gives serves every record: the run stops on it
        cause = missing or f"calibration unusable: {exc}"
        return [{"path": str(path), "skipped": cause, "object": label.object_name}]
    return rows


# Physical limits of Young's modulus, for the point value of a bound (see the module docstring).
def ablation_order(name: str, models: Sequence[ModelMethod] = ()) -> tuple:
    """Sort key of a method in the paper's ablation table: no tactile, elastic, Hertz, the
    series-compliance fit, the CNN alone, the hybrid, then ``auto``; within a learned method RGB
    before depth, with markers before without, with force and width before without."""
    entry = next((e for e in models if e.name == name), None)
    if entry is None:
        return (METHODS.index(name) if name in METHODS else len(ALL_METHODS), name)
    v = entry.variant
    return (len(METHODS) + LEARNED_METHODS.index(entry.method), v.image != "rgb", not v.markers,
            not v.force_width, v.n_frames, v.size_px, name)


def ablation_table(rows: Sequence[dict[str, Any]], *, methods: Sequence[str],
                   models: Sequence[ModelMethod] = (),
                   display_range_pa: tuple[float, float] | None = None) -> dict[str, Any]:
    """:func:`summarise` over the analytical ``methods`` and the ``models``, in the paper's
    order (:func:`ablation_order`), each with its inputs and the paper's figure for the same
    method and inputs; a model's entry also says which model and its ``interval_level``, and
    ``auto`` who answered. ``display_range_pa`` (the display's ``(e_soft_pa, e_rigid_pa)``)
    gives the felt and width figures; without it they are None."""
    names = sorted([*methods, *(e.name for e in models)], key=lambda n: ablation_order(n, models))
    summary = summarise(rows, names, display_range_pa=display_range_pa,
                        interval_levels={e.name: e.interval_level for e in models})
    for name, entry in summary.items():
        model = next((e for e in models if e.name == name), None)
        if model is None:
            entry.update(inputs=ANALYTICAL_INPUTS.get(name), paper=PAPER.get(name))
            continue
        entry.update(inputs=model.inputs, paper=PAPER.get(f"{model.method}[{model.variant.name}]"),
                     model=model.model_dir, variant=model.variant.name, n_frames=model.variant.n_frames,
                     size_px=list(model.variant.size_px), measurement_code_matches=model.measurement_code_matches)
        if model.method == "auto":
            entry["answered_by"] = answered_by(rows, name)
    return summary


def evaluate_records(
    paths: Sequence[Path],
    *,
    settings: Settings,
    methods: Sequence[str],
    calibration: str | None = None,
    models: Sequence[ModelMethod] = (),
    exclude: frozenset[str] | None = None,
    workers: int = 1,
    correct_camera_lag: bool = False,
    correct_width_lag: bool = True,
    progress: bool = True,
) -> list[dict[str, Any]]:
    """Rows of :func:`evaluate_record` over ``paths``, in order, with a progress bar on stderr; records
    of an object in ``exclude`` are skipped (``trained on``)."""
    work = partial(evaluate_record, settings=settings, methods=tuple(methods), calibration=calibration,
                   models=tuple(models), exclude=exclude, correct_camera_lag=correct_camera_lag,
                   correct_width_lag=correct_width_lag)
    results = progress_map(work, paths, workers=workers, desc="evaluate", progress=progress)
    return [row for rows in results for row in rows]


def plot(rows: Sequence[dict[str, Any]], methods: Sequence[str], path: str | Path, *,
         display_range_pa: tuple[float, float] | None = None, image_format: str | None = None) -> None:
    """Predictions against truth, log-log, one panel per method with the one-decade band and
    its figures; bounds drawn as triangles; the display's range (``display_range_pa``) as dashed
    lines, with the felt figures. ``image_format`` (``png``, ``svg``...): by default the one
    ``path``'s suffix names."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    scored = [r for r in rows if r.get("method") in methods]
    values = [r["truth_pa"] for r in scored] + [r["e_pa"] for r in scored if r.get("e_pa")]
    lo, hi = (min(values) / 3, max(values) * 3) if values else (1e3, 1e12)
    line = [lo, hi]
    cols = min(3, max(1, len(methods)))
    nrows = max(1, math.ceil(len(methods) / cols))
    fig, axes = plt.subplots(nrows, cols, figsize=(3.6 * cols, 3.5 * nrows), sharex=True, sharey=True,
                             squeeze=False)
    markers = {"ok": ("o", "C0"), "lower_bound": ("^", "C3"), "upper_bound": ("v", "C2")}
    legend = [Patch(color="0.88", label="within 10x"),
              *([Line2D([], [], ls="--", color="C1", lw=1, label="display range")] if display_range_pa else []),
              *(Line2D([], [], ls="", marker=mk, color=c, label=state) for state, (mk, c) in markers.items())]
    summary = summarise(scored, methods, display_range_pa=display_range_pa)
    for ax, method in zip(axes.flat, methods, strict=False):
        ax.fill_between(line, [v / 10 for v in line], [v * 10 for v in line], color="0.88")
        ax.plot(line, line, color="0.4", lw=1)
        for end in display_range_pa or ():
            ax.axhline(end, ls="--", color="C1", lw=1)
        for state, (marker, color) in markers.items():
            pts = [(r["truth_pa"], r["e_pa"]) for r in scored if r["method"] == method and r["state"] == state]
            if pts:
                xs, ys = zip(*pts, strict=True)
                ax.scatter(xs, ys, s=14, marker=marker, color=color, alpha=0.7)
        m = summary[method]
        figures = (f"err {m['log10_error']:.2f} decades, {m['within_10x']:.0%} in 10x" if m["n"] else "no estimate")
        if m["n"] and m.get("felt_log10_error") is not None:
            figures += f"\nfelt err {m['felt_log10_error']:.2f} decades, {m['felt_within_2x']:.0%} in 2x"
        ax.set_title(f"{method}\n{figures} (n={m['n']})", fontsize=8)
        ax.set(xscale="log", yscale="log", xlim=line, ylim=line)
        ax.tick_params(labelsize=7)
    for ax in axes.flat[len(methods):]:
        ax.set_visible(False)
    for ax in axes[-1]:
        ax.set_xlabel("label E (Pa)", fontsize=8)
    for ax in axes[:, 0]:
        ax.set_ylabel("estimated E (Pa)", fontsize=8)
    axes.flat[0].legend(handles=legend, loc="upper left", fontsize=6)
    where = _records_dir([r["path"] for r in rows if r.get("path")])
    fig.suptitle("Young's modulus: estimate vs label (triangles: bounds; band: one decade)"
                 + (f"\nrecords: {where}" if where else ""), fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=120, format=image_format)  # the format: a staged path's name does not say it
    plt.close(fig)


def _records_dir(paths: Sequence[str]) -> str | None:
    """The directory the scored records lie in (the deepest one holding them all), None without one."""
    if not paths:
        return None
    try:
        return os.path.commonpath([os.path.dirname(os.path.abspath(p)) for p in paths])
    except ValueError:  # paths on different drives
        return None
