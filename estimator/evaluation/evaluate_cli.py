"""``estimator evaluate`` command line: score the estimators over labelled grasp records.

Runs :func:`~estimator.evaluation.evaluate.evaluate_records` over the ``.grasp`` records
under a directory, summarises them with :func:`~estimator.evaluation.evaluate.ablation_table`
(metrics: :mod:`estimator.evaluation.metrics`, against the softness display's range from
the settings) and prints the paper's ablation table, or with ``--json`` one JSON
object on the last stdout line. ``--rows FILE.csv`` writes every scored grasp
(:func:`write_rows`); ``--plot`` draws predictions against labels.
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import json
import os
import shlex
import sys
import time
from collections import Counter
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from estimator.analytical import METHODS
from estimator.errors import EstimatorError
from estimator.evaluation.evaluate import (
    ModelMethod,
    _predictor,
    ablation_table,
    evaluate_records,
    model_methods,
    plot,
    skip_cause,
)
from estimator.evaluation.metrics import felt_pa
from estimator.inference.hybrid import ALL_METHODS, LEARNED_METHODS
from estimator.inference.infer import load_predictor
from estimator.inference.provenance import trained_objects
from haptics.settings import display_range_pa
from teleop.clikit import PLOT_SUFFIXES, output_file
from teleop.record import find_records
from teleop.settings import Settings, default_settings_path, load_settings
from teleop.staging import staged

__all__ = ["ROW_COLUMNS", "add_arguments", "fmt_value", "print_skipped", "run", "skipped_records", "unseen_by", "write_rows"]

#: The columns of ``--rows``: one row per grasp and method.
ROW_COLUMNS = ("record", "object", "material", "shape", "truth_pa", "method", "state", "e_pa", "low_pa",
               "high_pa", "felt_pa", "reason")


def write_rows(rows: Sequence[Mapping[str, Any]], path: str | Path, *,
               display_range_pa: tuple[float, float]) -> int:
    """Write the scored rows as CSV (:data:`ROW_COLUMNS`), one per grasp and method.

    Parameters
    ----------
    rows : sequence of mapping
        Rows of :func:`~estimator.evaluation.evaluate.evaluate_records`; skipped records (rows without a
        method) are left out.
    path : str or Path
        The CSV file to write.
    display_range_pa : (float, float)
        The display's ``(e_soft_pa, e_rigid_pa)``, for ``felt_pa`` (the modulus the display
        renders: :func:`~estimator.evaluation.metrics.felt_pa`).

    Returns
    -------
    int
        How many rows were written. An empty cell is None: an open interval side, or no
        estimate and nothing felt for a refusal.
    """
    scored = [r for r in rows if "method" in r]
    with open(path, "w", newline="", encoding="utf-8") as handle:
        writer = csv.writer(handle)
        writer.writerow(ROW_COLUMNS)
        for r in scored:
            values = {**r, "record": r["path"], "felt_pa": felt_pa(r, display_range_pa=display_range_pa)}
            writer.writerow(["" if values.get(c) is None else values[c] for c in ROW_COLUMNS])
    return len(scored)


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
        "as missing: left out of every figure but states and soft_refused (of n, the errors and shares, "
        "rigid_shown_rigid, coverage and the width medians). What the softness display "
        "renders (its own mapping, over the settings' display range [e_soft_pa, e_rigid_pa]) is scored "
        "against the label clipped to that range: felt_log10_error, felt_within_2x (share within a "
        "factor 2), dangerous_misses (a rigid object, label >= 100 MPa, felt below the lower of 1 MPa and "
        "the display's rigid end, or a soft one, label <= 1 MPa, felt at or above the lower of 10 MPa and "
        "the display's rigid end), rigid_shown_rigid (share of the rigid objects' grasps rendered rigid); "
        "shown_unknown counts the estimates whose interval spans the display's whole range: shown as "
        "unknown, they are left out of the felt figures and dangerous_misses (which are over n minus "
        "shown_unknown) but stay in rigid_shown_rigid as not rigid and in the width medians at the whole "
        "range's width; interval_level is the coverage a model states for its intervals, "
        "interval_width_decades_median the median interval width in decades as the display shows it "
        "(soft_...: over labels at or below 3 MPa; soft_n counts those grasps' estimates, soft_refused "
        "their refusals). Unreadable and unlabelled records (and with --unseen-by, "
        "records of objects a model trained on) are skipped and listed by name with the cause; a run that "
        "scores no record exits with status 2."
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
                        help="keep only records whose object this model did not train on: skip the objects its "
                             "metadata.json lists as train or val objects (val objects chose its epoch and "
                             "calibrated its intervals; a fine-tuned model lists its fine-tuning objects among "
                             "the train ones) or, where it lists no names, its dataset's split.json does. Any "
                             "other object is kept, whatever the records' source (the published table's test "
                             "objects, a lab's session records). Repeat to keep only objects no given model "
                             "trained on")
    parser.add_argument("--workers", type=int, default=1, help="worker processes")
    parser.add_argument("--plot", metavar="PNG", default=None,
                        help="write predictions vs label on log axes with the one-decade band, one panel "
                             "per method")
    parser.add_argument("--rows", metavar="FILE.csv", default=None,
                        help="write one CSV row per grasp and method: record (path), object, material, "
                             "shape, truth_pa (label), method, state, e_pa, low_pa, high_pa (the interval), "
                             "felt_pa (the modulus the display renders for the estimate) and reason; an "
                             "empty cell is none (an open interval side; no estimate for a refusal)")
    parser.add_argument("--calibration", metavar="CAL", default=None,
                        help="calibration (.npz) for every record; default: the file each record's "
                             "sensor names (as the record's settings resolved it)")
    parser.add_argument("--settings", metavar="FILE", default=str(default_settings_path()),
                        help="settings TOML (estimator and gripper sections are used, and the display's "
                             "range e_soft_pa..e_rigid_pa for the felt figures)")
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
                        help="print one JSON object with the summary on the last stdout line (with 'command', the "
                             "command line that made it, which estimator card quotes)")


def fmt_value(value: float | None, spec: str) -> str:
    """``value`` formatted by ``spec``; None as "-", right-aligned to the spec's width."""
    if value is None:
        width = "".join(c for c in spec.split(".")[0] if c.isdigit())
        return format("-", f">{width}") if width else "-"
    return format(value, spec)


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
    predictors = [_predictor(str(d)) for d in dirs]
    models = model_methods(predictors, methods=learned)
    missing = [m for m in learned if args.methods is not None and not any(e.method == m for e in models)]
    if missing:
        # Every model loaded (the shipped default when none was given), not only those of the methods asked for.
        kinds = ", ".join(f"{p.variant.name} ({p.variant.method}) in {p.model_dir}" for p in predictors)
        raise EstimatorError(f"--methods {' '.join(missing)}: no model given has it (cnn needs a model trained "
                             f"without analytical inputs, hybrid and auto one with them; models: {kinds}); "
                             "add one with --model DIR")
    return models


