"""Import the published dataset: raw grasps to grasp records, preprocessed grasps to training samples.

Layouts (see the product brief)
-------------------------------
raw
    ``<object>/grasp=<i>/`` holding ``<object>.avi`` (no-marker finger, MJPG,
    640x480, 30 fps), ``<object>_markers.avi`` (marker finger),
    ``<object>_forces.pkl`` and ``<object>_widths.pkl`` (pickled 1-D numpy arrays,
    N and m, one value per frame). Each grasp becomes one grasp record
    ``<out>/<object>/grasp=<i>.grasp`` (:mod:`teleop.record`). Frames keep the
    video's own JPEG bytes, unchanged (``encoding="jpeg"``, quality unknown and
    recorded as None): no re-encoding loss and no size growth. Frame ``k`` of
    both videos and the ``k``-th force and width share the time ``k / fps`` s
    (one clock); the sensors' identity and warp calibration come from a
    settings file (the no-marker video goes to the sensor without markers, the
    marker video to the sensor with them).
preprocessed
    ``<object>/grasp=<g>/augmentation=<k>/`` holding ``RGB.pkl`` (n x 250 x 350
    x 3 float difference images, BGR), ``depth.pkl`` (n x 250 x 350, mm),
    ``RGB_markers.pkl``, ``depth_markers.pkl``, ``forces.pkl`` (n,),
    ``widths.pkl`` (n,), ``elastic_estimate.pkl`` (E, Pa) and
    ``hertz_estimate.pkl`` (E*, Pa). Each becomes one training sample
    ``<out>/<object>/grasp=<g>/augmentation=<k>.npz`` (:mod:`estimator.samples`),
    converted explicitly to float32 images and depth in metres. A published
    estimate that is NaN, infinite or <= 0 (the published code had no guards)
    is stored as "not available" and counted.

Labels come from an object table (``--objects``: the published CSV or a
project TOML catalogue) when the object is in it.

Pickles execute code on load, so every ``.pkl`` is read with
:func:`safe_load_pickle`, which admits numpy arrays and nothing else.
"""

from __future__ import annotations

import argparse
import codecs
import io
import json
import os
import pickle
import re
import sys
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy._core.multiarray import _reconstruct, scalar
from numpy._core.numeric import _frombuffer
from tqdm import tqdm

from estimator.errors import SampleError
from estimator.samples import TrainingSample, save_sample
from teleop.catalogue import ObjectSpec, load_catalogue
from teleop.errors import DatasetError, UnsafePickleError
from teleop.record import FrameStream, GraspRecord, Label, Provenance, Samples, write_record
from teleop.settings import SensorSettings, default_settings_path, load_settings

__all__ = [
    "LAYOUTS",
    "ImportSummary",
    "SkippedItem",
    "find_preprocessed_samples",
    "find_raw_grasps",
    "import_dataset",
    "import_preprocessed_sample",
    "import_raw_grasp",
    "load_pickled_array",
    "read_mjpg_packets",
    "safe_load_pickle",
]

LAYOUTS = ("raw", "preprocessed")
RAW_FPS = 30.0

# --------------------------------------------------------------------------- safe unpickling


class _Refused(Exception):
    """An admitted global was asked to build something outside a plain numpy array."""


class _PickledNdarrayType:
    """Stands for ``numpy.ndarray`` inside a pickle: only :func:`_reconstruct_array` accepts it.

    Handing out the real class would let a pickle call ``ndarray(shape)`` directly and
    allocate whatever it asks for.
    """

    def __new__(cls, *args: Any, **kwargs: Any) -> Any:
        raise _Refused("a direct call of numpy.ndarray (arrays are rebuilt through _reconstruct only)")


def _reconstruct_array(subtype: Any, shape: Any, dtype: Any) -> np.ndarray:
    # numpy always pickles an empty (0,) placeholder and fills it from the pickled state;
    # any other shape would only serve to allocate memory.
    if subtype is not _PickledNdarrayType or tuple(shape) != (0,):
        raise _Refused(f"_reconstruct of {subtype!r} with shape {shape!r} (only numpy's empty placeholder is admitted)")
    return _reconstruct(np.ndarray, (0,), dtype)


_LATIN1_NAMES = ("latin1", "latin-1", "iso-8859-1", "iso8859-1", "l1")


