"""Import the published dataset's preprocessed layout: augmentation folders to training samples.

``<object>/grasp=<g>/augmentation=<k>/`` holds ``RGB.pkl`` (n x 250 x 350 x 3 float
difference images, BGR), ``depth.pkl`` (n x 250 x 350, mm), ``RGB_markers.pkl``,
``depth_markers.pkl``, ``forces.pkl`` (n,), ``widths.pkl`` (n,),
``elastic_estimate.pkl`` (E, Pa) and ``hertz_estimate.pkl`` (E*, Pa). Each becomes
one training sample ``<out>/<object>/grasp=<g>/augmentation=<k>.npz``
(:mod:`estimator.training.samples`), converted explicitly to float32 images and depth in
metres. A published estimate that is NaN, infinite or <= 0 (the published code had
no guards) is stored as "not available" and counted.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from estimator.errors import SampleError
from estimator.training.samples import TrainingSample
from teleop.catalogue import ObjectSpec
from teleop.errors import DatasetError
from teleop.system.dataset_files import (
    find_layout_folders,
    layout_index,
    layout_member,
    load_pickled_array,
    safe_load_pickle,
)

__all__ = [
    "find_preprocessed_samples",
    "import_preprocessed_sample",
]


def find_preprocessed_samples(root: str | os.PathLike[str]) -> list[Path]:
    """The ``<object>/grasp=<g>/augmentation=<k>`` folders under ``root``, sorted."""
    return find_layout_folders(Path(root), "*/grasp=*/augmentation=*", "<object>/grasp=<g>/augmentation=<k>")


def _published_modulus(path: Path) -> float | None:
    """A published estimate (Pa) as a float, or None where it is NaN, infinite or <= 0."""
    value = np.asarray(safe_load_pickle(path))
    if value.size != 1 or value.dtype.kind not in "biuf":
        raise DatasetError(f"{path}: expected one number (Pa), got {value.dtype} shape {value.shape}")
    number = float(value.reshape(()))
    return number if np.isfinite(number) and number > 0 else None


def import_preprocessed_sample(
    sample_dir: str | os.PathLike[str], *, labels: Mapping[str, ObjectSpec] | None = None
) -> TrainingSample:
    """One preprocessed-layout folder as a :class:`~estimator.training.samples.TrainingSample`.

    Images are converted to float32 and depth from mm to m (float32); forces and widths
    to float64. A published estimate that is NaN, infinite or <= 0 becomes None.

    Raises
    ------
    DatasetError
        A file is missing, unsafe, damaged or of the wrong shape; the message names the file.
    SampleError
        The arrays do not form a valid sample (mismatched frame counts or image sizes).
    """
    sample_dir = Path(sample_dir)
    augmentation = layout_index(sample_dir, "augmentation")
    grasp = layout_index(sample_dir.parent, "grasp")
    name = sample_dir.parent.parent.name

    def array(member: str, ndim: int) -> np.ndarray:
        return load_pickled_array(layout_member(sample_dir, member), ndim=ndim)

    spec = (labels or {}).get(name)
    try:
        return TrainingSample(
            object_name=name,
            grasp=grasp,
            augmentation=augmentation,
            rgb_diff=array("RGB.pkl", 4).astype(np.float32),
            depth_m=(array("depth.pkl", 3) * 1e-3).astype(np.float32),
            rgb_diff_markers=array("RGB_markers.pkl", 4).astype(np.float32),
            depth_markers_m=(array("depth_markers.pkl", 3) * 1e-3).astype(np.float32),
            force_n=array("forces.pkl", 1).astype(np.float64),
            width_m=array("widths.pkl", 1).astype(np.float64),
            elastic_estimate_pa=_published_modulus(layout_member(sample_dir, "elastic_estimate.pkl")),
            hertz_estar_pa=_published_modulus(layout_member(sample_dir, "hertz_estimate.pkl")),
            label_modulus_pa=spec.modulus_pa if spec else None,
            material=spec.material if spec else "",
            shape=spec.shape if spec else "",
        )
    except SampleError as exc:
        raise SampleError(f"{sample_dir}: {exc}") from None
