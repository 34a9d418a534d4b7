"""Labelled grasp records to training samples, split by object.

Every record is measured with the live estimator's own code
(:func:`~estimator.inference.sampling.sample_grasp`: segmentation, warp, depth,
contact features and the analytical fits of :mod:`estimator.measurements`), from
its frames, forces, widths and timestamps only; simulator internals are never
read. Each grasp gives up to ``shifts`` sample sets: set ``k`` starts the
equidistant sampling of the loading phase ``k`` frames after contact (set 0 is
exactly what the live estimator samples). Images and depth are stored as the
model reads them: the gel patch ``window_m`` (default the pad of the settings'
estimator sensor) centred on each record's pad, area-averaged to ``size_px``
(:mod:`estimator.inference.inputs`, "Input window"), so training reads small files,
the network's input needs no further resizing, and records of sensors with other
pads and pitches show contacts at their physical size.

Split
-----
Objects, never grasps, are split: :func:`split_objects` assigns each object to
train, val or test, deterministically from ``seed`` and stratified by
material, and every sample is written under its object's split::

    OUT/dataset.json                 manifest (settings, counts, the records used and skipped)
    OUT/split.json                   {"seed", "fractions", "train": [objects], "val": [...], "test": [...]}
    OUT/<split>/<object>/<object>_g<i>_a<k>.npz  (i: the object's i-th record, in path order)

so no grasp or augmentation of a val or test object can reach training. The split file is
read with :func:`~estimator.inference.provenance.load_split` (evaluation reads it too).

Nothing half-written, nothing dropped silently
----------------------------------------------
The dataset is written into a hidden folder beside ``OUT`` and renamed to ``OUT`` at the end; an
error (or an interrupt) removes it, so ``OUT`` is either a whole dataset or absent. Every record
that gives no sample is in the manifest's ``skipped`` list with its path, a ``cause`` (one of
:data:`SKIP_CAUSES`) and a ``reason`` that says what to do about it: unreadable; unlabelled (no
label, or no modulus); no sensor on the settings' finger; a calibration it names that does not
exist; no usable loading phase (or too few loading frames); its measurement failed; a duplicate (a
byte-identical copy of a record met earlier in path order, e.g. one export copied into two folders:
the reason names the copy kept, so a grasp is never counted twice). A build that gives no sample at all
raises :class:`~estimator.errors.EstimatorError` listing them.

Object names become folder and file names (:func:`object_file_name`): a name of lower-case letters,
digits, ``.``, ``_`` and ``-`` only (most catalogue names) is used as it is; any other (``"vinyl eraser"``,
``"海绵"``, ``"café"``, ``".."``, ``"Ball"``) gets a readable form with a hash of the whole name after a
``+``, so every object has a folder of its own inside its split and no sample overwrites another's, on
file systems that ignore case too.

Warnings
--------
Each is logged and listed in the manifest's ``warnings``; none stops the build:

* an object labelled with moduli that differ by more than :data:`MODULUS_SPREAD` (e.g. one export that
  says 1 MPa and another 40 kPa), naming the object, its moduli and the records of each: the network
  is trained on every label as given, so relabel the wrong ones with `teleop label`;
* a val or test split left without samples (too few objects for ``fractions``).
"""

from __future__ import annotations

import hashlib
import json
import logging
import math
import os
import re
import secrets
import shutil
import time
import zlib
from collections import Counter, defaultdict
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np

from estimator.errors import EstimatorError, SampleError
from estimator.inference.inputs import MEASUREMENT_VERSION, RIG_QUANTITIES
from estimator.inference.provenance import SPLITS
from estimator.inference.sampling import sample_grasp
from estimator.measurements import calibration_problem
from estimator.settings import estimator_settings
from estimator.training.samples import TrainingSample, save_sample
from teleop.clikit import file_in_the_way
from teleop.errors import RecordError
from teleop.parallel import progress_map
from teleop.record import read_record
from teleop.settings import Settings

__all__ = [
    "DATASET_FORMAT",
    "SKIP_CAUSES",
    "DatasetOptions",
    "build_dataset",
    "load_manifest",
    "object_file_name",
    "split_objects",
]

DATASET_FORMAT = "compliance-teleop.dataset"
DEFAULT_FRACTIONS = (0.7, 0.15, 0.15)
#: Why a record gave no sample (the ``cause`` of each entry in the manifest's ``skipped``).
SKIP_CAUSES = ("unreadable", "unlabelled", "no sensor", "calibration missing", "no usable loading phase",
               "measurement failed", "duplicate")