def _latin1_encode(text: str, encoding: str = "latin1", errors: str = "strict") -> bytes:
    # Protocol 0-2 pickles carry array bytes as latin-1 text; admit no other codec.
    # Compared by name, not looked up: a codec lookup may import a module.
    if not isinstance(encoding, str) or encoding.lower().replace("_", "-") not in _LATIN1_NAMES:
        raise _Refused(f"_codecs.encode with codec {encoding!r} (only latin-1 is admitted)")
    return codecs.encode(text, "latin1", errors)


# Every global a pickled numpy array, dtype or scalar names (numpy 2 ``numpy._core`` and the
# ``numpy.core`` names of pickles written by numpy 1), mapped to what it may build.
_ADMITTED_GLOBALS: dict[tuple[str, str], Any] = {
    ("numpy", "ndarray"): _PickledNdarrayType,
    ("numpy", "dtype"): np.dtype,
    ("numpy._core.multiarray", "_reconstruct"): _reconstruct_array,
    ("numpy.core.multiarray", "_reconstruct"): _reconstruct_array,
    ("numpy._core.multiarray", "scalar"): scalar,
    ("numpy.core.multiarray", "scalar"): scalar,
    ("numpy._core.numeric", "_frombuffer"): _frombuffer,
    ("numpy.core.numeric", "_frombuffer"): _frombuffer,
    ("_codecs", "encode"): _latin1_encode,
}


class _ArrayUnpickler(pickle.Unpickler):
    """An unpickler whose only globals are those of :data:`_ADMITTED_GLOBALS`."""

    def __init__(self, data: bytes, name: str):
        # latin-1 lets numpy arrays pickled by Python 2 load (their bytes are str there).
        super().__init__(io.BytesIO(data), encoding="latin1")
        self.name = name

    def find_class(self, module: str, name: str) -> Any:
        try:
            return _ADMITTED_GLOBALS[(module, name)]
        except KeyError:
            raise UnsafePickleError(
                f"{self.name}: refused pickle global {module}.{name}: only numpy arrays are admitted "
                "(a pickle naming it could run code when loaded)"
            ) from None

    def persistent_load(self, pid: Any) -> Any:
        raise UnsafePickleError(f"{self.name}: refused persistent id {pid!r}: only numpy arrays are admitted")


def _check_plain(value: Any, name: str) -> None:
    """Refuse anything but numeric/string arrays, numpy scalars and plain data holding them."""
    if isinstance(value, np.ndarray | np.generic):
        if value.dtype.hasobject:
            raise UnsafePickleError(f"{name}: refused an object array: only plain numpy arrays are admitted")
    elif isinstance(value, list | tuple):
        for item in value:
            _check_plain(item, name)
    elif isinstance(value, dict):
        for key, item in value.items():
            _check_plain(key, name)
            _check_plain(item, name)
    elif not (value is None or isinstance(value, bool | int | float | complex | str | bytes)):
        raise UnsafePickleError(f"{name}: refused a {type(value).__name__}: only numpy arrays are admitted")


def safe_load_pickle(source: str | os.PathLike[str] | bytes, *, name: str | None = None) -> Any:
    """Unpickle ``source`` (a path, or the pickle's bytes) admitting numpy arrays and nothing else.

    The unpickler resolves only the globals a pickled numpy array, dtype or numpy
    scalar needs (numpy 2 and numpy 1 names); any other global (``os.system``,
    ``eval``, ``subprocess.Popen``, ...) is refused before it is imported or
    called, so nothing in the pickle runs. The result may be an array, a numpy
    scalar, or plain numbers, strings, lists, tuples and dicts of them; object
    arrays are refused.

    Parameters
    ----------
    source : path or bytes
        The pickle file, or its contents.
    name : str, optional
        What to call the pickle in errors (default: the path, or ``"<bytes>"``).

    Raises
    ------
    UnsafePickleError
        The pickle names a global other than the admitted ones, or builds an object
        array; the message names the file and what was refused.
    DatasetError
        The file cannot be read, or is not a complete, valid pickle.
    """
    if isinstance(source, bytes | bytearray | memoryview):
        data = bytes(source)
        name = name or "<bytes>"
    else:
        name = name or str(source)
        try:
            data = Path(source).read_bytes()
        except OSError as exc:
            raise DatasetError(f"{name}: cannot read pickle ({exc.strerror or exc})") from exc
    try:
        value = _ArrayUnpickler(data, name).load()
    except UnsafePickleError:
        raise
    except _Refused as exc:
        raise UnsafePickleError(f"{name}: refused {exc}: only numpy arrays are admitted") from None
    except Exception as exc:  # a damaged pickle fails in many ways; each is the same user error
        raise DatasetError(f"{name}: not a valid pickle of numpy arrays ({type(exc).__name__}: {exc})") from exc
    _check_plain(value, name)
    return value