def unseen_by(model_dirs: Sequence[str]) -> dict[str, list[str]]:
    """Object name -> the models of ``model_dirs`` that trained on it (:func:`trained_objects`)."""
    by_object: dict[str, list[str]] = {}
    for model_dir in model_dirs:
        for name in trained_objects(model_dir):
            by_object.setdefault(name, []).append(str(model_dir))
    return by_object


def skipped_records(rows: Sequence[Mapping[str, Any]], *,
                    trained_by: Mapping[str, Sequence[str]] | None = None) -> list[dict[str, str]]:
    """The skipped records of ``rows``, each ``{"path", "cause"}``: ``unreadable: ...``, ``unlabelled: ...``
    or ``excluded by --unseen-by: MODEL trained on OBJECT`` (``trained_by``: object -> models)."""
    out = []
    for r in rows:
        if "skipped" not in r:
            continue
        cause = r["skipped"]
        if skip_cause(r) == "trained on":
            models = ", ".join((trained_by or {}).get(r.get("object", ""), [])) or "a model"
            cause = f"excluded by --unseen-by: {models} trained on {r.get('object')}"
        out.append({"path": r["path"], "cause": cause})
    return out


def print_skipped(skipped: Sequence[Mapping[str, str]], total: int, *, file: Any = None, limit: int = 50) -> None:
    """List skipped records, one a line with its cause (the first ``limit``; ``--json`` holds them all)."""
    if not skipped:
        return
    print(f"skipped {len(skipped)} of {total} records:", file=file)
    for entry in skipped[:limit]:
        print(f"  {entry['path']}: {entry['cause']}", file=file)
    if len(skipped) > limit:
        print(f"  ... and {len(skipped) - limit} more (--json lists every one)", file=file)