#: Largest ratio between the moduli one object is labelled with before the build warns about it.
MODULUS_SPREAD = 2.0

log = logging.getLogger(__name__)


# --------------------------------------------------------------------------- split


def split_objects(
    materials: Mapping[str, str], *, seed: int, fractions: Sequence[float] = DEFAULT_FRACTIONS
) -> dict[str, list[str]]:
    """Assign every object to train, val or test, stratified by material.

    Objects are taken material by material (sorted), in a seeded random order
    within each material, and each goes to the split furthest below its target
    share so far, so every split gets its share of every material and the
    totals follow ``fractions``. The result depends only on the objects, their
    materials, ``seed`` and ``fractions``.

    Parameters
    ----------
    materials : mapping
        Object name -> material ("" when unknown).
    seed : int
    fractions : (train, val, test)
        Non-negative, summing to 1.

    Returns
    -------
    dict
        ``{"train": [...], "val": [...], "test": [...]}``, names sorted.
    """
    share = np.asarray(fractions, dtype=np.float64)
    if share.shape != (3,) or np.any(share < 0) or not math.isclose(share.sum(), 1.0, abs_tol=1e-9):
        raise EstimatorError(f"split fractions {list(fractions)}: expected three values >= 0 summing to 1")
    by_material: dict[str, list[str]] = defaultdict(list)
    for name, material in materials.items():
        by_material[material].append(name)
    counts = np.zeros(3)
    out: dict[str, list[str]] = {split: [] for split in SPLITS}
    for material in sorted(by_material):
        rng = np.random.default_rng([seed, zlib.crc32(material.encode())])
        for name in rng.permutation(sorted(by_material[material])):
            chosen = int(np.argmax(share * (counts.sum() + 1) - counts))
            counts[chosen] += 1
            out[SPLITS[chosen]].append(str(name))
    return {split: sorted(names) for split, names in out.items()}


def load_manifest(directory: str | Path) -> dict[str, Any]:
    """The ``dataset.json`` of a directory written by :func:`build_dataset`."""
    path = Path(directory) / "dataset.json"
    try:
        manifest = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise SampleError(f"{path}: not a readable dataset manifest ({exc}); run `estimator build-dataset`") from exc
    if not isinstance(manifest, dict) or manifest.get("format") != DATASET_FORMAT:
        raise SampleError(f"{path}: not a {DATASET_FORMAT} manifest")
    return manifest


# --------------------------------------------------------------------------- building


@dataclass(frozen=True)
class DatasetOptions:
    """How samples are made from records (recorded in the manifest)."""

    n_frames: int = 3
    shifts: int = 3
    size_px: tuple[int, int] = (64, 88)
    window_m: tuple[float, float] | None = None  # None: the pad of the settings' estimator sensor
    markers: bool = False
    calibration: str | None = None
    marker_calibration: str | None = None


def object_file_name(name: str) -> str:
    """The folder and file name of the samples of the object ``name``; distinct for distinct names.

    A name of lower-case letters, digits, ``.``, ``_`` and ``-`` only, and not made of dots alone, is
    used as it is. Any other name has every run of characters other than letters, digits, ``.``, ``_``
    and ``-`` replaced by ``_``, leading dots dropped (``"."`` and ``".."`` are not folders of their
    own; a leading dot would hide one) and ``+`` and 16 hex digits of the SHA-256 of its UTF-8 appended:
    ``"café"`` -> ``"caf_+…"``, ``"海绵"`` -> ``"_+…"``, ``"Ball"`` -> ``"Ball+…"``. No name of the first
    kind contains ``+`` or a capital, so the two kinds never meet, even where case is ignored ("Ball"
    and "ball"), and two names of the second kind meet only if their hashes do.
    """
    if re.fullmatch(r"[a-z0-9._-]+", name) and name.strip("."):
        return name
    readable = re.sub(r"[^A-Za-z0-9._-]+", "_", name).lstrip(".")
    return f"{readable}+{hashlib.sha256(name.encode()).hexdigest()[:16]}"


def _skip(path: Path, cause: str, reason: str) -> dict[str, Any]:
    return {"path": str(path), "cause": cause, "skipped": reason}


