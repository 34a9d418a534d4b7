"""``estimator compare``: is a candidate model better than the base model, on objects neither trained on?

Before a new model (a fine-tuned one, say) is served, it should answer grasps of objects it never
saw better than the model it replaces. :func:`compare_models` scores both on the labelled records
whose object neither model trained on (:func:`~estimator.inference.provenance.trained_objects` of each: train,
val and fine-tuning objects; every other object counts, whatever the records' source) and says
which is better and by how much.

Scoring
    Each model answers every kept grasp as the service would: ``auto`` (the hybrid's per-grasp
    choice between the series-compliance fit and the network; :class:`~estimator.inference.hybrid.HybridEstimator`)
    by default, or with ``mode="model"`` the network alone. Per model the figures are those of
    ``estimator evaluate`` (:func:`~estimator.evaluation.metrics.summarise`: felt error, share within a
    factor 2, dangerous misses, rigid objects rendered rigid, interval level, coverage and width,
    soft objects' width, states, per material and shape), plus ``answered`` (the share of the
    grasps the display places: neither refused nor shown unknown), against the display range of
    the settings.

The verdict
    ``better`` is ``"candidate"``, ``"base"`` or ``"undecided"`` by the felt error (what the
    operator feels; :mod:`estimator.evaluation.metrics`). Grasps of one object are not independent (one
    label, one shape), so the uncertainty comes from the objects: a paired bootstrap over the
    objects (:data:`RESAMPLES` resamples with replacement, seeded by :data:`SEED`; each resample
    recomputes both models' felt errors over the grasps of the drawn objects, so the point value
    is the difference of the figures shown) gives the :data:`LEVEL` (90 %) percentile interval of
    candidate minus base. The candidate is better when that interval lies below 0, the base when
    it lies above 0, undecided when it contains 0, and undecided too with fewer than
    :data:`MIN_OBJECTS` objects (a bootstrap over one or two objects has almost no spread to show)
    or when a model answered none of the grasps. ``dangerous_misses_increase`` says whether the
    candidate misjudges more grasps badly than the base; the verdict sentence says so whatever
    ``better`` is.

The command line is :mod:`estimator.evaluation.compare_cli`; ``estimator fine-tune --compare RECORDS`` prints
the same verdict for the model it has just made.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from estimator.errors import EstimatorError
from estimator.evaluation.evaluate import (
    ModelMethod,
    _predictor,
    evaluate_records,
    skip_cause,
)
from estimator.evaluation.metrics import felt_log10_error, felt_pa, summarise
from estimator.inference.provenance import trained_objects
from haptics.settings import display_range_pa
from teleop.errors import RecordError
from teleop.record import find_records, read_record
from teleop.settings import Settings

__all__ = [
    "LEVEL",
    "MIN_OBJECTS",
    "MODES",
    "RESAMPLES",
    "SEED",
    "NothingToCompare",
    "compare_models",
    "felt_difference",
    "unseen_records",
    "verdict",
]

#: Bootstrap resamples of the objects.
RESAMPLES = 2000
#: Seed of the bootstrap.
SEED = 0
#: Level of the interval on the difference of felt errors.
LEVEL = 0.9
#: Fewer objects than this give ``undecided`` whatever the interval.
MIN_OBJECTS = 3
#: How the models answer: as the service does (``auto``) or the network alone (``model``).
MODES = ("auto", "model")
ROLES = ("base", "candidate")


class NothingToCompare(EstimatorError):
    """No record can be scored (none readable, labelled, with its calibration and of an object neither model
    trained on); ``skipped`` lists every record's cause."""

    def __init__(self, message: str, skipped: list[dict[str, str]]):
        super().__init__(message)
        self.skipped = skipped


def _felt_errors(rows: Sequence[Mapping[str, Any]], method: str, display_range_pa: tuple[float, float]
                 ) -> dict[str, list[float]]:
    """Object -> the felt errors (decades) of ``method``'s counted grasps (as :mod:`estimator.evaluation.metrics`)."""
    out: dict[str, list[float]] = {}
    for r in rows:
        if r.get("method") != method:
            continue
        out.setdefault(r["object"], [])
        felt = felt_pa(r, display_range_pa=display_range_pa)
        if felt is not None:
            out[r["object"]].append(felt_log10_error(felt, r["truth_pa"], display_range_pa=display_range_pa))
    return out


