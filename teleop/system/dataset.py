"""Import the published dataset: raw grasps to grasp records, preprocessed grasps to training samples.

Layouts (see the product brief)
-------------------------------
raw
    ``<object>/grasp=<i>/`` folders, two MJPG videos and the forces and widths
    pickles each, become grasp records (:mod:`teleop.system.dataset_raw`).
preprocessed
    ``<object>/grasp=<g>/augmentation=<k>/`` folders of pickled images, depth,
    forces, widths and published estimates become training samples
    (:mod:`teleop.system.dataset_preprocessed`).

Labels come from an object table (``--objects``: the published CSV or a
project TOML catalogue) when the object is in it.

Pickles execute code on load, so every ``.pkl`` is read with
:func:`~teleop.system.dataset_files.safe_load_pickle`, which admits numpy arrays and
nothing else.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from tqdm import tqdm

from estimator.errors import SampleError
from estimator.training.samples import TrainingSample, save_sample
from teleop.catalogue import load_catalogue
from teleop.errors import DatasetError
from teleop.progress import progress_bar
from teleop.record import GraspRecord, write_record
from teleop.settings import default_settings_path, load_settings
from teleop.system.dataset_preprocessed import find_preprocessed_samples, import_preprocessed_sample
from teleop.system.dataset_raw import RAW_FPS, find_raw_grasps, import_raw_grasp, raw_sensors

MIN_FPS, MAX_FPS = 0.1, 10000.0  # a plausible camera frame rate, Hz

__all__ = [
    "LAYOUTS",
    "ImportSummary",
    "SkippedItem",
    "import_dataset",
]

LAYOUTS = ("raw", "preprocessed")


# --------------------------------------------------------------------------- the whole import


@dataclass(frozen=True)
class SkippedItem:
    """An input folder that was not imported, and why."""

    path: str
    reason: str


@dataclass
class ImportSummary:
    """What :func:`import_dataset` did."""

    layout: str
    source: str
    out: str
    imported: list[str] = field(default_factory=list)
    skipped: list[SkippedItem] = field(default_factory=list)
    labelled: int = 0
    unavailable_estimates: int = 0

    def to_json(self) -> dict[str, Any]:
        return {
            "layout": self.layout,
            "source": self.source,
            "out": self.out,
            "imported": len(self.imported),
            "skipped": len(self.skipped),
            "labelled": self.labelled,
            "unavailable_estimates": self.unavailable_estimates,
            "skipped_items": [{"path": s.path, "reason": s.reason} for s in self.skipped],
        }


def import_dataset(
    src: str | os.PathLike[str],
    *,
    layout: str,
    out: str | os.PathLike[str],
    objects: str | os.PathLike[str] | None = None,
    settings: str | os.PathLike[str] | None = None,
    fps: float = RAW_FPS,
    on_skip: Callable[[SkippedItem], None] | None = None,
    progress: bool = False,
    overwrite: bool = False,
) -> ImportSummary:
    """Import every grasp (raw) or sample (preprocessed) under ``src`` into ``out``.

    A folder whose files are missing, unreadable, unsafe, inconsistent or physically
    impossible (bool or negative forces, widths outside the gripper's range, images not
    of the published size) is skipped with its reason (reported through ``on_skip``)
    and the import carries on. Records or samples already in ``out`` under the names this
    import would write are refused before anything is read or written, unless ``overwrite``.

    Parameters
    ----------
    src : path
        Root of the published dataset in the chosen layout.
    layout : {"raw", "preprocessed"}
    out : path
        Output folder (created): ``<object>/grasp=<i>.grasp`` or
        ``<object>/grasp=<g>/augmentation=<k>.npz``.
    objects : path, optional
        Object table (.csv) or catalogue (.toml) giving labels.
    settings : path, optional
        Settings TOML whose sensors describe the raw videos and whose ``gripper.max_width_m``
        bounds the widths of both layouts (default: the shipped one).
    fps : float
        Frame rate of the raw videos, Hz.
    on_skip : callable, optional
        Called with each :class:`SkippedItem` as it happens.
    progress : bool
        Show a progress bar on stderr (:func:`teleop.progress.progress_bar`).
    overwrite : bool
        Replace the files in ``out`` this import writes again instead of refusing them.

    Raises
    ------
    DatasetError
        ``layout`` is unknown, ``src`` holds no folder of that layout, the settings lack the
        sensors the raw layout needs, ``out`` already holds some of the outputs and
        ``overwrite`` is False (nothing is written then), or an output cannot be written.
    """
    if layout not in LAYOUTS:
        raise DatasetError(f"layout {layout!r}: expected one of {', '.join(LAYOUTS)}")
    if not MIN_FPS <= fps <= MAX_FPS:
        raise DatasetError(f"fps = {fps}: expected a frame rate from {MIN_FPS:g} to {MAX_FPS:g} Hz")
    src, out = Path(src), Path(out)
    labels = {spec.name: spec for spec in load_catalogue(objects)} if objects is not None else {}
    summary = ImportSummary(layout=layout, source=str(src), out=str(out))
    loaded = load_settings(settings if settings is not None else default_settings_path())
    max_width_m = loaded.gripper.max_width_m  # bounds the imported widths, both layouts
    if layout == "raw":
        sensors = raw_sensors(loaded.sensors)
        folders = find_raw_grasps(src)
    else:
        folders = find_preprocessed_samples(src)
    _refuse_existing([_destination(out, folder.relative_to(src), layout) for folder in folders], out, overwrite)
    for folder in progress_bar(folders, desc=f"import {layout}", unit="grasp" if layout == "raw" else "sample",
                       enabled=progress):
        relative = folder.relative_to(src)
        try:
            if layout == "raw":
                item: GraspRecord | TrainingSample = import_raw_grasp(
                    folder, sensors=sensors, labels=labels, fps=fps, max_width_m=max_width_m)
            else:
                item = import_preprocessed_sample(folder, labels=labels, max_width_m=max_width_m)
        except (DatasetError, SampleError) as exc:
            skipped = SkippedItem(str(folder), str(exc))
            summary.skipped.append(skipped)
            if on_skip is not None:
                on_skip(skipped)
            continue
        try:
            if isinstance(item, GraspRecord):
                dest = _destination(out, relative, layout)
                dest.parent.mkdir(parents=True, exist_ok=True)
                write_record(item, dest)
                summary.labelled += int(item.label is not None and item.label.modulus_pa is not None)
            else:
                dest = _destination(out, relative, layout)
                dest.parent.mkdir(parents=True, exist_ok=True)
                save_sample(item, dest)
                summary.labelled += int(item.label_modulus_pa is not None)
                summary.unavailable_estimates += [item.elastic_estimate_pa, item.hertz_estar_pa].count(None)
        except OSError as exc:
            raise DatasetError(f"cannot write {dest}: {exc.strerror or exc}") from exc
        summary.imported.append(str(dest))
    return summary


def _destination(out: Path, relative: Path, layout: str) -> Path:
    """Where the grasp (raw) or sample (preprocessed) of the input folder ``relative`` is written."""
    return out / relative.parent / f"{relative.name}{'.grasp' if layout == 'raw' else '.npz'}"


def _refuse_existing(destinations: list[Path], out: Path, overwrite: bool) -> None:
    """Raise unless none of ``destinations`` exists or ``overwrite``: an earlier import's (labelled) outputs stay."""
    if overwrite:
        return
    taken = []
    for dest in destinations:
        try:
            if dest.exists():
                taken.append(dest.relative_to(out).as_posix())
        except OSError as exc:
            raise DatasetError(f"--out {out}: cannot use {dest} ({exc.strerror or exc})") from exc
    if taken:
        raise DatasetError(f"--out {out}: {len(taken)} of this import's {len(destinations)} outputs exist already "
                           f"({', '.join(taken[:3])}{', ...' if len(taken) > 3 else ''}): pass --overwrite to "
                           "replace them, or another --out; nothing was imported")