def _size(path: Path) -> int | None:
    """A record's size in bytes (None: unreadable, left to the record check to report)."""
    try:
        return path.stat().st_size
    except OSError:
        return None


def _content_hash(path: Path) -> str | None:
    """The SHA-256 of a record's bytes (None: unreadable, left to the record check to report)."""
    digest = hashlib.sha256()
    try:
        with path.open("rb") as f:
            for block in iter(partial(f.read, 1 << 20), b""):
                digest.update(block)
    except OSError:
        return None
    return digest.hexdigest()


def _check_record(path: Path, *, finger: str,
                  options: DatasetOptions) -> tuple[str, str, float] | dict[str, Any]:
    """(object, material, modulus) of a record samples can be made of, or why it cannot be used (a skipped row)."""
    try:
        record = read_record(path)
    except RecordError as exc:
        return _skip(path, "unreadable", f"unreadable: {exc}")
    label = record.label
    if label is None:
        return _skip(path, "unlabelled", "unlabelled: the record has no label (label its session's grasps with "
                                         "`teleop label LOG --csv FILE`, then export it again)")
    if label.modulus_pa is None:
        return _skip(path, "unlabelled", f"unlabelled: its object {label.object_name!r} has no modulus (give it "
                                         "one with `teleop label`, or export with a catalogue that has it)")
    fingers = [s.finger for s in record.sensors]
    if finger not in fingers:
        return _skip(path, "no sensor", f"no sensor on finger {finger!r} (the settings' sensing.finger); the "
                                        f"record has {', '.join(fingers)}: pass the --settings of its rig")
    problem = calibration_problem(record, finger, options.calibration, "--calibration", markers=options.markers,
                                  marker_override=options.marker_calibration, marker_option="--marker-calibration")
    if problem is not None:
        return _skip(path, "calibration missing", problem)
    return label.object_name, label.material or "", label.modulus_pa


def _record_samples(job: tuple[Path, int, str], *, settings: Settings, options: DatasetOptions,
                    out: Path) -> dict[str, Any]:
    """Write the sample sets of one record (runs in a worker); returns what happened."""
    path, grasp, split = job
    try:
        record = read_record(path)
    except RecordError as exc:
        return _skip(path, "unreadable", f"unreadable: {exc}")
    label = record.label
    written, reasons = [], {}
    smoothings = set()
    for shift in range(options.shifts):
        try:
            sampled = sample_grasp(
                record, settings=settings, calibration=options.calibration, n_frames=options.n_frames,
                size_px=options.size_px, shift=shift, rgb=True, markers=options.markers,
                marker_calibration=options.marker_calibration, window_m=options.window_m,
            )
            if sampled:  # a sample failing its checks (a NaN depth, say) fails this record, not the build
                sample = TrainingSample(
                    object_name=label.object_name, grasp=grasp, augmentation=shift, rgb_diff=sampled.rgb_diff,
                    depth_m=sampled.depth_m, force_n=sampled.force_n, width_m=sampled.width_m,
                    rgb_diff_markers=sampled.rgb_diff_markers, depth_markers_m=sampled.depth_markers_m,
                    label_modulus_pa=label.modulus_pa, material=label.material, shape=label.shape,
                    estimates=sampled.estimates, **{name: getattr(sampled, name) for name in RIG_QUANTITIES},
                )
        except (EstimatorError, RecordError) as exc:
            for relative in written:  # a skipped record leaves no sample for training to read
                (out / relative).unlink()
            return _skip(path, "measurement failed", f"measurement failed: {exc}")
        if not sampled:
            reasons[shift] = sampled.reason
            continue
        if sampled.measurements is not None and sampled.measurements.calibration_smoothing_px is not None:
            smoothings.add(sampled.measurements.calibration_smoothing_px)
        # Named by the object's grasp index, not the record's name: records of one object from
        # several runs (rigs, sensors) may share a file name in different folders.
        object_dir = object_file_name(label.object_name)
        relative = Path(split) / object_dir / f"{object_dir}_g{grasp:04d}_a{shift}.npz"
        (out / relative).parent.mkdir(parents=True, exist_ok=True)
        save_sample(sample, out / relative)
        written.append(relative.as_posix())
    row: dict[str, Any] = {"path": str(path), "object": label.object_name, "split": split,
                           "samples": written, "notes": reasons, "calibration_smoothing_px": sorted(smoothings)}
    if not written:
        row["cause"] = "no usable loading phase"
        row["skipped"] = f"no usable loading phase: {reasons[0]}"
    return row


