"""Training samples: the learned model's input for one grasp, with its label.

A :class:`TrainingSample` holds ``n`` tactile frames sampled across the loading
phase of one grasp (3 in the published dataset) as difference images and depth
maps, the force and gripper width at each of those frames, the analytical
estimates computed from them and the object's label.

File format (version 1)
-----------------------
One ``.npz`` archive per sample, written uncompressed with :func:`numpy.savez` (noisy
float images barely compress, and training reads them often) and read with
``allow_pickle=False``, holding these members:

``format`` (str ``"compliance-teleop.sample"``), ``version`` (int)
``object_name`` (str), ``grasp`` (int), ``augmentation`` (int), ``material`` (str), ``shape`` (str)
``rgb_diff``
    float32 (n, H, W, 3): frame minus the no-contact frame, BGR, 8-bit levels.
``depth_m``
    float32 (n, H, W): gel indentation, metres.
``force_n``, ``width_m``
    float64 (n,): normal force (N) and gripper width (m) at each frame.
``rgb_diff_markers``, ``depth_markers_m`` (optional, together)
    The same from the marker finger.
``elastic_estimate_pa``, ``hertz_estar_pa``, ``label_modulus_pa``, ``gel_modulus_pa`` (optional float64 scalars)
    Simple-elasticity estimate of E, Hertz estimate of the composite modulus E*, the
    true E, and the Young's modulus of the gel that measured the grasp (its sensor's
    settings), all Pa. A missing member means "not available"; a present one is finite and > 0.
``gel_thickness_m``, ``finger_stiffness_n_per_m`` (optional float64 scalars)
    The measuring rig's gel thickness (m) and finger stiffness (N/m), as its settings say;
    missing or finite and > 0 as the moduli.
    (The published dataset's two estimates; samples built from grasp records carry
    ``estimate_*`` instead.)
``estimate_method``, ``estimate_state``, ``estimate_reason`` (optional, together, str (m,))
``estimate_pa`` (optional, with them, float64 (m, 3))
    The analytical :class:`~estimator.estimate.Estimate` of each method over the sample's
    frames: method name, state, reason, and ``(e_pa, low_pa, high_pa)`` with NaN where
    the estimate has None (an open interval side, or a refusal). These NaNs are the
    file's encoding of None; in memory the estimates are checked ``Estimate`` objects.
    A sample written before the series fit's rename names it ``split``: it is read as ``series``.

Images and depth maps may have any size H x W: the published dataset's are the
sensor's 250 x 350 grid, ``estimator build-dataset`` stores them reduced (its
``--size``).
"""

from __future__ import annotations

import dataclasses
import os
import zipfile
import zlib
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from estimator.errors import FitError, SampleError
from estimator.estimate import Estimate
from teleop.scene import current_method

__all__ = [
    "SAMPLE_FORMAT",
    "SAMPLE_VERSION",
    "TrainingSample",
    "iter_samples",
    "load_sample",
    "sample_paths",
    "save_sample",
]

SAMPLE_FORMAT = "compliance-teleop.sample"
SAMPLE_VERSION = 1

_ARRAYS = ("rgb_diff", "depth_m", "force_n", "width_m")
_MARKER_ARRAYS = ("rgb_diff_markers", "depth_markers_m")
# Optional positive scalars: moduli (Pa) and the measuring rig's gel thickness (m) and finger stiffness (N/m).
_POSITIVE = ("elastic_estimate_pa", "hertz_estar_pa", "label_modulus_pa", "gel_modulus_pa", "gel_thickness_m",
             "finger_stiffness_n_per_m")
_INTS = ("grasp", "augmentation")
_STRINGS = ("object_name", "material", "shape")
_ESTIMATE_MEMBERS = ("estimate_method", "estimate_state", "estimate_reason", "estimate_pa")


