"""Labelled grasp records to training samples, split by object.

Every record is measured with the live estimator's own code
(:func:`~estimator.learned.sampling.sample_grasp`: segmentation, warp, depth,
contact features and the analytical fits of :mod:`estimator.measure`), from
its frames, forces, widths and timestamps only; simulator internals are never
read. Each grasp gives up to ``shifts`` sample sets: set ``k`` starts the
equidistant sampling of the loading phase ``k`` frames after contact (set 0 is
exactly what the live estimator samples). Images and depth are stored as the
model reads them: the gel patch ``window_m`` (default the pad of the settings'
estimator sensor) centred on each record's pad, area-averaged to ``size_px``
(:mod:`estimator.learned.inputs`, "Input window"), so training reads small files,
the network's input needs no further resizing, and records of sensors with other
pads and pitches show contacts at their physical size.

Split
-----
Objects, never grasps, are split: :func:`split_objects` assigns each object to
train, val or test, deterministically from ``seed`` and stratified by
material, and every sample is written under its object's split::

    OUT/dataset.json                 manifest (settings, counts, skipped records)
    OUT/split.json                   {"seed", "fractions", "train": [objects], "val": [...], "test": [...]}
    OUT/<split>/<object>/<object>_g<i>_a<k>.npz  (i: the object's i-th record, in path order)

so no grasp or augmentation of a val or test object can reach training.
"""

from __future__ import annotations

import json
import math
import re
import time
import zlib
from collections import Counter, defaultdict
from collections.abc import Mapping, Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, replace
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from estimator.errors import EstimatorError, SampleError
from estimator.learned.inputs import MEASUREMENT_VERSION, RIG_QUANTITIES
from estimator.learned.sampling import sample_grasp
from estimator.samples import TrainingSample, save_sample
from estimator.settings import estimator_settings
from teleop.errors import RecordError
from teleop.record import read_record
from teleop.settings import Settings

__all__ = [
    "DATASET_FORMAT",
    "SPLITS",
    "DatasetOptions",
    "build_dataset",
    "load_manifest",
    "load_split",
    "split_objects",
]

DATASET_FORMAT = "compliance-teleop.dataset"
SPLITS = ("train", "val", "test")
DEFAULT_FRACTIONS = (0.7, 0.15, 0.15)


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


def load_split(path: str | Path) -> dict[str, list[str]]:
    """Read a split file; raises SampleError when it is malformed or names an object twice."""
    path = Path(path)
    try:
        data = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise SampleError(f"{path}: not a readable split file ({exc})") from exc
    if not isinstance(data, dict) or not all(isinstance(data.get(s), list) for s in SPLITS):
        raise SampleError(f"{path}: expected lists of object names under {', '.join(SPLITS)}")
    names = [n for s in SPLITS for n in data[s]]
    if len(set(names)) != len(names):
        twice = sorted(n for n, c in Counter(names).items() if c > 1)
        raise SampleError(f"{path}: objects in more than one split: {twice[:5]}")
    return {s: list(data[s]) for s in SPLITS}


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


def _safe_name(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9._-]+", "_", name)


def _record_samples(job: tuple[Path, int, str], *, settings: Settings, options: DatasetOptions,
                    out: Path) -> dict[str, Any]:
    """Write the sample sets of one record (runs in a worker); returns what happened."""
    path, grasp, split = job
    try:
        record = read_record(path)
    except RecordError as exc:
        return {"path": str(path), "skipped": f"unreadable: {exc}"}
    label = record.label
    if label is None or label.modulus_pa is None:
        return {"path": str(path), "skipped": "unlabelled"}
    written, reasons = [], {}
    smoothings = set()
    for shift in range(options.shifts):
        sampled = sample_grasp(
            record, settings=settings, calibration=options.calibration, n_frames=options.n_frames,
            size_px=options.size_px, shift=shift, rgb=True, markers=options.markers,
            marker_calibration=options.marker_calibration, window_m=options.window_m,
        )
        if not sampled:
            reasons[shift] = sampled.reason
            continue
        if sampled.measurements is not None and sampled.measurements.calibration_smoothing_px is not None:
            smoothings.add(sampled.measurements.calibration_smoothing_px)
        sample = TrainingSample(
            object_name=label.object_name, grasp=grasp, augmentation=shift, rgb_diff=sampled.rgb_diff,
            depth_m=sampled.depth_m, force_n=sampled.force_n, width_m=sampled.width_m,
            rgb_diff_markers=sampled.rgb_diff_markers, depth_markers_m=sampled.depth_markers_m,
            label_modulus_pa=label.modulus_pa, material=label.material, shape=label.shape,
            estimates=sampled.estimates, **{name: getattr(sampled, name) for name in RIG_QUANTITIES},
        )
        # Named by the object's grasp index, not the record's name: records of one object from
        # several runs (rigs, sensors) may share a file name in different folders.
        object_dir = _safe_name(label.object_name)
        dest = out / split / object_dir / f"{object_dir}_g{grasp:04d}_a{shift}.npz"
        dest.parent.mkdir(parents=True, exist_ok=True)
        written.append(str(save_sample(sample, dest)))
    row: dict[str, Any] = {"path": str(path), "object": label.object_name, "split": split,
                           "samples": written, "notes": reasons, "calibration_smoothing_px": sorted(smoothings)}
    if not written:
        row["skipped"] = reasons[0]
    return row