def _modulus_warnings(labels: Mapping[Path, tuple[str, str, float]]) -> list[str]:
    """A warning per object whose labelled moduli differ by more than :data:`MODULUS_SPREAD`."""
    records: dict[str, dict[float, list[Path]]] = defaultdict(lambda: defaultdict(list))
    for path in sorted(labels):
        name, _, modulus = labels[path]
        records[name][modulus].append(path)
    warnings = []
    for name, by_modulus in sorted(records.items()):
        low, high = min(by_modulus), max(by_modulus)
        if high <= MODULUS_SPREAD * low:
            continue
        moduli = "; ".join(f"{modulus:g} Pa in {', '.join(map(str, paths))}"
                           for modulus, paths in sorted(by_modulus.items()))
        warnings.append(
            f"object {name!r} is labelled with moduli {high / low:.3g} times apart (more than "
            f"{MODULUS_SPREAD:g}x): {moduli}; all are trained on as given: if one object, relabel the wrong "
            "records (`teleop label`, then export again); if different objects, give them different names")
        log.warning("%s", warnings[-1])
    return warnings


def _nothing_made(skipped: list[dict[str, Any]], n_records: int) -> EstimatorError:
    lines = "\n".join(f"  {s['path']}: {s['reason']}" for s in skipped)
    return EstimatorError(f"no training sample made from the {n_records} records given; every one was "
                          f"skipped:\n{lines}")


def build_dataset(
    records: Sequence[Path],
    out: str | Path,
    *,
    settings: Settings,
    options: DatasetOptions,
    seed: int = 0,
    fractions: Sequence[float] = DEFAULT_FRACTIONS,
    workers: int = 1,
    progress: bool = True,
) -> dict[str, Any]:
    """Write the samples of ``records`` under ``out`` with the split and manifest; return the manifest.

    ``out`` appears whole or not at all (module notes). The manifest's ``skipped`` lists every
    record that gave no sample (``path``, ``cause``, ``reason``), ``used`` the others (``path``,
    ``object``, ``split``, ``samples``: paths relative to ``out``), ``warnings`` what was logged as
    a warning (module notes).

    Raises
    ------
    EstimatorError
        ``out`` already holds a dataset or other files, or no sample could be made (the message
        lists every record with the cause).
    """
    out = Path(out)
    if (out / "dataset.json").exists():
        raise EstimatorError(f"{out}: already holds a dataset (dataset.json); choose an empty --out")
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        raise EstimatorError(f"{out}: exists and is not an empty folder; choose a new or empty --out")
    for option, given in (("--calibration", options.calibration), ("--marker-calibration", options.marker_calibration)):
        if given is not None and not Path(given).is_file():
            raise EstimatorError(f"{option} {given}: no such calibration file")
    started = time.perf_counter()
    finger = settings.sensing.finger
    labels: dict[Path, tuple[str, str, float]] = {}
    skipped: list[dict[str, Any]] = []
    first_of: dict[str, Path] = {}
    paths = sorted(Path(p) for p in records)
    sizes = Counter(_size(path) for path in paths)
    for path in paths:
        # a copy has its original's size: only a record sharing its size with another is read twice
        digest = _content_hash(path) if sizes[_size(path)] > 1 else None
        if digest is not None and digest in first_of:
            skipped.append(_skip(path, "duplicate", f"duplicate of {first_of[digest]} (the same bytes; that "
                                                    "copy is used, this one is not counted again)"))
            continue
        if digest is not None:
            first_of[digest] = path
        checked = _check_record(path, finger=finger, options=options)
        if isinstance(checked, dict):
            skipped.append(checked)
        else:
            labels[path] = checked
    if not labels:
        raise _nothing_made([_skipped_entry(s) for s in skipped], len(records))
    warnings = _modulus_warnings(labels)
    split = split_objects({name: material for name, material, _ in labels.values()}, seed=seed,
                          fractions=fractions)
    split_of = {name: s for s, names in split.items() for name in names}
    grasp_index: dict[str, int] = Counter()
    jobs = []
    for path in sorted(labels):
        name = labels[path][0]
        jobs.append((path, grasp_index[name], split_of[name]))
        grasp_index[name] += 1
    if options.window_m is None:
        options = replace(options, window_m=settings.sensor(finger).pad_size_m)
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        tmp = out.parent / f".{out.name}.{os.getpid()}-{secrets.token_hex(4)}.partial"
        tmp.mkdir()
    except OSError as exc:
        blocking = file_in_the_way(out.parent)
        why = f"{blocking} is not a directory" if blocking is not None else exc.strerror or exc
        raise EstimatorError(f"cannot create a folder beside --out {out}: {why}") from exc
    try:
        manifest = _write(jobs, tmp, settings=settings, options=options, workers=workers, progress=progress,
                          skipped=skipped, split=split, seed=seed, fractions=fractions, n_records=len(records),
                          warnings=warnings, started=started)
        try:
            if out.exists():
                out.rmdir()  # empty (checked above): the dataset takes its place
            tmp.replace(out)
        except OSError as exc:
            raise EstimatorError(f"cannot move the dataset into --out {out}: {exc.strerror or exc}") from exc
    except OSError as exc:
        shutil.rmtree(tmp, ignore_errors=True)
        raise EstimatorError(f"cannot write the dataset beside --out {out} ({tmp.name}): {exc.strerror or exc}; "
                             "nothing was kept") from exc
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return manifest


