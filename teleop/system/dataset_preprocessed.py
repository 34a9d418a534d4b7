"""Import the published dataset's preprocessed layout: augmentation folders to training samples.

``<object>/grasp=<g>/augmentation=<k>/`` holds ``RGB.pkl`` (n x 250 x 350 x 3 float
difference images, BGR), ``depth.pkl`` (n x 250 x 350, mm), ``RGB_markers.pkl``,
``depth_markers.pkl``, ``forces.pkl`` (n,), ``widths.pkl`` (n,),
``elastic_estimate.pkl`` (E, Pa) and ``hertz_estimate.pkl`` (E*, Pa). Each becomes
one training sample ``<out>/<object>/grasp=<g>/augmentation=<k>.npz``
(:mod:`estimator.training.samples`), converted explicitly to float32 images and depth in
metres. A published estimate that is NaN, infinite or <= 0 (the published code had
no guards) is stored as "not available" and counted.

Every file is checked before conversion, and an error names the file, its dtype and
shape and what was expected: images and depth maps of the published 250 x 350 size
with values in a plausible range (so none overflows float32), forces >= 0 N (to
:data:`~teleop.system.dataset_files.FORCE_TOLERANCE_N`), widths within the gripper's
range, one of each per frame.
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
from teleop.settings import GripperSettings
from teleop.system.dataset_files import (
    array_from_pickle,
    check_forces,
    check_widths,
    find_layout_folders,
    layout_index,
    layout_member,
    load_pickled_array,
    safe_load_pickle,
)

__all__ = [
    "DEPTH_LIMIT_MM",
    "IMAGE_SIZE",
    "RGB_LIMIT",
    "find_preprocessed_samples",
    "import_preprocessed_sample",
]


# The published images and depth maps: the sensor's 250 x 350 (rows x cols) grid.
IMAGE_SIZE = (250, 350)
# Difference images are of 8-bit levels (within +-255); the bound leaves room for augmentation.
RGB_LIMIT = 1024.0
# Gel indentation: the gel is a few mm thick, so |depth| beyond 100 mm is not a depth in mm.
DEPTH_LIMIT_MM = 100.0


def find_preprocessed_samples(root: str | os.PathLike[str]) -> list[Path]:
    """The ``<object>/grasp=<g>/augmentation=<k>`` folders under ``root``, sorted."""
    return find_layout_folders(Path(root), "*/grasp=*/augmentation=*", "<object>/grasp=<g>/augmentation=<k>")


def _published_modulus(path: Path) -> float | None:
    """A published estimate (Pa) as a float, or None where it is NaN, infinite or <= 0."""
    value = array_from_pickle(safe_load_pickle(path), path)
    if value.size != 1 or value.dtype.kind not in "iuf":
        raise DatasetError(f"{path}: expected one number (Pa), got {value.dtype} shape {value.shape}")
    number = float(value.reshape(()))
    return number if np.isfinite(number) and number > 0 else None


def _float32(path: Path, value: np.ndarray, *, limit: float, unit: str, what: str, scale: float = 1.0) -> np.ndarray:
    """``value * scale`` as float32, refusing values beyond +-``limit`` first (no overflow in the cast)."""
    low, high = float(value.min()), float(value.max())
    if max(-low, high) > limit:
        raise DatasetError(
            f"{path}: expected {what} within +-{limit:g}{unit}, got {value.dtype} {value.shape} "
            f"with values from {low:.4g} to {high:.4g}"
        )
    return (value * scale).astype(np.float32)


def import_preprocessed_sample(
    sample_dir: str | os.PathLike[str], *, labels: Mapping[str, ObjectSpec] | None = None,
    max_width_m: float | None = None,
) -> TrainingSample:
    """One preprocessed-layout folder as a :class:`~estimator.training.samples.TrainingSample`.

    Images are converted to float32 and depth from mm to m (float32); forces and widths
    to float64. A published estimate that is NaN, infinite or <= 0 becomes None.

    Parameters
    ----------
    sample_dir : path
        ``<object>/grasp=<g>/augmentation=<k>``.
    labels : mapping of object name to ObjectSpec, optional
        Ground truth; objects not in it are unlabelled.
    max_width_m : float, optional
        The gripper's widest opening, m (default: the default settings' ``gripper.max_width_m``);
        widths beyond it (plus :data:`~teleop.system.dataset_files.WIDTH_SLACK_M`) are refused.

    Raises
    ------
    DatasetError
        A file is missing, unsafe or damaged, of the wrong dtype or shape, or holds values
        out of range (see the module docstring); the message names the file.
    SampleError
        The arrays do not form a valid sample.
    """
    sample_dir = Path(sample_dir)
    augmentation = layout_index(sample_dir, "augmentation")
    grasp = layout_index(sample_dir.parent, "grasp")
    name = sample_dir.parent.parent.name
    if max_width_m is None:
        max_width_m = GripperSettings().max_width_m
    size = f"the published {IMAGE_SIZE[0]}x{IMAGE_SIZE[1]} size"

    def array(member: str, shape: tuple[int | None, ...], what: str) -> tuple[Path, np.ndarray]:
        path = layout_member(sample_dir, member)
        return path, load_pickled_array(path, shape=shape, what=what)

    rgb_path, rgb = array("RGB.pkl", (None, *IMAGE_SIZE, 3), f"BGR difference images of {size}")
    n = rgb.shape[0]
    per_frame = "one per frame of RGB.pkl"
    depth_path, depth = array("depth.pkl", (n, *IMAGE_SIZE), f"depth maps in mm of {size}, {per_frame}")
    rgb_m_path, rgb_markers = array("RGB_markers.pkl", (n, *IMAGE_SIZE, 3), f"marker images of {size}, {per_frame}")
    depth_m_path, depth_markers = array("depth_markers.pkl", (n, *IMAGE_SIZE),
                                        f"marker depth maps in mm of {size}, {per_frame}")
    force_path, force = array("forces.pkl", (n,), f"forces in N, {per_frame}")
    width_path, width = array("widths.pkl", (n,), f"gripper widths in m, {per_frame}")
    check_forces(force_path, force)
    check_widths(width_path, width, max_width_m)

    spec = (labels or {}).get(name)
    try:
        return TrainingSample(
            object_name=name,
            grasp=grasp,
            augmentation=augmentation,
            rgb_diff=_float32(rgb_path, rgb, limit=RGB_LIMIT, unit="", what="8-bit difference levels"),
            depth_m=_float32(depth_path, depth, limit=DEPTH_LIMIT_MM, unit=" mm", what="depths", scale=1e-3),
            rgb_diff_markers=_float32(rgb_m_path, rgb_markers, limit=RGB_LIMIT, unit="",
                                      what="8-bit difference levels"),
            depth_markers_m=_float32(depth_m_path, depth_markers, limit=DEPTH_LIMIT_MM, unit=" mm", what="depths",
                                     scale=1e-3),
            force_n=force.astype(np.float64),
            width_m=width.astype(np.float64),
            elastic_estimate_pa=_published_modulus(layout_member(sample_dir, "elastic_estimate.pkl")),
            hertz_estar_pa=_published_modulus(layout_member(sample_dir, "hertz_estimate.pkl")),
            label_modulus_pa=spec.modulus_pa if spec else None,
            material=spec.material if spec else "",
            shape=spec.shape if spec else "",
        )
    except SampleError as exc:
        raise SampleError(f"{sample_dir}: {exc}") from None