def run(args: argparse.Namespace) -> int:
    if args.workers < 1:
        raise EstimatorError(f"--workers {args.workers}: expected at least 1")
    plot_path = output_file("--plot", args.plot, suffixes=PLOT_SUFFIXES)
    rows_path = output_file("--rows", args.rows, suffixes=(".csv",))
    settings = load_settings(args.settings)
    root = Path(args.dir)
    paths = find_records(root)
    methods = list(METHODS) if args.methods is None else [m for m in args.methods if m in METHODS]
    trained_by = unseen_by(args.unseen_by) if args.unseen_by else None
    models = _models(args, settings)
    started = time.perf_counter()
    rows = evaluate_records(paths, settings=settings, methods=methods, calibration=args.calibration,
                            models=models, exclude=None if trained_by is None else frozenset(trained_by),
                            workers=min(args.workers, os.cpu_count() or 1, len(paths)),
                            correct_camera_lag=args.camera_lag, correct_width_lag=args.width_lag)
    skipped = skipped_records(rows, trained_by=trained_by)
    scored = sorted({r["path"] for r in rows if "method" in r})
    if not scored:
        print_skipped(skipped, len(paths), file=sys.stderr)
        causes = Counter(skip_cause(r) for r in rows if "skipped" in r)
        said = {"trained on": f"of objects {', '.join(args.unseen_by or [])} trained on"}
        raise EstimatorError(f"{root}: no record scored, all {len(paths)} skipped ("
                             + ", ".join(f"{n} {said.get(cause, cause)}" for cause, n in causes.most_common())
                             + "; listed above)")
    display_range = display_range_pa(settings)
    summary = ablation_table(rows, methods=methods, models=models, display_range_pa=display_range)
    # Written beside their names and renamed in place at the end: an interrupt keeps the earlier ones.
    with contextlib.ExitStack() as outputs:
        if plot_path:
            plot(rows, list(summary), outputs.enter_context(staged(plot_path)), display_range_pa=display_range,
                 image_format=plot_path.suffix.lstrip("."))
        if rows_path:
            write_rows(rows, outputs.enter_context(staged(rows_path)), display_range_pa=display_range)
    kept = sorted({r["object"] for r in rows if "method" in r})
    result = {
        "command": shlex.join(getattr(args, "_command_line", None) or ["estimator", "evaluate", str(root)]),
        "dir": str(root), "records": len(paths), "labelled": len(scored),
        "skipped": dict(Counter(skip_cause(r) for r in rows if "skipped" in r)), "skipped_records": skipped,
        "seconds": time.perf_counter() - started, "display_range_pa": list(display_range), "methods": summary,
        "models": sorted({e.model_dir for e in models}),
        "unseen_by": None if trained_by is None else {"models": args.unseen_by, "trained_on": sorted(trained_by),
                                                     "objects": kept},
        "plot": args.plot, "rows": args.rows,
    }
    if args.json:
        print(json.dumps(result, allow_nan=False))
        return 0
    _print_table(result, root)
    return 0