@dataclass(frozen=True)
class TrainingSample:
    """One grasp's model input and label; every field is checked on construction.

    Parameters
    ----------
    object_name : str
    grasp : int
        Grasp index of the object (>= 0).
    augmentation : int
        Augmentation index of the grasp (>= 0; 0 for an unaugmented sample).
    rgb_diff : ndarray, float32, shape (n, H, W, 3)
        Difference images (frame minus no-contact frame), BGR, 8-bit levels, finite.
    depth_m : ndarray, float32, shape (n, H, W)
        Gel indentation depth, metres, finite.
    force_n : ndarray, float64, shape (n,)
        Normal force at each frame, N, finite.
    width_m : ndarray, float64, shape (n,)
        Gripper width at each frame, m, finite and >= 0.
    rgb_diff_markers, depth_markers_m : ndarray or None
        The same two arrays from the marker finger (both or neither), n frames each.
    elastic_estimate_pa, hertz_estar_pa : float or None
        Analytical estimates (E from simple elasticity; composite E* from Hertz), Pa;
        None when not available. Never NaN, infinite or <= 0.
    label_modulus_pa : float or None
        The object's true Young's modulus, Pa; None when unlabelled.
    gel_modulus_pa : float or None
        Young's modulus of the measuring sensor's gel (its settings), Pa; None when unknown.
    gel_thickness_m, finger_stiffness_n_per_m : float or None
        The measuring rig's gel thickness (m) and finger stiffness (N/m); None when unknown.
    material, shape : str
        Material class and shape of the object ("" when unknown).
    estimates : tuple of Estimate
        Analytical estimates over these frames, at most one per method (empty when
        not computed).

    Raises
    ------
    SampleError
        A field has the wrong type, dtype or shape, or a value is not finite.
    """

    object_name: str
    grasp: int
    augmentation: int
    rgb_diff: np.ndarray
    depth_m: np.ndarray
    force_n: np.ndarray
    width_m: np.ndarray
    rgb_diff_markers: np.ndarray | None = None
    depth_markers_m: np.ndarray | None = None
    elastic_estimate_pa: float | None = None
    hertz_estar_pa: float | None = None
    label_modulus_pa: float | None = None
    gel_modulus_pa: float | None = None
    gel_thickness_m: float | None = None
    finger_stiffness_n_per_m: float | None = None
    material: str = ""
    shape: str = ""
    estimates: tuple[Estimate, ...] = ()

    def __post_init__(self) -> None:
        for name in _STRINGS:
            if not isinstance(getattr(self, name), str):
                self._fail(f"{name} must be a string, got {getattr(self, name)!r}")
        if not self.object_name:
            self._fail("object_name is empty")
        for name in _INTS:
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < 0:
                self._fail(f"{name} must be an integer >= 0, got {value!r}")
            object.__setattr__(self, name, int(value))
        rgb = self._array("rgb_diff", np.float32, ndim=4)
        if rgb.shape[0] < 1 or rgb.shape[3] != 3:
            self._fail(f"rgb_diff must have shape (n >= 1, H, W, 3), got {rgb.shape}")
        n = rgb.shape[0]
        self._array("depth_m", np.float32, shape=rgb.shape[:3])
        self._array("force_n", np.float64, shape=(n,))
        width = self._array("width_m", np.float64, shape=(n,))
        if np.any(width < 0):
            self._fail(f"width_m must be >= 0 m, got {width.tolist()}")
        markers = [getattr(self, name) is None for name in _MARKER_ARRAYS]
        if any(markers) != all(markers):
            self._fail("rgb_diff_markers and depth_markers_m must be given together")
        if not any(markers):
            rgb_markers = self._array("rgb_diff_markers", np.float32, ndim=4)
            if rgb_markers.shape[0] != n or rgb_markers.shape[3] != 3:
                self._fail(f"rgb_diff_markers must have shape ({n}, H, W, 3), got {rgb_markers.shape}")
            self._array("depth_markers_m", np.float32, shape=rgb_markers.shape[:3])
        for name in _POSITIVE:
            value = getattr(self, name)
            if value is None:
                continue
            if isinstance(value, bool) or not isinstance(value, int | float | np.integer | np.floating):
                self._fail(f"{name} must be a number or None, got {value!r}")
            if not (np.isfinite(value) and value > 0):
                self._fail(f"{name} must be finite and > 0 (or None when unknown), got {value!r}")
            object.__setattr__(self, name, float(value))
        estimates = tuple(self.estimates) if isinstance(self.estimates, list | tuple) else None
        if estimates is None or not all(isinstance(e, Estimate) for e in estimates):
            self._fail(f"estimates must be a tuple of Estimate, got {self.estimates!r}")
        methods = [e.method for e in estimates]
        if len(set(methods)) != len(methods):
            self._fail(f"estimates name a method twice: {methods}")
        object.__setattr__(self, "estimates", estimates)

    def _fail(self, what: str) -> None:
        raise SampleError(
            f"training sample {self.object_name!r} grasp {self.grasp!r} "
            f"augmentation {self.augmentation!r}: {what}"
        )

    def _array(self, name: str, dtype: type, *, ndim: int | None = None,
               shape: tuple[int, ...] | None = None) -> np.ndarray:
        """Check field ``name`` is a finite ``dtype`` array of ``ndim`` dimensions or ``shape``."""
        value = getattr(self, name)
        if not isinstance(value, np.ndarray):
            self._fail(f"{name} must be a numpy array, got {type(value).__name__}")
        expected = f"shape {shape}" if shape is not None else f"{ndim} dimensions"
        if value.dtype != dtype or (shape is not None and value.shape != shape) or (
            ndim is not None and value.ndim != ndim
        ):
            self._fail(
                f"{name} must be {np.dtype(dtype)} with {expected}, got {value.dtype} {value.shape}"
            )
        if not np.all(np.isfinite(value)):
            self._fail(f"{name} holds {np.count_nonzero(~np.isfinite(value))} non-finite values")
        return value

    @property
    def n_frames(self) -> int:
        """Number of frames (n)."""
        return int(self.rgb_diff.shape[0])

    @property
    def has_markers(self) -> bool:
        """Whether the marker finger's arrays are present."""
        return self.rgb_diff_markers is not None

    def estimate(self, method: str) -> Estimate | None:
        """The analytical estimate of ``method``, or None when the sample has none."""
        return next((e for e in self.estimates if e.method == method), None)