def load_pickled_array(path: str | os.PathLike[str], *, ndim: int | None = None) -> np.ndarray:
    """A numeric array from a pickle read with :func:`safe_load_pickle` (dtype kept as stored).

    Raises
    ------
    DatasetError
        The pickle is unsafe or damaged, does not hold a real-valued numeric array,
        holds non-finite values, or (when ``ndim`` is given) has another number of
        dimensions. The message names the file.
    """
    value = np.asarray(safe_load_pickle(path))
    if value.dtype.kind not in "biuf":
        raise DatasetError(f"{path}: expected a numeric array, got dtype {value.dtype}")
    if ndim is not None and value.ndim != ndim:
        raise DatasetError(f"{path}: expected a {ndim}-D array, got shape {value.shape}")
    if not np.all(np.isfinite(value)):
        raise DatasetError(f"{path}: {np.count_nonzero(~np.isfinite(value))} values are NaN or infinite")
    return value


# --------------------------------------------------------------------------- raw layout


def read_mjpg_packets(path: str | os.PathLike[str]) -> tuple[tuple[bytes, ...], tuple[int, int, int]]:
    """The JPEG bytes of every frame of an MJPG video, unchanged, and the frame shape.

    Every frame is checked to decode (at 1/8 scale, for speed); the first is decoded in full
    for its (rows, cols, 3) shape.

    Raises
    ------
    DatasetError
        The video cannot be opened, is not MJPG, has no frames, is truncated (fewer frames
        than its header lists) or a frame does not decode; the message names the file.
    """
    capture = cv2.VideoCapture(str(path), cv2.CAP_FFMPEG)
    packets = []
    try:
        if not capture.isOpened():
            raise DatasetError(f"{path}: unreadable video (OpenCV's FFMPEG backend cannot open it)")
        fourcc = (int(capture.get(cv2.CAP_PROP_FOURCC)) & 0xFFFFFFFF).to_bytes(4, "little").decode("latin1")
        if fourcc.upper() != "MJPG":
            raise DatasetError(f"{path}: expected an MJPG video, got codec {fourcc!r}")
        listed = int(capture.get(cv2.CAP_PROP_FRAME_COUNT))
        # Raw mode hands out the encoded packets (here: one JPEG per frame) instead of decoding.
        if not capture.set(cv2.CAP_PROP_FORMAT, -1):
            raise DatasetError(f"{path}: this OpenCV build cannot hand out MJPG frames undecoded")
        while True:
            ok, packet = capture.read()
            if not ok:
                break
            packets.append(packet.tobytes())
    finally:
        capture.release()
    if not packets:
        raise DatasetError(f"{path}: the video holds no frames")
    if listed > len(packets):
        raise DatasetError(f"{path}: truncated video: its header lists {listed} frames, {len(packets)} read")
    first = cv2.imdecode(np.frombuffer(packets[0], np.uint8), cv2.IMREAD_COLOR)
    if first is None:
        raise DatasetError(f"{path}: frame 0 is not a decodable JPEG")
    for i, packet in enumerate(packets[1:], start=1):
        if cv2.imdecode(np.frombuffer(packet, np.uint8), cv2.IMREAD_REDUCED_GRAYSCALE_8) is None:
            raise DatasetError(f"{path}: frame {i} is not a decodable JPEG")
    return tuple(packets), first.shape


def _layout_index(folder: Path, key: str) -> int:
    match = re.fullmatch(rf"{key}=(\d+)", folder.name)
    if match is None:
        raise DatasetError(f"{folder}: expected a folder named {key}=<integer>")
    return int(match.group(1))


def _member(folder: Path, name: str) -> Path:
    path = folder / name
    if not path.is_file():
        raise DatasetError(f"{path}: missing (the layout needs it)")
    return path


def _label(object_name: str, labels: Mapping[str, ObjectSpec]) -> Label:
    spec = labels.get(object_name)
    if spec is None:
        return Label(object_name=object_name)
    return Label(object_name, spec.modulus_pa, spec.material, spec.shape, {"source": spec.source})


