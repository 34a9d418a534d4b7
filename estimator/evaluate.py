"""``estimator evaluate``: accuracy of the analytical estimators over labelled grasp records.

For every labelled ``.grasp`` under a directory, each method gives an
:class:`~estimator.estimate.Estimate`; per method the summary holds

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
    the paper's figure for that method on unseen real objects, for comparison.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import time
from collections import Counter, defaultdict
from collections.abc import Iterable, Sequence
from concurrent.futures import ProcessPoolExecutor
from functools import lru_cache, partial
from pathlib import Path
from typing import Any

from tqdm import tqdm

from estimator.analytical import METHODS
from estimator.errors import EstimatorError
from estimator.estimate import STATES
from estimator.measure import TACTILE_METHODS, calibration_path, estimate_grasp, measure_grasp
from estimator.perception.calibration import Calibration, load_calibration
from teleop.errors import RecordError
from teleop.record import read_record
from teleop.settings import Settings, default_settings_path, load_settings

__all__ = ["PAPER", "evaluate_records", "summarise"]

# The paper's unseen-object figures: mean |log10 error| and share within one decade.
PAPER: dict[str, dict[str, float] | None] = {
    "no_tactile": {"log10_error": 2.13, "within_10x": 0.182},
    "elastic": {"log10_error": 1.90, "within_10x": 0.273},
    "hertz": {"log10_error": 1.68, "within_10x": 0.289},
    "split": None,
}


@lru_cache(maxsize=8)
def _calibration(path: str) -> Calibration:
    return load_calibration(path)


def evaluate_record(
    path: Path,
    *,
    settings: Settings,
    methods: Sequence[str],
    calibration: str | None,
    correct_camera_lag: bool = False,
    correct_width_lag: bool = True,
) -> list[dict[str, Any]]:
    """One row per method for a labelled record; one row without a method for a skipped one."""
    try:
        record = read_record(path)
    except RecordError as exc:
        return [{"path": str(path), "skipped": f"unreadable: {exc}"}]
    label = record.label
    if label is None or label.modulus_pa is None:
        return [{"path": str(path), "skipped": "unlabelled"}]
    tactile = any(m in TACTILE_METHODS for m in methods)
    cal = None
    if tactile:
        sensor = record.sensor(settings.estimator.finger)
        cal = _calibration(str(calibration_path(sensor, calibration)))
    measurements = measure_grasp(record, settings=settings, calibration=cal, tactile=tactile,
                                 correct_camera_lag=correct_camera_lag, correct_width_lag=correct_width_lag)
    rows = []
    for method in methods:
        est = estimate_grasp(measurements, method, settings=settings)
        low, high = est.interval_pa
        rows.append({
            "path": str(path), "object": label.object_name, "material": label.material or "unknown",
            "shape": label.shape or "unknown", "truth_pa": label.modulus_pa, "method": method,
            "state": est.state, "e_pa": est.e_pa, "low_pa": low, "high_pa": high, "reason": est.reason,
        })
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


def evaluate_records(
    paths: Sequence[Path],
    *,
    settings: Settings,
    methods: Sequence[str],
    calibration: str | None = None,
    workers: int = 1,
    correct_camera_lag: bool = False,
    correct_width_lag: bool = True,
    progress: bool = True,
) -> list[dict[str, Any]]:
    """Rows of :func:`evaluate_record` over ``paths``, in order, with a progress bar on stderr."""
    work = partial(evaluate_record, settings=settings, methods=tuple(methods), calibration=calibration,
                   correct_camera_lag=correct_camera_lag, correct_width_lag=correct_width_lag)
    bar = partial(tqdm, total=len(paths), desc="evaluate", unit="grasp", disable=not progress)
    if workers <= 1:
        results = [work(p) for p in bar(paths)]
    else:
        with ProcessPoolExecutor(max_workers=workers) as pool:
            results = list(bar(pool.map(work, paths, chunksize=max(1, len(paths) // (8 * workers)))))
    return [row for rows in results for row in rows]


def plot(rows: Sequence[dict[str, Any]], methods: Sequence[str], path: str | Path) -> None:
    """Predictions against truth, log-log, with the one-decade band; bounds drawn as triangles."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.5, 6))
    values = [r["truth_pa"] for r in rows if "method" in r] + [r["e_pa"] for r in rows if r.get("e_pa")]
    lo, hi = (min(values) / 3, max(values) * 3) if values else (1e3, 1e12)
    line = [lo, hi]
    ax.fill_between(line, [v / 10 for v in line], [v * 10 for v in line], color="0.88", label="within 10x")
    ax.plot(line, line, color="0.4", lw=1)
    markers = {"ok": "o", "lower_bound": "^", "upper_bound": "v"}
    for i, method in enumerate(methods):
        color = f"C{i}"
        for state, marker in markers.items():
            pts = [(r["truth_pa"], r["e_pa"]) for r in rows if r.get("method") == method and r["state"] == state]
            if pts:
                xs, ys = zip(*pts, strict=True)
                ax.scatter(xs, ys, s=18, marker=marker, color=color, alpha=0.7,
                           label=method if state == "ok" else None)
    ax.set(xscale="log", yscale="log", xlim=line, ylim=line, xlabel="label E (Pa)", ylabel="estimated E (Pa)",
           title="Young's modulus: estimate vs label (triangles: bounds)")
    ax.legend(loc="upper left", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


# --------------------------------------------------------------------------- command


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.description = (
        "Evaluate the analytical estimators over the labelled .grasp records under DIR. Per method: "
        "n, log10_error (mean |log10 E_hat - log10 E|), within_10x (share with error <= 1 decade), "
        "interval_coverage (share whose interval contains the label), states, per_material and "
        "per_shape, and the paper's figure. log10_error and within_10x count a lower or upper bound "
        "with its bound value (E_pa is the bound); point_log10_error and point_within_10x count it "
        "with the geometric middle of the bound and the physical limit on its open side (1e12 Pa "
        "above a lower bound, 1e3 Pa below an upper bound); ok_only holds the figures over ok "
        "estimates alone; refusals (insufficient_data) count as missing: left out of n and the "
        "errors, reported in states. Unlabelled and unreadable records are skipped and counted."
    )
    parser.add_argument("dir", metavar="DIR", help="directory searched recursively for .grasp records")
    parser.add_argument("--methods", nargs="+", choices=METHODS, default=list(METHODS),
                        help="methods to evaluate")
    parser.add_argument("--workers", type=int, default=1, help="worker processes")
    parser.add_argument("--plot", metavar="PNG", default=None,
                        help="write a predictions-vs-label log-log plot with the one-decade band")
    parser.add_argument("--calibration", metavar="CAL", default=None,
                        help="calibration (.npz) for every record; default: the file each record's "
                             "sensor names (relative to configs/)")
    parser.add_argument("--settings", metavar="FILE", default=str(default_settings_path()),
                        help="settings TOML (estimator and gripper sections are used)")
    parser.add_argument("--camera-lag", action="store_true",
                        help="estimate and correct each record's camera clock lag")
    parser.add_argument("--no-width-lag", dest="width_lag", action="store_false",
                        help="do not estimate and correct how late each record's widths are stamped "
                             "(by default the lag is estimated from when the fingers stop against the "
                             "force peak: a host stamps a gripper read when it returns, ~0.1 s late, "
                             "which the hold frames at the peak force would otherwise misread as "
                             "approach)")
    parser.add_argument("--json", action="store_true",
                        help="print one JSON object with the summary on the last stdout line")


def _fmt(value: float | None, spec: str) -> str:
    return "-" if value is None else format(value, spec)


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
    started = time.perf_counter()
    rows = evaluate_records(paths, settings=settings, methods=args.methods, calibration=args.calibration,
                            workers=min(args.workers, os.cpu_count() or 1, len(paths)),
                            correct_camera_lag=args.camera_lag, correct_width_lag=args.width_lag)
    skipped = Counter(r["skipped"].split(":")[0] for r in rows if "skipped" in r)
    summary = summarise(rows, args.methods)
    if args.plot:
        plot(rows, args.methods, args.plot)
    result = {
        "dir": str(root), "records": len(paths), "labelled": len({r["path"] for r in rows if "method" in r}),
        "skipped": dict(skipped), "seconds": time.perf_counter() - started, "methods": summary,
        "plot": args.plot,
    }
    if args.json:
        print(json.dumps(result, allow_nan=False))
        return 0
    print(f"{result['labelled']} labelled records of {len(paths)} under {root} ({result['seconds']:.1f} s)")
    print("log10 err / within10x: bounds at their value; point: bounds at the geometric middle of "
          "bound and physical limit; ok: ok estimates only")
    print(f"{'method':<11} {'n':>4} {'log10 err':>9} {'within10x':>9} {'point err':>9} {'point10x':>8} "
          f"{'ok n':>4} {'ok err':>6} {'coverage':>8}  paper   states")
    for method, m in summary.items():
        paper = PAPER.get(method)
        paper_text = f"{paper['log10_error']:.2f}/{paper['within_10x']:.0%}" if paper else "-"
        states = ", ".join(f"{k} {v}" for k, v in m["states"].items() if v)
        ok = m["ok_only"]
        print(f"{method:<11} {m['n']:>4} {_fmt(m['log10_error'], '9.2f')} {_fmt(m['within_10x'], '9.1%')} "
              f"{_fmt(m['point_log10_error'], '9.2f')} {_fmt(m['point_within_10x'], '8.1%')} "
              f"{ok['n']:>4} {_fmt(ok['log10_error'], '6.2f')} "
              f"{_fmt(m['interval_coverage'], '8.1%')}  {paper_text:<7} {states}")
    return 0
