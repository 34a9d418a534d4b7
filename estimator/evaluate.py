"""``estimator evaluate``: accuracy of the analytical and learned estimators over labelled grasp records.

For every labelled ``.grasp`` under a directory, each method gives an
:class:`~estimator.estimate.Estimate`. The methods are the analytical ones
(:data:`estimator.analytical.METHODS`) and those of trained models
(:mod:`estimator.learned.hybrid`): each model gives the method its variant says,
``hybrid`` (with analytical inputs; also its ``auto`` mode) or ``cnn`` (trained
without them), named ``method`` or, where two models give the same method,
``method[variant]``. Analytical methods measure every loading frame (with the
clock-lag corrections asked for); a model measures a grasp as its training data
was measured (:func:`~estimator.learned.inputs.sample_grasp`).

Per method the summary holds

``n``
    estimates that count (every state but ``insufficient_data``);
``log10_error``
    mean ``|log10 E_hat - log10 E|`` over them (a bound counts with its bound
    value);
``within_10x``
    share of them with ``|log10 E_hat - log10 E| <= 1``;
``point_log10_error``, ``point_within_10x``
    the same with a documented point value for each bound: the geometric
    middle of the bound and the physical limit on that side
    (``E_MAX_PA`` = 1e12 Pa above diamond for a lower bound, ``E_MIN_PA`` =
    1e3 Pa below the softest gels and foams for an upper bound); an ``ok``
    estimate counts with ``E_pa``;
``ok_only``
    ``n``, ``log10_error`` and ``within_10x`` over the ``ok`` estimates alone;
``interval_coverage``
    share whose interval (open side included) contains the label;
``states``
    how many of each state, refusals included;
``per_material``, ``per_shape``
    the same metrics per label material and shape;
``paper``
    the paper's figure on unseen real objects for the same method and inputs
    (:data:`PAPER`; its ablation table), None where the paper has none;
``inputs``
    what the method reads; a model's entry also names ``model``, ``variant``,
    ``n_frames``, ``size_px`` and ``measurement_code_matches``, and an ``auto``
    entry ``answered_by`` (how many grasps each branch answered).

The methods come in the order of the paper's ablation table (:func:`ablation_order`).
``--unseen-by MODEL_DIR`` keeps only the records of objects in that model's test
split (:func:`held_out_objects`), so the table is on objects it never trained on.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import time
from collections import Counter, defaultdict
from collections.abc import Iterable, Mapping, Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from functools import lru_cache, partial
from pathlib import Path
from typing import Any

from tqdm import tqdm

from estimator.analytical import METHODS
from estimator.errors import EstimatorError, ModelError
from estimator.estimate import STATES, Estimate
from estimator.learned.dataset import load_split
from estimator.learned.hybrid import HybridEstimator
from estimator.learned.infer import CompliancePredictor, load_predictor
from estimator.learned.inputs import Variant
from estimator.measure import TACTILE_METHODS, calibration_path, estimate_grasp, measure_grasp
from estimator.perception.calibration import Calibration, load_calibration
from teleop.errors import RecordError
from teleop.record import Label, read_record
from teleop.settings import Settings, default_settings_path, load_settings

__all__ = [
    "ALL_METHODS",
    "LEARNED_METHODS",
    "PAPER",
    "ModelMethod",
    "ablation_order",
    "ablation_table",
    "answered_by",
    "evaluate_records",
    "model_methods",
    "result_row",
    "summarise",
    "held_out_objects",
]

LEARNED_METHODS = ("cnn", "hybrid", "auto")
ALL_METHODS = (*METHODS, *LEARNED_METHODS)
ANALYTICAL_INPUTS = {m: "F, w" if m not in TACTILE_METHODS else "depth, F, w" for m in METHODS}
REPO_DIR = Path(__file__).resolve().parent.parent

# The paper's unseen-object figures (ablation table): mean |log10 error| and share within one
# decade, keyed by method, and for a learned one by ``method[variant]`` (its inputs).
PAPER: dict[str, dict[str, float] | None] = {
    "no_tactile": {"log10_error": 2.13, "within_10x": 0.182},
    "elastic": {"log10_error": 1.90, "within_10x": 0.273},
    "hertz": {"log10_error": 1.68, "within_10x": 0.289},
    "split": None,
    "hybrid[rgb+markers+fw+analytical]": {"log10_error": 0.76, "within_10x": 0.735},
    "hybrid[rgb+markers+analytical]": {"log10_error": 0.76, "within_10x": 0.742},
    "hybrid[rgb+fw+analytical]": {"log10_error": 0.88, "within_10x": 0.686},
    "hybrid[rgb+analytical]": {"log10_error": 0.90, "within_10x": 0.679},
    "cnn[rgb+markers+fw]": {"log10_error": 0.86, "within_10x": 0.646},
    "cnn[rgb+markers]": {"log10_error": 0.85, "within_10x": 0.650},
    "hybrid[depth+fw+analytical]": {"log10_error": 0.98, "within_10x": 0.636},
    "hybrid[depth+analytical]": {"log10_error": 1.04, "within_10x": 0.594},
}


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
    """

    name: str
    method: str
    model_dir: str
    variant: Variant
    measurement_code_matches: bool = True

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
    a name is the method, ``method[variant]`` where two models give the method, and
    ``method[variant Nf RxC]`` where the variant alone does not tell them apart.

    Raises
    ------
    ModelError
        Two models would have the same name (the same model, or the same variant at the same
        frame count and size).
    """
    wanted = set(methods)
    found = [(method, p) for p in predictors
             for method in ((p.variant.method, "auto") if p.variant.method == "hybrid" else (p.variant.method,))
             if method in wanted]
    per_method = Counter(method for method, _ in found)
    per_variant = Counter((method, p.variant.name) for method, p in found)
    out: list[ModelMethod] = []
    for method, p in found:
        v = p.variant
        name = method
        if per_method[method] > 1:
            name = f"{method}[{v.name}]"
        if per_variant[(method, v.name)] > 1:
            name = f"{method}[{v.name} {v.n_frames}f {v.size_px[0]}x{v.size_px[1]}]"
        if any(e.name == name for e in out):
            other = next(e.model_dir for e in out if e.name == name)
            raise ModelError(f"models {other} and {p.model_dir} both give {name}: give each model once")
        out.append(ModelMethod(name, method, str(p.model_dir), v, p.measurement_code_matches))
    return out


def held_out_objects(model_dir: str | Path) -> frozenset[str]:
    """Names of the objects in a model's test split: the objects it never trained or stopped on.

    Read from ``metadata.json`` ``data.objects.test`` when it lists names, else from the
    ``split.json`` of the dataset the model was trained on (``data.dir``; a relative
    directory is looked up under the working directory, then the repository).

    Raises
    ------
    ModelError
        The metadata is unreadable or neither source names the test objects.
    """
    meta_path = Path(model_dir) / "metadata.json"
    try:
        data = json.loads(meta_path.read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise ModelError(f"{meta_path}: not a readable model metadata file ({exc})") from exc
    info = data.get("data") if isinstance(data, dict) else None
    if not isinstance(info, dict):
        raise ModelError(f"{meta_path}: no data section, so its test objects are unknown")
    objects = info.get("objects")
    listed = objects.get("test") if isinstance(objects, dict) else None
    if isinstance(listed, list):
        return frozenset(map(str, listed))
    dataset = Path(str(info.get("dir") or ""))
    candidates = [dataset] if dataset.is_absolute() else [Path.cwd() / dataset, REPO_DIR / dataset]
    split_path = next((d / "split.json" for d in candidates if info.get("dir") and (d / "split.json").is_file()),
                      None)
    if split_path is None:
        raise ModelError(f"{meta_path}: data.objects.test does not list the test objects and its dataset's "
                         f"split ({info.get('dir')!r}/split.json) is not found; rebuild that dataset "
                         "(same seed) to recover it")
    return frozenset(load_split(split_path)["test"])


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
    """For an ``auto`` method: how many grasps each branch answered (``model``, ``split``, ...,
    ``refused``), read from the reason :class:`HybridEstimator` gives."""
    return dict(Counter("refused" if r["state"] == "insufficient_data" else r["reason"].split(":")[0]
                        for r in rows if r.get("method") == method))


def evaluate_record(
    path: Path,
    *,
    settings: Settings,
    methods: Sequence[str],
    calibration: str | None,
    models: Sequence[ModelMethod] = (),
    objects: frozenset[str] | None = None,
    correct_camera_lag: bool = False,
    correct_width_lag: bool = True,
) -> list[dict[str, Any]]:
    """One row per method (analytical ``methods``, then ``models``) for a labelled record; one
    row without a method for a skipped one (unreadable, unlabelled, or its object not in
    ``objects`` when given)."""
    try:
        record = read_record(path)
    except RecordError as exc:
        return [{"path": str(path), "skipped": f"unreadable: {exc}"}]
    label = record.label
    if label is None or label.modulus_pa is None:
        return [{"path": str(path), "skipped": "unlabelled"}]
    if objects is not None and label.object_name not in objects:
        return [{"path": str(path), "skipped": f"seen: {label.object_name} is not a test object"}]
    rows = []
    if methods:
        tactile = any(m in TACTILE_METHODS for m in methods)
        cal = None
        if tactile:
            sensor = record.sensor(settings.estimator.finger)
            cal = _calibration(str(calibration_path(sensor, calibration)))
        measurements = measure_grasp(record, settings=settings, calibration=cal, tactile=tactile,
                                     correct_camera_lag=correct_camera_lag, correct_width_lag=correct_width_lag)
        rows += [result_row(path, label, m, estimate_grasp(measurements, m, settings=settings)) for m in methods]
    for entry in models:
        estimator = _hybrid_estimator(entry.model_dir, settings, calibration)
        rows.append(result_row(path, label, entry.name, estimator.estimate(record, mode=entry.mode)))
    return rows


# Physical limits of Young's modulus, for the point value of a bound (see the module docstring).
E_MAX_PA = 1e12
E_MIN_PA = 1e3


def point_value(state: str, e_pa: float) -> float:
    """The value a bound counts with in the point metrics: the geometric middle of the bound and
    the physical limit on its open side (``e_pa`` itself for ``ok`` or a bound beyond the limit)."""
    if state == "lower_bound" and e_pa < E_MAX_PA:
        return math.sqrt(e_pa * E_MAX_PA)
    if state == "upper_bound" and e_pa > E_MIN_PA:
        return math.sqrt(e_pa * E_MIN_PA)
    return e_pa


def _log_errors(rows: Sequence[dict[str, Any]], value: Any) -> list[float]:
    return [abs(math.log10(value(r)) - math.log10(r["truth_pa"])) for r in rows]


def _summary(errors: Sequence[float]) -> tuple[float | None, float | None]:
    if not errors:
        return None, None
    return sum(errors) / len(errors), sum(e <= 1.0 for e in errors) / len(errors)


def _metrics(rows: Iterable[dict[str, Any]]) -> dict[str, Any]:
    rows = list(rows)
    counted = [r for r in rows if r["state"] != "insufficient_data"]
    errors = _log_errors(counted, lambda r: r["e_pa"])
    point_error, point_within = _summary(_log_errors(counted, lambda r: point_value(r["state"], r["e_pa"])))
    ok = [r for r in counted if r["state"] == "ok"]
    ok_error, ok_within = _summary(_log_errors(ok, lambda r: r["e_pa"]))
    covered = [
        (r["low_pa"] is None or r["low_pa"] <= r["truth_pa"]) and (r["high_pa"] is None or r["truth_pa"] <= r["high_pa"])
        for r in counted
    ]
    states = Counter(r["state"] for r in rows)
    return {
        "n": len(counted),
        "log10_error": sum(errors) / len(errors) if errors else None,
        "within_10x": sum(e <= 1.0 for e in errors) / len(errors) if errors else None,
        "point_log10_error": point_error,
        "point_within_10x": point_within,
        "ok_only": {"n": len(ok), "log10_error": ok_error, "within_10x": ok_within},
        "interval_coverage": sum(covered) / len(covered) if covered else None,
        "states": {s: states.get(s, 0) for s in STATES},
    }


def summarise(rows: Sequence[dict[str, Any]], methods: Sequence[str]) -> dict[str, Any]:
    """Per-method metrics, overall and per material and shape (see the module docstring)."""
    out = {}
    for method in methods:
        mine = [r for r in rows if r.get("method") == method]
        groups: dict[str, dict[str, list]] = {"material": defaultdict(list), "shape": defaultdict(list)}
        for r in mine:
            for key, group in groups.items():
                group[r[key]].append(r)
        out[method] = {
            **_metrics(mine),
            "per_material": {k: _metrics(v) for k, v in sorted(groups["material"].items())},
            "per_shape": {k: _metrics(v) for k, v in sorted(groups["shape"].items())},
            "paper": PAPER.get(method),
        }
    return out


def ablation_order(name: str, models: Sequence[ModelMethod] = ()) -> tuple:
    """Sort key of a method in the paper's ablation table: no tactile, elastic, Hertz, the
    compliance split, the CNN alone, the hybrid, then ``auto``; within a learned method RGB
    before depth, with markers before without, with force and width before without."""
    entry = next((e for e in models if e.name == name), None)
    if entry is None:
        return (METHODS.index(name) if name in METHODS else len(ALL_METHODS), name)
    v = entry.variant
    return (len(METHODS) + LEARNED_METHODS.index(entry.method), v.image != "rgb", not v.markers,
            not v.force_width, v.n_frames, v.size_px, name)


def ablation_table(rows: Sequence[dict[str, Any]], *, methods: Sequence[str],
                   models: Sequence[ModelMethod] = ()) -> dict[str, Any]:
    """:func:`summarise` over the analytical ``methods`` and the ``models``, in the paper's
    order (:func:`ablation_order`), each with its inputs and the paper's figure for the same
    method and inputs; a model's entry also says which model, and ``auto`` who answered."""
    names = sorted([*methods, *(e.name for e in models)], key=lambda n: ablation_order(n, models))
    summary = summarise(rows, names)
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
    objects: frozenset[str] | None = None,
    workers: int = 1,
    correct_camera_lag: bool = False,
    correct_width_lag: bool = True,
    progress: bool = True,
) -> list[dict[str, Any]]:
    """Rows of :func:`evaluate_record` over ``paths``, in order, with a progress bar on stderr."""
    work = partial(evaluate_record, settings=settings, methods=tuple(methods), calibration=calibration,
                   models=tuple(models), objects=objects, correct_camera_lag=correct_camera_lag,
                   correct_width_lag=correct_width_lag)
    bar = partial(tqdm, total=len(paths), desc="evaluate", unit="grasp", disable=not progress)
    if workers <= 1:
        results = [work(p) for p in bar(paths)]
    else:
        with ProcessPoolExecutor(max_workers=workers) as pool:
            results = list(bar(pool.map(work, paths, chunksize=max(1, len(paths) // (8 * workers)))))
    return [row for rows in results for row in rows]


def plot(rows: Sequence[dict[str, Any]], methods: Sequence[str], path: str | Path) -> None:
    """Predictions against truth, log-log, one panel per method with the one-decade band and
    its figures; bounds drawn as triangles."""
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
              *(Line2D([], [], ls="", marker=mk, color=c, label=state) for state, (mk, c) in markers.items())]
    summary = summarise(scored, methods)
    for ax, method in zip(axes.flat, methods, strict=False):
        ax.fill_between(line, [v / 10 for v in line], [v * 10 for v in line], color="0.88")
        ax.plot(line, line, color="0.4", lw=1)
        for state, (marker, color) in markers.items():
            pts = [(r["truth_pa"], r["e_pa"]) for r in scored if r["method"] == method and r["state"] == state]
            if pts:
                xs, ys = zip(*pts, strict=True)
                ax.scatter(xs, ys, s=14, marker=marker, color=color, alpha=0.7)
        m = summary[method]
        figures = (f"err {m['log10_error']:.2f}, {m['within_10x']:.0%} in 10x" if m["n"] else "no estimate")
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
    fig.suptitle("Young's modulus: estimate vs label (triangles: bounds; band: one decade)", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


# --------------------------------------------------------------------------- command


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.description = (
        "Evaluate the analytical and learned estimators over the labelled .grasp records under DIR and "
        "print the paper's ablation table (rows in its order, its unseen-object figures beside them). "
        "Per method: n, log10_error (mean |log10 E_hat - log10 E|), within_10x (share with error <= 1 "
        "decade), interval_coverage (share whose interval contains the label), states, per_material "
        "and per_shape, and the paper's figure for the same method and inputs. log10_error and "
        "within_10x count a lower or upper bound with its bound value (E_pa is the bound); "
        "point_log10_error and point_within_10x count it with the geometric middle of the bound and "
        "the physical limit on its open side (1e12 Pa above a lower bound, 1e3 Pa below an upper "
        "bound); ok_only holds the figures over ok estimates alone; refusals (insufficient_data) count "
        "as missing: left out of n and the errors, reported in states. Unlabelled and unreadable "
        "records (and with --unseen-by, records of objects a model saw) are skipped and counted."
    )
    parser.add_argument("dir", metavar="DIR", help="directory searched recursively for .grasp records")
    parser.add_argument("--methods", nargs="+", choices=ALL_METHODS, default=None,
                        help="methods to evaluate (default: every analytical method and every method the "
                             "models give); cnn needs a model trained without analytical inputs, hybrid "
                             "and auto a model with them")
    parser.add_argument("--model", dest="models", action="append", metavar="DIR", default=None,
                        help="trained model directory; repeat for several. Each gives the method its "
                             "metadata's variant says: hybrid (with analytical inputs, plus its auto "
                             "mode) or cnn (without); a method two models give is named method[variant]. "
                             "Default: the settings' estimator.model_path, else the shipped model "
                             "(estimator/models/default). Read only when a learned method is evaluated")
    parser.add_argument("--unseen-by", dest="unseen_by", action="append", metavar="MODEL_DIR", default=None,
                        help="keep only records whose object is in this model's test split (metadata.json "
                             "data.objects.test, else the split.json of its dataset), so that model never "
                             "trained on them (a model trained on another split may have); repeat to keep "
                             "those in every given model's test split")
    parser.add_argument("--workers", type=int, default=1, help="worker processes")
    parser.add_argument("--plot", metavar="PNG", default=None,
                        help="write predictions vs label on log axes with the one-decade band, one panel "
                             "per method")
    parser.add_argument("--calibration", metavar="CAL", default=None,
                        help="calibration (.npz) for every record; default: the file each record's "
                             "sensor names (relative to configs/)")
    parser.add_argument("--settings", metavar="FILE", default=str(default_settings_path()),
                        help="settings TOML (estimator and gripper sections are used)")
    parser.add_argument("--camera-lag", action="store_true",
                        help="estimate and correct each record's camera clock lag (analytical methods; a "
                             "model measures grasps as its training data was measured)")
    parser.add_argument("--no-width-lag", dest="width_lag", action="store_false",
                        help="do not estimate and correct how late each record's widths are stamped "
                             "(analytical methods; by default the lag is estimated from when the fingers "
                             "stop against the force peak: a host stamps a gripper read when it returns, "
                             "~0.1 s late, which the hold frames at the peak force would otherwise misread "
                             "as approach)")
    parser.add_argument("--json", action="store_true",
                        help="print one JSON object with the summary on the last stdout line")


def _fmt(value: float | None, spec: str) -> str:
    return "-" if value is None else format(value, spec)


def _models(args: argparse.Namespace, settings: Settings) -> list[ModelMethod]:
    """The learned methods asked for (all the models give when --methods is not given)."""
    learned = LEARNED_METHODS if args.methods is None else [m for m in args.methods if m in LEARNED_METHODS]
    if not learned:
        return []
    dirs = args.models or [load_predictor(settings=settings).model_dir]
    resolved = [Path(d).resolve() for d in dirs]
    twice = sorted({str(d) for d in resolved if resolved.count(d) > 1})
    if twice:
        raise EstimatorError(f"--model {twice[0]}: given more than once")
    models = model_methods([_predictor(str(d)) for d in dirs], methods=learned)
    missing = [m for m in learned if args.methods is not None and not any(e.method == m for e in models)]
    if missing:
        kinds = ", ".join(f"{e.variant.name} ({e.method})" for e in models if e.method != "auto") or "none"
        raise EstimatorError(f"--methods {' '.join(missing)}: no model given has it (cnn needs a model trained "
                             f"without analytical inputs, hybrid and auto one with them; models: {kinds}); "
                             "add one with --model DIR")
    return models


def run(args: argparse.Namespace) -> int:
    if args.workers < 1:
        raise EstimatorError(f"--workers {args.workers}: expected at least 1")
    settings = load_settings(args.settings)
    root = Path(args.dir)
    if not root.is_dir():
        raise EstimatorError(f"{root}: not a directory")
    paths = sorted(root.rglob("*.grasp"))
    if not paths:
        raise EstimatorError(f"{root}: no .grasp records found")
    methods = list(METHODS) if args.methods is None else [m for m in args.methods if m in METHODS]
    models = _models(args, settings)
    objects = None
    if args.unseen_by:
        objects = frozenset.intersection(*(held_out_objects(d) for d in args.unseen_by))
    started = time.perf_counter()
    rows = evaluate_records(paths, settings=settings, methods=methods, calibration=args.calibration,
                            models=models, objects=objects,
                            workers=min(args.workers, os.cpu_count() or 1, len(paths)),
                            correct_camera_lag=args.camera_lag, correct_width_lag=args.width_lag)
    skipped = Counter(r["skipped"].split(":")[0] for r in rows if "skipped" in r)
    labelled = len({r["path"] for r in rows if "method" in r})
    if objects is not None and not labelled:
        raise EstimatorError(f"{root}: no labelled record is of an object in the test split of "
                             f"{', '.join(args.unseen_by)} ({len(objects)} objects)")
    summary = ablation_table(rows, methods=methods, models=models)
    if args.plot:
        plot(rows, list(summary), args.plot)
    result = {
        "dir": str(root), "records": len(paths), "labelled": labelled, "skipped": dict(skipped),
        "seconds": time.perf_counter() - started, "methods": summary,
        "models": sorted({e.model_dir for e in models}),
        "unseen_by": None if objects is None else {"models": args.unseen_by, "objects": sorted(objects)},
        "plot": args.plot,
    }
    if args.json:
        print(json.dumps(result, allow_nan=False))
        return 0
    _print_table(result, root)
    return 0


def _print_table(result: Mapping[str, Any], root: Path) -> None:
    unseen = result["unseen_by"]
    scope = "" if unseen is None else f", objects of the test split of {', '.join(unseen['models'])}"
    print(f"{result['labelled']} labelled records of {result['records']} under {root}{scope} "
          f"({result['seconds']:.1f} s)")
    print("log10 err / within10x: bounds at their value; point: bounds at the geometric middle of "
          "bound and physical limit; ok: ok estimates only; paper: its unseen-object figure for the "
          "same method and inputs")
    width = max([6, *(len(name) for name in result["methods"])])
    wide = max([6, *(len(m["inputs"] or "-") for m in result["methods"].values())])
    print(f"{'method':<{width}} {'inputs':<{wide}} {'n':>4} {'log10 err':>9} {'within10x':>9} {'point err':>9} "
          f"{'point10x':>8} {'ok n':>4} {'ok err':>6} {'coverage':>8}  {'paper':<9} states")
    for method, m in result["methods"].items():
        paper = m["paper"]
        paper_text = f"{paper['log10_error']:.2f}/{paper['within_10x']:.1%}" if paper else "-"
        states = ", ".join(f"{k} {v}" for k, v in m["states"].items() if v)
        ok = m["ok_only"]
        print(f"{method:<{width}} {m['inputs'] or '-':<{wide}} {m['n']:>4} {_fmt(m['log10_error'], '9.2f')} "
              f"{_fmt(m['within_10x'], '9.1%')} {_fmt(m['point_log10_error'], '9.2f')} "
              f"{_fmt(m['point_within_10x'], '8.1%')} {ok['n']:>4} {_fmt(ok['log10_error'], '6.2f')} "
              f"{_fmt(m['interval_coverage'], '8.1%')}  {paper_text:<9} {states}")
    for method, m in result["methods"].items():
        if "answered_by" in m:
            print(f"{method} answered by: " + ", ".join(f"{k} {v}" for k, v in sorted(m["answered_by"].items())))
    for model in sorted({m["model"] for m in result["methods"].values() if m.get("measurement_code_matches") is False}):
        print(f"note: {model} was trained on inputs measured by other code; its methods' figures are not its own")