def _find(root: Path, pattern: str, what: str) -> list[Path]:
    if not root.is_dir():
        raise DatasetError(f"{root}: not a directory")
    folders = sorted(p for p in root.glob(pattern) if p.is_dir())
    if not folders:
        raise DatasetError(f"{root}: no {what} folders: not the expected layout")
    return folders


def find_raw_grasps(root: str | os.PathLike[str]) -> list[Path]:
    """The ``<object>/grasp=<i>`` folders under ``root``, sorted."""
    return _find(Path(root), "*/grasp=*", "<object>/grasp=<i>")


def _raw_sensors(sensors: Sequence[SensorSettings]) -> tuple[SensorSettings, SensorSettings]:
    plain = next((s for s in sensors if not s.markers), None)
    marked = next((s for s in sensors if s.markers), None)
    if plain is None or marked is None:
        raise DatasetError(
            "the raw layout has a no-marker and a marker video per grasp: the settings need one "
            f"sensor without markers and one with (fingers: {[s.finger for s in sensors]})"
        )
    return plain, marked


def import_raw_grasp(
    grasp_dir: str | os.PathLike[str],
    *,
    sensors: Sequence[SensorSettings],
    labels: Mapping[str, ObjectSpec] | None = None,
    fps: float = RAW_FPS,
) -> GraspRecord:
    """One raw-layout grasp folder as a :class:`~teleop.record.GraspRecord`.

    Parameters
    ----------
    grasp_dir : path
        ``<object>/grasp=<i>``.
    sensors : sequence of SensorSettings
        Must hold a sensor without markers (gets ``<object>.avi``) and one with markers
        (gets ``<object>_markers.avi``); their raw frame size must match the videos.
    labels : mapping of object name to ObjectSpec, optional
        Ground truth; objects not in it get a label with the name alone.
    fps : float
        Frame rate, Hz: frame ``k`` and force/width sample ``k`` are at ``k / fps`` s.

    Raises
    ------
    DatasetError
        A file is missing, unreadable, unsafe or damaged, or the videos, forces and widths
        do not have one length; the message names the file.
    """
    grasp_dir = Path(grasp_dir)
    index = _layout_index(grasp_dir, "grasp")
    name = grasp_dir.parent.name
    plain, marked = _raw_sensors(sensors)
    force = load_pickled_array(_member(grasp_dir, f"{name}_forces.pkl"), ndim=1)
    width = load_pickled_array(_member(grasp_dir, f"{name}_widths.pkl"), ndim=1)
    streams = []
    for sensor, video_name in ((plain, f"{name}.avi"), (marked, f"{name}_markers.avi")):
        video = _member(grasp_dir, video_name)
        packets, shape = read_mjpg_packets(video)
        expected = (sensor.raw_height_px, sensor.raw_width_px, 3)
        if shape != expected:
            raise DatasetError(f"{video}: frames are {shape}, sensor {sensor.finger!r} expects {expected}")
        if len(packets) != force.shape[0]:
            raise DatasetError(
                f"{video}: {len(packets)} frames but {force.shape[0]} forces in {name}_forces.pkl "
                "(expected one per frame)"
            )
        t_s = np.arange(len(packets)) / fps
        streams.append(FrameStream(sensor.finger, t_s, packets, encoding="jpeg", shape=shape))
    if width.shape != force.shape:
        raise DatasetError(
            f"{grasp_dir / f'{name}_widths.pkl'}: {width.shape[0]} widths but {force.shape[0]} forces "
            "(expected one per frame)"
        )
    t_s = streams[0].t_s
    return GraspRecord(
        sensors=(plain, marked),
        frames=tuple(streams),
        force_n=Samples(t_s, force.astype(np.float64)),
        width_m=Samples(t_s, width.astype(np.float64)),
        provenance=Provenance(
            source="imported",
            model="published dataset, raw layout",
            created_utc=datetime.now(UTC).isoformat(timespec="seconds"),
            extra={"source_dir": str(grasp_dir), "grasp": index, "fps": fps},
        ),
        label=_label(name, labels or {}),
    )


# --------------------------------------------------------------------------- preprocessed layout