# --------------------------------------------------------------------------- command


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.description = (
        "Import the published dataset. raw: <object>/grasp=<i>/ folders (two MJPG videos, "
        "forces and widths pickles) become grasp records <out>/<object>/grasp=<i>.grasp keeping "
        "the videos' JPEG frames unchanged. preprocessed: <object>/grasp=<g>/augmentation=<k>/ "
        "folders become training samples <out>/<object>/grasp=<g>/augmentation=<k>.npz. Pickles "
        "are loaded admitting numpy arrays only. A bad folder is reported and skipped; the exit "
        "status is non-zero only when nothing was imported."
    )
    parser.add_argument("src", metavar="SRC", help="root folder of the published dataset")
    parser.add_argument("--layout", choices=LAYOUTS, required=True,
                        help="which layout SRC is in: raw grasps or preprocessed samples")
    parser.add_argument("--out", metavar="DIR", required=True, help="output folder (created if missing)")
    parser.add_argument("--objects", metavar="CSV", default=None,
                        help="object table (published .csv, or a .toml catalogue) giving each "
                             "object's label; without it nothing is labelled")
    parser.add_argument("--settings", metavar="TOML", default=str(default_settings_path()),
                        help="settings whose sensors (one without markers, one with) describe the raw "
                             "videos and whose gripper.max_width_m bounds the imported widths")
    parser.add_argument("--fps", type=float, default=RAW_FPS,
                        help=f"frame rate of the raw videos, Hz ({MIN_FPS:g} to {MAX_FPS:g}); frame k is at k / fps seconds")
    parser.add_argument("--overwrite", action="store_true",
                        help="replace the records or samples already in --out under the names this import "
                             "writes (without it the import refuses them and writes nothing); other files "
                             "in --out are kept")
    parser.add_argument("--json", action="store_true",
                        help="print the summary as one JSON object on the last stdout line")


def run(args: argparse.Namespace) -> int:
    def report(item: SkippedItem) -> None:
        tqdm.write(f"skipped {item.path}: {item.reason}", file=sys.stderr)  # above the bar

    summary = import_dataset(
        args.src, layout=args.layout, out=args.out, objects=args.objects, settings=args.settings,
        fps=args.fps, on_skip=report, progress=True, overwrite=args.overwrite,
    )
    what = "grasp records" if args.layout == "raw" else "training samples"
    if args.json:
        print(json.dumps(summary.to_json()))
    else:
        print(
            f"imported {len(summary.imported)} {what} into {summary.out} "
            f"({summary.labelled} labelled); skipped {len(summary.skipped)}"
        )
        if summary.unavailable_estimates:
            print(f"{summary.unavailable_estimates} published estimates were NaN, infinite or <= 0 "
                  "and are stored as not available")
    return 0 if summary.imported else 1