def felt_difference(rows: Sequence[Mapping[str, Any]], *, display_range_pa: tuple[float, float],
                    base: str = "base", candidate: str = "candidate", resamples: int = RESAMPLES,
                    level: float = LEVEL, seed: int = SEED) -> dict[str, Any]:
    """Candidate minus base felt error over the scored ``rows``, with its paired bootstrap interval over objects.

    Parameters
    ----------
    rows : sequence of mapping
        Scored rows (:func:`~estimator.evaluation.evaluate.result_row`) of both methods on the same grasps.
    display_range_pa : (float, float)
        The display's ``(e_soft_pa, e_rigid_pa)``.
    base, candidate : str
        The two methods' names in ``rows``.
    resamples : int
        Bootstrap resamples (>= 1).
    level : float
        Level of the percentile interval, in (0, 1).
    seed : int
        Seed of the resampling.

    Returns
    -------
    dict
        ``felt_log10_error`` (the difference, decades; None when a model answered no grasp),
        ``interval`` ([low, high] or None), ``level``, ``resamples``, ``seed`` and ``objects``
        (how many objects were resampled).
    """
    if resamples < 1 or not 0.0 < level < 1.0:
        raise EstimatorError(f"resamples {resamples}, level {level}: expected at least 1 resample and 0 < level < 1")
    errors = [_felt_errors(rows, name, display_range_pa) for name in (base, candidate)]
    objects = sorted(set(errors[0]) | set(errors[1]))
    out: dict[str, Any] = {"felt_log10_error": None, "interval": None, "level": level, "resamples": resamples,
                           "seed": seed, "objects": len(objects)}
    sums = np.array([[sum(e.get(o, [])) for o in objects] for e in errors])
    counts = np.array([[len(e.get(o, [])) for o in objects] for e in errors], dtype=float)
    if not objects or not counts.sum(axis=1).all():
        return out
    out["felt_log10_error"] = float(sums[1].sum() / counts[1].sum() - sums[0].sum() / counts[0].sum())
    rng = np.random.default_rng(seed)
    drawn = rng.integers(0, len(objects), size=(resamples, len(objects)))
    weights = np.zeros((resamples, len(objects)))
    np.add.at(weights, (np.repeat(np.arange(resamples), len(objects)), drawn.ravel()), 1.0)
    n = weights @ counts.T  # (resamples, 2): counted grasps per model
    keep = (n > 0).all(axis=1)
    if not keep.any():  # no resample drew a grasp each model answered (few resamples): no interval
        return out
    means = (weights @ sums.T)[keep] / n[keep]
    differences = means[:, 1] - means[:, 0]
    tail = (1.0 - level) / 2.0
    out["interval"] = [float(v) for v in np.quantile(differences, [tail, 1.0 - tail])]
    return out


def _better(difference: Mapping[str, Any]) -> str:
    interval = difference["interval"]
    if difference["objects"] < MIN_OBJECTS or interval is None:
        return "undecided"
    if interval[1] < 0.0:
        return "candidate"
    if interval[0] > 0.0:
        return "base"
    return "undecided"


def verdict(result: Mapping[str, Any]) -> str:
    """The comparison in one sentence with its numbers (``result``: :func:`compare_models`')."""
    base, candidate, diff = result["base"], result["candidate"], result["difference"]
    scope = f"{result['grasps']} grasps of {result['n_objects']} objects neither model trained on"
    if base["felt_log10_error"] is None or candidate["felt_log10_error"] is None:
        refusing = " and ".join(r for r in ROLES if result[r]["felt_log10_error"] is None)
        return f"undecided: {refusing} answered none of the {scope}"
    text = f"felt error {base['felt_log10_error']:.3f} -> {candidate['felt_log10_error']:.3f} decade (base -> candidate"
    if diff["interval"] is not None:
        low, high = diff["interval"]
        text += (f"; candidate - base {diff['felt_log10_error']:+.3f}, {diff['level'] * 100:g} % interval "
                 f"{low:+.3f} to {high:+.3f}")
    text += f") on {scope}"
    better = result["better"]
    if better == "undecided":
        why = (f"only {diff['objects']} objects, at least {MIN_OBJECTS} are needed to tell"
               if diff["objects"] < MIN_OBJECTS else "no interval: no resample held grasps both models answered"
               if diff["interval"] is None else "the interval contains 0")
        head = f"undecided ({why}): "
    else:
        head = f"{better} better: "
    misses = f"; dangerous misses {base['dangerous_misses']} -> {candidate['dangerous_misses']}"
    if result["dangerous_misses_increase"]:
        misses += " (more with the candidate)"
    return head + text + misses


def unseen_records(records: str | Path, exclude: frozenset[str]) -> tuple[list[Path], list[dict[str, str]]]:
    """The labelled records under the directory ``records`` whose object is not in ``exclude``, and the
    others (``{"path", "cause"}``); reads each record's label only to check, before anything is trained.

    Raises
    ------
    RecordError
        ``records`` is not a directory or holds no record.
    """
    kept, skipped = [], []
    for path in find_records(records):
        try:
            label = read_record(path).label
        except RecordError as exc:
            skipped.append({"path": str(path), "cause": f"unreadable: {exc}"})
            continue
        if label is None or label.modulus_pa is None:
            skipped.append({"path": str(path), "cause": "unlabelled"})
        elif label.object_name in exclude:
            skipped.append({"path": str(path), "cause": f"trained on: {label.object_name}"})
        else:
            kept.append(path)
    return kept, skipped


def _method(model_dir: str, name: str, mode: str) -> ModelMethod:
    predictor = _predictor(model_dir)
    method = "auto" if mode == "auto" else predictor.variant.method
    return ModelMethod(name, method, model_dir, predictor.variant, predictor.measurement_code_matches,
                       getattr(predictor, "interval_level", None))