def _estimate_members(estimates: tuple[Estimate, ...]) -> dict[str, np.ndarray]:
    """The ``estimate_*`` members of ``estimates`` (None written as NaN)."""
    values = [(e.e_pa, *e.interval_pa) for e in estimates]
    return {
        "estimate_method": np.array([e.method for e in estimates], dtype=np.str_),
        "estimate_state": np.array([e.state for e in estimates], dtype=np.str_),
        "estimate_reason": np.array([e.reason for e in estimates], dtype=np.str_),
        "estimate_pa": np.array([[np.nan if v is None else v for v in row] for row in values],
                                dtype=np.float64).reshape(len(estimates), 3),
    }


def _estimates_from(path: Path, members: dict[str, np.ndarray]) -> tuple[Estimate, ...]:
    """Estimates from the ``estimate_*`` members read from ``path``."""
    text = [members[name] for name in _ESTIMATE_MEMBERS[:3]]
    values = members["estimate_pa"]
    m = text[0].shape[0] if text[0].ndim == 1 else -1
    if any(t.ndim != 1 or t.dtype.kind != "U" or t.shape[0] != m for t in text) or (
        values.dtype != np.float64 or values.shape != (m, 3)
    ):
        raise SampleError(
            f"{path}: estimate_method, estimate_state, estimate_reason must be str (m,) and "
            f"estimate_pa float64 (m, 3), got {[f'{a.dtype} {a.shape}' for a in (*text, values)]}"
        )
    estimates = []
    for method, state, reason, row in zip(*text, values, strict=True):
        e_pa, low, high = (None if np.isnan(v) else float(v) for v in row)
        method = current_method(str(method))  # datasets from before a rename still train and calibrate
        try:
            estimates.append(Estimate(str(method), e_pa, (low, high), str(state), str(reason)))
        except FitError as exc:
            raise SampleError(f"{path}: member 'estimate_pa' of method {str(method)!r}: {exc}") from None
    return tuple(estimates)


def save_sample(sample: TrainingSample, path: str | os.PathLike[str]) -> Path:
    """Write ``sample`` to ``path`` (an ``.npz`` archive, format in the module docstring).

    The file is written under a temporary name and renamed, so a crash never leaves a
    half-written sample under the final name. Returns the path.
    """
    path = Path(path)
    members: dict[str, Any] = {"format": np.str_(SAMPLE_FORMAT), "version": np.int64(SAMPLE_VERSION)}
    for f in dataclasses.fields(sample):
        value = getattr(sample, f.name)
        if value is None:
            continue
        if f.name == "estimates":
            if value:
                members.update(_estimate_members(value))
        elif f.name in _STRINGS:
            members[f.name] = np.str_(value)
        elif f.name in _INTS:
            members[f.name] = np.int64(value)
        elif f.name in _POSITIVE:
            members[f.name] = np.float64(value)
        else:
            members[f.name] = value
    tmp = path.with_name(path.name + ".partial")
    with tmp.open("wb") as fh:
        np.savez(fh, **members)
    tmp.replace(path)
    return path