def _skipped_entry(row: dict[str, Any]) -> dict[str, Any]:
    return {"path": row["path"], "cause": row["cause"], "reason": row["skipped"]}


def _write(jobs: list[tuple[Path, int, str]], out: Path, *, settings: Settings, options: DatasetOptions,
           workers: int, progress: bool, skipped: list[dict[str, Any]], split: dict[str, list[str]], seed: int,
           fractions: Sequence[float], n_records: int, warnings: list[str], started: float) -> dict[str, Any]:
    """Write the samples, split and manifest of ``jobs`` into ``out``; return the manifest (with
    ``warnings``, logged already, and those of the splits)."""
    work = partial(_record_samples, settings=settings, options=options, out=out)
    rows = progress_map(work, jobs, workers=workers, desc="build-dataset", progress=progress)
    skipped = [_skipped_entry(s) for s in skipped] + [_skipped_entry(r) for r in rows if "skipped" in r]
    skipped.sort(key=lambda s: s["path"])
    if not any(r.get("samples") for r in rows):
        raise _nothing_made(skipped, n_records)
    counts = {s: sum(len(r.get("samples", ())) for r in rows if r.get("split") == s) for s in SPLITS}
    warnings = list(warnings)
    for s in ("val", "test"):
        if not counts[s]:
            n_objects = len({r["object"] for r in rows if r.get("samples")})
            warnings.append(
                f"split {s!r} has no samples ({len(split[s])} of {n_objects} objects with samples, fractions "
                f"{list(fractions)}): "
                + ("`estimator train` refuses a dataset without val samples" if s == "val" else
                   "evaluation and calibration have no held-out test samples")
                + "; add records of more objects, or change --split TRAIN,VAL,TEST (`estimator fine-tune` "
                  "trains on every split: nothing to do for it)")
            log.warning("%s", warnings[-1])
    (out / "split.json").write_text(json.dumps(
        {"seed": seed, "fractions": list(fractions), "stratified_by": "material", **split}, indent=1))
    manifest = {
        "format": DATASET_FORMAT, "version": 1, "n_frames": options.n_frames, "shifts": options.shifts,
        "size_px": list(options.size_px), "window_m": list(options.window_m), "markers": options.markers,
        "finger": settings.sensing.finger,
        "depth_binning": estimator_settings(settings).depth_binning,
        "calibration": options.calibration, "marker_calibration": options.marker_calibration,
        "measurement_version": MEASUREMENT_VERSION,
        "calibration_smoothing_px": sorted({s for r in rows for s in r.get("calibration_smoothing_px", ())}),
        "records": n_records, "grasps_used": sum(1 for r in rows if r.get("samples")),
        # objects that gave samples: one whose every record was skipped is in split.json alone
        "samples": counts, "objects": {s: len({r["object"] for r in rows if r.get("split") == s and r.get("samples")})
                                       for s in SPLITS},
        "used": [{k: r[k] for k in ("path", "object", "split", "samples")} for r in rows if r.get("samples")],
        "skipped": skipped, "skipped_reasons": dict(Counter(s["cause"] for s in skipped)),
        "warnings": warnings,
        "seconds": time.perf_counter() - started,
    }
    (out / "dataset.json").write_text(json.dumps(manifest, indent=1))
    return manifest