def _labels(paths: Sequence[Path]) -> dict[Path, tuple[str, str]]:
    """Object name and material of every labelled record (headers only)."""
    labels = {}
    for path in paths:
        try:
            label = read_record(path).label
        except RecordError:
            continue
        if label is not None and label.modulus_pa is not None:
            labels[path] = (label.object_name, label.material or "")
    return labels


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
    """Write the samples of ``records`` under ``out`` with the split and manifest; return the summary.

    Raises
    ------
    EstimatorError
        No labelled record, or ``out`` already holds a dataset.
    """
    out = Path(out)
    if (out / "dataset.json").exists():
        raise EstimatorError(f"{out}: already holds a dataset (dataset.json); choose an empty --out")
    started = time.perf_counter()
    labels = _labels(records)
    if not labels:
        raise EstimatorError("no labelled .grasp record among the records given")
    split = split_objects(dict(labels.values()), seed=seed, fractions=fractions)
    split_of = {name: s for s, names in split.items() for name in names}
    grasp_index: dict[str, int] = Counter()
    jobs = []
    for path in sorted(labels):
        name = labels[path][0]
        jobs.append((path, grasp_index[name], split_of[name]))
        grasp_index[name] += 1
    if options.window_m is None:
        options = replace(options, window_m=settings.sensor(settings.sensing.finger).pad_size_m)
    out.mkdir(parents=True, exist_ok=True)
    work = partial(_record_samples, settings=settings, options=options, out=out)
    bar = partial(tqdm, total=len(jobs), desc="build-dataset", unit="grasp", disable=not progress)
    if workers <= 1:
        rows = [work(job) for job in bar(jobs)]
    else:
        with ProcessPoolExecutor(max_workers=workers) as pool:
            rows = list(bar(pool.map(work, jobs, chunksize=max(1, len(jobs) // (8 * workers)))))
    skipped = [{"path": r["path"], "reason": r["skipped"]} for r in rows if "skipped" in r]
    skipped += [{"path": str(p), "reason": "unreadable or unlabelled"} for p in records if p not in labels]
    counts = {s: sum(len(r.get("samples", ())) for r in rows if r.get("split") == s) for s in SPLITS}
    (out / "split.json").write_text(json.dumps(
        {"seed": seed, "fractions": list(fractions), "stratified_by": "material", **split}, indent=1))
    manifest = {
        "format": DATASET_FORMAT, "version": 1, "n_frames": options.n_frames, "shifts": options.shifts,
        "size_px": list(options.size_px), "window_m": list(options.window_m), "markers": options.markers, "finger": settings.sensing.finger,
        "depth_binning": estimator_settings(settings).depth_binning,
        "calibration": options.calibration, "marker_calibration": options.marker_calibration,
        "measurement_version": MEASUREMENT_VERSION,
        "calibration_smoothing_px": sorted({s for r in rows for s in r.get("calibration_smoothing_px", ())}),
        "records": len(records), "grasps_used": sum(1 for r in rows if r.get("samples")),
        "samples": counts, "objects": {s: len(v) for s, v in split.items()},
        "skipped": skipped, "skipped_reasons": dict(Counter(re.sub(r"-?\d[\d.e+-]*", "#", s["reason"]) for s in skipped)),
        "seconds": time.perf_counter() - started,
    }
    (out / "dataset.json").write_text(json.dumps(manifest, indent=1))
    return manifest