def load_sample(path: str | os.PathLike[str]) -> TrainingSample:
    """Read a sample written by :func:`save_sample`.

    Raises
    ------
    SampleError
        The file is missing or not an ``.npz`` archive, of another format or version, a
        member is missing, unknown, damaged or of the wrong kind, or the sample it holds
        is invalid; the message names the file and the member.
    """
    path = Path(path)
    if not path.is_file():
        raise SampleError(f"{path}: no such training sample")
    if not zipfile.is_zipfile(path):
        raise SampleError(f"{path}: not a training sample (not an .npz archive)")
    try:
        archive = np.load(path, allow_pickle=False)
    except (OSError, ValueError, EOFError, zipfile.BadZipFile) as exc:
        raise SampleError(f"{path}: not a readable .npz archive ({exc})") from exc
    with archive:
        names = set(archive.files)
        allowed = {"format", "version", *_ESTIMATE_MEMBERS} | {
            f.name for f in dataclasses.fields(TrainingSample) if f.name != "estimates"}
        unknown = sorted(names - allowed)
        if unknown:
            raise SampleError(f"{path}: unknown member {unknown[0]!r}; this is not a version-{SAMPLE_VERSION} sample")

        def member(name: str) -> np.ndarray:
            if name not in names:
                raise SampleError(f"{path}: member {name!r} is missing")
            try:
                return archive[name]
            except (OSError, ValueError, EOFError, zipfile.BadZipFile, zlib.error) as exc:
                raise SampleError(f"{path}: member {name!r} is damaged or not a plain array ({exc})") from exc

        def scalar(name: str, kind: str) -> Any:
            value = member(name)
            if value.ndim != 0 or value.dtype.kind != kind:
                raise SampleError(
                    f"{path}: member {name!r} must be a scalar of kind {kind!r}, got {value.dtype} {value.shape}"
                )
            return value.item()

        fmt = scalar("format", "U")
        if fmt != SAMPLE_FORMAT:
            raise SampleError(f"{path}: format is {fmt!r}, expected {SAMPLE_FORMAT!r}")
        version = scalar("version", "i")
        if version != SAMPLE_VERSION:
            raise SampleError(
                f"{path}: version {version} is not supported (this software reads version {SAMPLE_VERSION})"
            )
        fields: dict[str, Any] = {name: scalar(name, "U") for name in _STRINGS}
        fields.update({name: scalar(name, "i") for name in _INTS})
        fields.update({name: scalar(name, "f") for name in _POSITIVE if name in names})
        fields.update({name: member(name) for name in _ARRAYS})
        fields.update({name: member(name) for name in _MARKER_ARRAYS if name in names})
        present = [name for name in _ESTIMATE_MEMBERS if name in names]
        if present and len(present) != len(_ESTIMATE_MEMBERS):
            missing = sorted(set(_ESTIMATE_MEMBERS) - set(present))
            raise SampleError(f"{path}: member {missing[0]!r} is missing (estimate_* members come together)")
        if present:
            fields["estimates"] = _estimates_from(path, {name: member(name) for name in present})
    try:
        return TrainingSample(**fields)
    except SampleError as exc:
        raise SampleError(f"{path}: {exc}") from None


def sample_paths(directory: str | os.PathLike[str]) -> list[Path]:
    """Every ``.npz`` file under ``directory`` (recursively), sorted by path."""
    directory = Path(directory)
    if not directory.is_dir():
        raise SampleError(f"{directory}: not a directory of training samples")
    return sorted(directory.rglob("*.npz"))


def iter_samples(directory: str | os.PathLike[str]) -> Iterator[TrainingSample]:
    """Load the samples under ``directory`` one at a time (a full dataset does not fit in memory).

    Raises
    ------
    SampleError
        ``directory`` holds no samples, or a sample file is invalid (named in the message).
    """
    paths = sample_paths(directory)
    if not paths:
        raise SampleError(f"{directory}: holds no training samples (*.npz)")
    for path in paths:
        yield load_sample(path)
