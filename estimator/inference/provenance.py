"""What a model was trained on: the objects of its dataset's train, val and test parts.

A dataset built by ``estimator build-dataset`` (:mod:`estimator.training.dataset`) puts each object,
with all its grasps, in one part and names them in its ``split.json``::

    {"seed": ..., "fractions": [...], "train": [objects], "val": [...], "test": [...]}

which :func:`load_split` reads. A model's ``metadata.json`` ``data.objects`` lists the same names;
an older model's names only ``data.dir``, the dataset whose ``split.json`` does; a fine-tuned
model's ``fine_tuning.objects`` adds those it was fine-tuned on. :func:`trained_objects` and
:func:`held_out_objects` read them.

Here, below training and evaluation, because both ask: evaluation which records a model never saw
(``estimator evaluate --unseen-by``, ``estimator compare``), training which objects a fine-tune's
check leaves out and which parts it rehearses. Torch-free; the live service never loads it.
"""

from __future__ import annotations

import json
from collections import Counter
from pathlib import Path
from typing import Any

from estimator.errors import ModelError, SampleError

__all__ = ["SPLITS", "held_out_objects", "load_split", "trained_objects"]

#: The parts of a dataset, in order.
SPLITS = ("train", "val", "test")
REPO_DIR = Path(__file__).resolve().parents[2]


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


def _model_metadata(model_dir: str | Path) -> tuple[Path, dict[str, Any]]:
    """The path and ``data`` section of a model's ``metadata.json``."""
    # Here, not at the top: reading a dataset's split loads no onnxruntime.
    from estimator.inference.infer import read_metadata

    meta_path, data = read_metadata(model_dir)
    info = data.get("data") if isinstance(data, dict) else None
    if not isinstance(info, dict):
        raise ModelError(f"{meta_path}: no data section, so the objects it trained on are unknown")
    return meta_path, data


def _split_of_dataset(meta_path: Path, info: dict[str, Any], missing: str) -> dict[str, list[str]]:
    """The split of the dataset a model was trained on (``data.dir``; a relative directory is looked up
    under the working directory, then the repository)."""
    dataset = Path(str(info.get("dir") or ""))
    candidates = [dataset] if dataset.is_absolute() else [Path.cwd() / dataset, REPO_DIR / dataset]
    split_path = next((d / "split.json" for d in candidates if info.get("dir") and (d / "split.json").is_file()),
                      None)
    if split_path is None:
        raise ModelError(f"{meta_path}: data.objects does not list the {missing} objects and its dataset's "
                         f"split ({info.get('dir') or 'no data.dir'}/split.json) is not found; rebuild that "
                         "dataset (same seed) to recover it")
    return load_split(split_path)


def held_out_objects(model_dir: str | Path) -> frozenset[str]:
    """Names of the objects in a model's test split: the published objects it never trained or stopped on.

    Read from ``metadata.json`` ``data.objects.test`` when it lists names, else from the
    ``split.json`` of the dataset the model was trained on (``data.dir``; a relative
    directory is looked up under the working directory, then the repository). Which records
    a model did not train on is :func:`trained_objects`' complement, not this.

    Raises
    ------
    ModelError
        The metadata is unreadable or neither source names the test objects.
    """
    meta_path, data = _model_metadata(model_dir)
    info = data["data"]
    objects = info.get("objects")
    listed = objects.get("test") if isinstance(objects, dict) else None
    if isinstance(listed, list):
        return frozenset(map(str, listed))
    return frozenset(_split_of_dataset(meta_path, info, "test")["test"])


def trained_objects(model_dir: str | Path) -> frozenset[str]:
    """Names of every object that shaped a model: what ``--unseen-by`` keeps out.

    A model is shaped by its train objects (the weights), its val objects (early stopping, the
    interval calibration, the ``auto`` policy; ``estimator recalibrate`` refits on them too) and
    the objects it was fine-tuned on (:func:`estimator.training.finetune.fine_tune` lists them among
    its train objects and in ``fine_tuning.objects``). Read from ``metadata.json``
    ``data.objects.train`` and ``.val`` when they list names, else from the ``split.json`` of the
    dataset the model was trained on (as :func:`held_out_objects`), plus ``fine_tuning.objects``.
    Any other object, whatever the records' source (the published table's test objects, a lab's
    session records under catalogue names), the model never trained on.

    Raises
    ------
    ModelError
        The directory or its metadata is unreadable, or neither source names the train and val
        objects.
    """
    meta_path, data = _model_metadata(model_dir)
    info = data["data"]
    objects = info.get("objects") if isinstance(info.get("objects"), dict) else {}
    listed = [objects.get(name) for name in ("train", "val")]
    if all(isinstance(names, list) for names in listed):
        names = {str(n) for part in listed for n in part}
    else:
        split = _split_of_dataset(meta_path, info, "train and val")
        names = {*split["train"], *split["val"], *(n for part in listed if isinstance(part, list) for n in part)}
    tuned = data.get("fine_tuning")
    if isinstance(tuned, dict) and isinstance(tuned.get("objects"), list):
        names |= {str(n) for n in tuned["objects"]}
    return frozenset(names)