def _print_table(result: Mapping[str, Any], root: Path) -> None:
    unseen = result["unseen_by"]
    scope = "" if unseen is None else (f", {len(unseen['objects'])} objects {', '.join(unseen['models'])} "
                                       "did not train on")
    print(f"scored {result['labelled']} records of {result['records']} under {root}{scope} "
          f"({result['seconds']:.1f} s)")
    print_skipped(result["skipped_records"], result["records"])
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
        print(f"{method:<{width}} {m['inputs'] or '-':<{wide}} {m['n']:>4} {fmt_value(m['log10_error'], '9.2f')} "
              f"{fmt_value(m['within_10x'], '9.1%')} {fmt_value(m['point_log10_error'], '9.2f')} "
              f"{fmt_value(m['point_within_10x'], '8.1%')} {ok['n']:>4} {fmt_value(ok['log10_error'], '6.2f')} "
              f"{fmt_value(m['interval_coverage'], '8.1%')}  {paper_text:<9} {states}")
    soft, rigid = result["display_range_pa"]
    print()
    print(f"on the display (range {soft:.3g} to {rigid:.3g} Pa, labels clipped to it): n = estimates counted "
          "(refusals left out of every figure here); felt err = mean |log10 felt - log10 label|; felt2x = "
          "share felt within 2x; danger = rigid (>= 100 MPa) felt below the lower of 1 MPa and the rigid "
          "end, or soft (<= 1 MPa) felt at or above the lower of 10 MPa and the rigid end; unknown = "
          "estimates whose interval spans the whole range, shown as unknown: felt err, felt2x and danger are "
          "over the placed estimates (n minus unknown), the rest over all n; rigid = share of rigid "
          "objects' grasps rendered rigid (unknown counts as not rigid); level = interval coverage the "
          "method states, coverage = share of intervals holding the label; width = median interval width "
          "in decades as shown (unknown at the whole range); soft: the same over labels at or below 3 MPa, "
          "the objects the display scales: soft n counted, refused = soft grasps refused, left out")
    print(f"{'method':<{width}} {'n':>4} {'felt err':>8} {'felt2x':>7} {'danger':>6} {'unknown':>7} {'rigid':>6} {'level':>6} "
          f"{'coverage':>8} {'width':>6} | {'soft n':>6} {'refused':>7} {'felt err':>8} {'felt2x':>7} {'coverage':>8} {'width':>6}")
    for method, m in result["methods"].items():
        danger = "-" if m["dangerous_misses"] is None else str(m["dangerous_misses"])
        print(f"{method:<{width}} {m['n']:>4} {fmt_value(m['felt_log10_error'], '8.2f')} "
              f"{fmt_value(m['felt_within_2x'], '7.1%')} {danger:>6} {fmt_value(m['shown_unknown'], '7d')} "
              f"{fmt_value(m['rigid_shown_rigid'], '6.1%')} "
              f"{fmt_value(m['interval_level'], '6.0%')} "
              f"{fmt_value(m['interval_coverage'], '8.1%')} {fmt_value(m['interval_width_decades_median'], '6.2f')} | "
              f"{m['soft_n']:>6} {m['soft_refused']:>7} {fmt_value(m['soft_felt_log10_error'], '8.2f')} {fmt_value(m['soft_felt_within_2x'], '7.1%')} "
              f"{fmt_value(m['soft_interval_coverage'], '8.1%')} {fmt_value(m['soft_interval_width_decades_median'], '6.2f')}")
    for method, m in result["methods"].items():
        if "answered_by" in m:
            print(f"{method} answered by: " + ", ".join(f"{k} {v}" for k, v in sorted(m["answered_by"].items())))
    for model in sorted({m["model"] for m in result["methods"].values() if m.get("measurement_code_matches") is False}):
        print(f"note: {model} was trained on inputs measured by other code; its methods' figures are not its own")