def find_preprocessed_samples(root: str | os.PathLike[str]) -> list[Path]:
    """The ``<object>/grasp=<g>/augmentation=<k>`` folders under ``root``, sorted."""
    return _find(Path(root), "*/grasp=*/augmentation=*", "<object>/grasp=<g>/augmentation=<k>")


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
    """One preprocessed-layout folder as a :class:`~estimator.samples.TrainingSample`.

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
    augmentation = _layout_index(sample_dir, "augmentation")
    grasp = _layout_index(sample_dir.parent, "grasp")
    name = sample_dir.parent.parent.name

    def array(member: str, ndim: int) -> np.ndarray:
        return load_pickled_array(_member(sample_dir, member), ndim=ndim)

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
            elastic_estimate_pa=_published_modulus(_member(sample_dir, "elastic_estimate.pkl")),
            hertz_estar_pa=_published_modulus(_member(sample_dir, "hertz_estimate.pkl")),
            label_modulus_pa=spec.modulus_pa if spec else None,
            material=spec.material if spec else "",
            shape=spec.shape if spec else "",
        )
    except SampleError as exc:
        raise SampleError(f"{sample_dir}: {exc}") from None


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
    progress: bool | None = False,
) -> ImportSummary:
    """Import every grasp (raw) or sample (preprocessed) under ``src`` into ``out``.

    A folder whose files are missing, unreadable, unsafe or inconsistent is skipped
    with its reason (reported through ``on_skip``) and the import carries on.

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
        Settings TOML whose sensors describe the raw videos (default: the shipped one).
    fps : float
        Frame rate of the raw videos, Hz.
    on_skip : callable, optional
        Called with each :class:`SkippedItem` as it happens.
    progress : bool or None
        Show a tqdm bar on stderr (None: only on a terminal).

    Raises
    ------
    DatasetError
        ``layout`` is unknown, ``src`` holds no folder of that layout, the settings lack the
        sensors the raw layout needs, or an output cannot be written.
    """
    if layout not in LAYOUTS:
        raise DatasetError(f"layout {layout!r}: expected one of {', '.join(LAYOUTS)}")
    if not (np.isfinite(fps) and fps > 0):
        raise DatasetError(f"fps = {fps}: expected a frame rate > 0 Hz")
    src, out = Path(src), Path(out)
    labels = {spec.name: spec for spec in load_catalogue(objects)} if objects is not None else {}
    summary = ImportSummary(layout=layout, source=str(src), out=str(out))
    if layout == "raw":
        sensors = _raw_sensors(load_settings(settings if settings is not None else default_settings_path()).sensors)
        folders = find_raw_grasps(src)
    else:
        folders = find_preprocessed_samples(src)
    for folder in tqdm(folders, desc=f"import {layout}", unit="grasp" if layout == "raw" else "sample",
                       file=sys.stderr, disable=None if progress is None else not progress):
        relative = folder.relative_to(src)
        try:
            if layout == "raw":
                item: GraspRecord | TrainingSample = import_raw_grasp(
                    folder, sensors=sensors, labels=labels, fps=fps)
            else:
                item = import_preprocessed_sample(folder, labels=labels)
        except (DatasetError, SampleError) as exc:
            skipped = SkippedItem(str(folder), str(exc))
            summary.skipped.append(skipped)
            if on_skip is not None:
                on_skip(skipped)
            continue
        try:
            if isinstance(item, GraspRecord):
                dest = out / relative.parent / f"{relative.name}.grasp"
                dest.parent.mkdir(parents=True, exist_ok=True)
                write_record(item, dest)
                summary.labelled += int(item.label is not None and item.label.modulus_pa is not None)
            else:
                dest = out / relative.parent / f"{relative.name}.npz"
                dest.parent.mkdir(parents=True, exist_ok=True)
                save_sample(item, dest)
                summary.labelled += int(item.label_modulus_pa is not None)
                summary.unavailable_estimates += [item.elastic_estimate_pa, item.hertz_estar_pa].count(None)
        except OSError as exc:
            raise DatasetError(f"cannot write {dest}: {exc.strerror or exc}") from exc
        summary.imported.append(str(dest))
    return summary


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
                             "videos")
    parser.add_argument("--fps", type=float, default=RAW_FPS,
                        help="frame rate of the raw videos, Hz; frame k is at k / fps seconds")
    parser.add_argument("--json", action="store_true",
                        help="print the summary as one JSON object on the last stdout line")


def run(args: argparse.Namespace) -> int:
    def report(item: SkippedItem) -> None:
        tqdm.write(f"skipped {item.path}: {item.reason}", file=sys.stderr)

    summary = import_dataset(
        args.src, layout=args.layout, out=args.out, objects=args.objects, settings=args.settings,
        fps=args.fps, on_skip=report, progress=None,
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