def compare_models(
    base: str | Path,
    candidate: str | Path,
    records: str | Path | Sequence[Path],
    *,
    settings: Settings,
    calibration: str | None = None,
    mode: str = "auto",
    exclude: frozenset[str] = frozenset(),
    workers: int = 1,
    resamples: int = RESAMPLES,
    level: float = LEVEL,
    seed: int = SEED,
    progress: bool = True,
) -> dict[str, Any]:
    """Score ``base`` and ``candidate`` on the labelled records neither trained on and say which is better.

    Parameters
    ----------
    base, candidate : str or Path
        Model directories (``metadata.json`` and ``model.onnx``).
    records : str, Path or sequence of Path
        A directory searched recursively for ``.grasp`` records, or the records.
    settings : Settings
        Estimator settings and the display's range for the felt figures.
    calibration : str, optional
        Calibration (.npz) for every record; default: the file each record's sensor names.
    mode : {"auto", "model"}
        ``auto``: answer as the service does; ``model``: the network alone.
    exclude : frozenset of str
        Further objects to leave out (beside both models' training objects).
    workers : int
        Worker processes.
    resamples, level, seed
        Of the bootstrap (:func:`felt_difference`).
    progress : bool
        Show a progress bar on stderr.

    Returns
    -------
    dict
        ``base`` and ``candidate`` (each the figures of ``estimator evaluate`` with ``model``,
        ``method``, ``variant`` and ``answered``), ``difference`` (:func:`felt_difference`),
        ``better`` ("base", "candidate" or "undecided"), ``dangerous_misses_increase``,
        ``verdict`` (:func:`verdict`), ``records`` (found), ``scored``, ``grasps`` (= scored
        records), ``objects`` (their names), ``n_objects``, ``trained_on`` (per model, how many
        objects), ``skipped`` (``{"path", "cause"}`` per record left out), ``mode`` and
        ``display_range_pa``.

    Raises
    ------
    NothingToCompare
        No record can be scored: the message counts the causes, ``skipped`` names each record's.
    ModelError
        A model directory is missing or unreadable.
    EstimatorError
        ``mode`` is unknown.
    """
    if mode not in MODES:
        raise EstimatorError(f"mode {mode!r}: expected one of {', '.join(MODES)}")
    dirs = {"base": str(base), "candidate": str(candidate)}
    trained = {role: trained_objects(d) for role, d in dirs.items()}
    methods = [_method(d, role, mode) for role, d in dirs.items()]
    paths = find_records(records) if isinstance(records, str | Path) else list(records)
    left_out = trained["base"] | trained["candidate"] | exclude
    rows = evaluate_records(paths, settings=settings, methods=(), calibration=calibration, models=methods,
                            exclude=frozenset(left_out), workers=max(1, min(workers, len(paths))),
                            progress=progress)
    skipped = []
    for r in rows:
        if "skipped" not in r:
            continue
        cause = r["skipped"]
        if skip_cause(r) == "trained on":
            which = [role for role in ROLES if r["object"] in trained[role]] or ["given as excluded"]
            cause = f"{' and '.join(which)} trained on {r['object']}"
        skipped.append({"path": r["path"], "cause": cause})
    scored = sorted({r["path"] for r in rows if "method" in r})
    if not scored:
        where = records if isinstance(records, str | Path) else f"{len(paths)} records"
        causes = Counter(skip_cause(r) for r in rows if "skipped" in r)
        said = {"trained on": "of objects they trained on"}
        raise NothingToCompare(
            f"{where}: no labelled record of an object neither model trained on ({len(paths)} records: "
            + ", ".join(f"{n} {said.get(cause, cause)}" for cause, n in causes.most_common())
            + ("; compare on grasps of other objects" if "trained on" in causes else "") + ")", skipped)
    display_range = display_range_pa(settings)
    summary = summarise(rows, list(ROLES), display_range_pa=display_range,
                        interval_levels={m.name: m.interval_level for m in methods})
    result: dict[str, Any] = {
        "records": len(paths), "scored": len(scored), "grasps": len(scored),
        "objects": sorted({r["object"] for r in rows if "method" in r}),
        "trained_on": {role: len(names) for role, names in trained.items()},
        "skipped": skipped, "mode": mode, "display_range_pa": list(display_range),
    }
    result["n_objects"] = len(result["objects"])
    for m in methods:
        figures = {k: v for k, v in summary[m.name].items() if k != "paper"}
        total = sum(figures["states"].values())
        result[m.name] = {"model": m.model_dir, "method": m.method, "variant": m.variant.name,
                          "measurement_code_matches": m.measurement_code_matches,
                          "answered": (figures["n"] - figures["shown_unknown"]) / total if total else None,
                          **figures}
    result["difference"] = felt_difference(rows, display_range_pa=display_range, resamples=resamples,
                                           level=level, seed=seed)
    result["better"] = _better(result["difference"])
    result["dangerous_misses_increase"] = result["candidate"]["dangerous_misses"] > result["base"]["dangerous_misses"]
    result["verdict"] = verdict(result)
    return result
