"""Run a trained model with onnxruntime; never imports torch.

A model directory holds ``model.onnx`` and ``metadata.json`` (written by
``estimator train``). Its identity is :func:`model_id`: the folder's name and a hash of those
files' contents, so two copies of one model have one id and any edit gives another; the live
service stamps every estimate with it. :class:`CompliancePredictor` reads each file once and
takes its :attr:`~CompliancePredictor.model_id` from the bytes it loaded, so the id names exactly
the pair it runs even while the files are being replaced.

``metadata.json`` holds:

``format``, ``version``
    ``"compliance-teleop.model"``, 1.
``variant``
    ``{"name", "n_frames", "size_px", "window_m"}``: the inputs it reads
    (:class:`~estimator.inference.inputs.Variant`); ``window_m`` = [height, width] in metres of the
    gel patch its images show (:mod:`estimator.inference.inputs`, "Input window"). A model without
    it (made before the key) reads the pad of the sensor it was trained on, the simulated Wedge's
    (:func:`~estimator.inference.inputs.default_window_m`).
``inputs``
    Input name -> shape with ``null`` for the batch axis; ``output``: the output's name.
``scales``
    The input and output scales it was trained with (checked against this code's; the
    ``analytical_methods`` only for a model that reads them), the output's log10 E bins among them.
``calibration``
    Fitted on the validation objects: ``temperature`` (divides the logits), ``floor``
    (``{"methods", "leak"}``: the analytical methods whose lower bounds floor a hybrid's
    distribution, and the share of its mass left below; null or absent for none),
    ``level`` (the stated coverage of an ``ok`` interval, 0.9), ``force_band_edges_n`` and
    ``interval_scales`` (per band of the grasp's peak force, the interval's half-width in spreads of
    the distribution that holds the truth at that level: split conformal per band; a model from
    before the bands has one ``interval_scale`` for every force), ``p_rigids`` (per band, the
    probability of E at or above the resolution limit from which the answer is a lower bound there;
    one ``p_rigid`` for all bands in a model from before the key), ``soft_pa`` (the softest training label: below it the
    estimate is an upper bound) and what they scored on the validation grasps
    (:mod:`estimator.inference.distribution`).
``metrics``, ``training``, ``data``
    What it scored on val and test objects, how and on what it was trained;
    ``data.measurement_version`` is the :data:`~estimator.inference.inputs.MEASUREMENT_VERSION`
    its inputs were measured with, ``data.depth_binning`` the depth grid
    (:attr:`~estimator.settings.EstimatorSettings.depth_binning`), and ``reference``
    its inputs on the fixed reference record (:mod:`estimator.inference.reference`).
"""

from __future__ import annotations

import copy
import hashlib
import itertools
import json
import logging
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
import onnxruntime as ort

from estimator.errors import ModelError
from estimator.inference import distribution, inputs
from estimator.inference.distribution import (
    Described,
    describe_on_gel,
    floor_log_weights,
    force_band,
    probabilities,
)
from estimator.inference.inputs import (
    MEASUREMENT_VERSION,
    ModelInputs,
    Variant,
    calibration_smoothings,
    default_window_m,
    encode,
)
from estimator.settings import estimator_settings
from teleop.bus.wire import MAX_MODEL_ID_CHARS
from teleop.scene import current_method
from teleop.settings import Settings, resolve_path

__all__ = [
    "MODEL_FILES",
    "MODEL_FORMAT",
    "CompliancePredictor",
    "ModelMetadata",
    "bands_text",
    "current_scales",
    "default_model_dir",
    "force_bands",
    "load_predictor",
    "model_files",
    "model_id",
]

log = logging.getLogger(__name__)

MODEL_FORMAT = "compliance-teleop.model"
MODEL_VERSION = 2
OUTPUT_NAME = "log10_e_logits"
#: The files a model folder must hold.
MODEL_FILES = ("model.onnx", "metadata.json")
MODEL_ID_HEX = 8  # hex digits of the content hash in a model id


def model_files(model_dir: str | Path) -> list[Path]:
    """The files a model's identity covers: ``metadata.json``, then every ``.onnx`` file of the
    folder by name (``model.onnx`` among them).

    Raises
    ------
    ModelError
        ``model_dir`` does not exist, is not a folder, or lacks one of :data:`MODEL_FILES` (named).
    """
    folder = _model_folder(model_dir)
    missing = [name for name in MODEL_FILES if not (folder / name).is_file()]
    if missing:
        raise ModelError(f"{folder} is not a model folder: it has no {' and no '.join(missing)} (a model folder "
                         f"holds {' and '.join(MODEL_FILES)}, as `estimator train` writes them)")
    # Regular files only: a named pipe or a folder ending in .onnx would block or fail the hash.
    return [folder / "metadata.json", *sorted(p for p in folder.glob("*.onnx") if p.is_file())]


def _model_folder(model_dir: str | Path) -> Path:
    folder = Path(model_dir)
    if not folder.exists():
        raise ModelError(f"model folder {folder} does not exist")
    if not folder.is_dir():
        raise ModelError(f"{folder} is not a model folder (a folder holding {' and '.join(MODEL_FILES)})")
    return folder


def read_metadata(model_dir: str | Path) -> tuple[Path, dict[str, Any]]:
    """The path and parsed contents of a model folder's ``metadata.json``, unchecked (what a model
    says of itself needs no network file).

    Raises
    ------
    ModelError
        ``model_dir`` is not a folder, or its ``metadata.json`` is missing or not JSON.
    """
    meta_path = _model_folder(model_dir) / "metadata.json"
    if not meta_path.is_file():
        raise ModelError(f"{model_dir} is not a model folder: it has no metadata.json")
    try:
        return meta_path, json.loads(meta_path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ModelError(f"{meta_path}: not a readable model metadata file ({exc})") from exc


def _digest_id(folder: Path, contents: Sequence[tuple[str, bytes]]) -> str:
    """``<folder name>-<hex>``: the name cut so the id has at most MAX_MODEL_ID_CHARS characters."""
    digest = hashlib.sha256()
    for name, data in contents:  # the names too: a file renamed is another model
        digest.update(name.encode("utf-8") + b"\0" + len(data).to_bytes(8, "little"))
        digest.update(data)
    name = folder.resolve().name or "model"
    return f"{name[: MAX_MODEL_ID_CHARS - MODEL_ID_HEX - 1]}-{digest.hexdigest()[:MODEL_ID_HEX]}"


def model_id(model_dir: str | Path) -> str:
    """The id of the model in ``model_dir``: ``"<folder name>-<8 hex digits>"``, the digits the start
    of a SHA-256 over the contents of ``metadata.json`` and every ``.onnx`` file (:func:`model_files`);
    at most 64 characters (a long folder name is cut). The same files give the same id wherever
    they lie under a folder of that name; a changed byte gives another.

    Raises
    ------
    ModelError
        ``model_dir`` is not a model folder (:func:`model_files`) or a file cannot be read.
    """
    files = model_files(model_dir)
    try:
        return _digest_id(Path(model_dir), [(f.name, f.read_bytes()) for f in files])
    except OSError as exc:
        raise ModelError(f"{model_dir}: cannot read the model's files ({exc.strerror or exc})") from exc


def default_model_dir() -> Path:
    """The shipped default model (``estimator/models/default``)."""
    return Path(__file__).resolve().parent.parent / "models" / "default"


def current_scales() -> dict[str, Any]:
    """The input and output scales of this code (a model must have been trained with them)."""
    return {
        "log10_e_range": list(inputs.LOG10_E_RANGE),
        "log10_e_bins": distribution.N_BINS,
        "force_scale_n": inputs.FORCE_SCALE_N,
        "width_scale_m": inputs.WIDTH_SCALE_M,
        "depth_scale_m": inputs.DEPTH_SCALE_M,
        "rgb_scale": inputs.RGB_SCALE,
        "analytical_methods": list(inputs.ANALYTICAL_METHODS),
        "features_per_method": inputs.FEATURES_PER_METHOD,
        "reference_gel_modulus_pa": inputs.REFERENCE_GEL_MODULUS_PA,
        "reference_gel_thickness_m": inputs.REFERENCE_GEL_THICKNESS_M,
        "reference_finger_stiffness_n_per_m": inputs.REFERENCE_FINGER_STIFFNESS_N_PER_M,
    }


def _scales_differ(scales: Any, *, analytical: bool) -> str:
    """How a model's ``scales`` (its metadata's) differ from :func:`current_scales`, in words: each
    differing key with both values; empty when none does.

    ``analytical_methods`` counts only for a model that reads the analytical fits (``analytical``,
    its variant's): which fits there are changes none of a CNN's inputs.
    """
    if not isinstance(scales, Mapping):
        return f"expected a table of scales, got {scales!r}"
    current = current_scales()
    keys = [*current, *(key for key in scales if key not in current)]
    if not analytical:
        keys.remove("analytical_methods")

    def shown(table: Mapping[str, Any], key: str) -> str:
        return repr(table[key]) if key in table else "absent"

    return ", ".join(f"{key} {shown(scales, key)} (this code: {shown(current, key)})" for key in keys
                     if (key in scales, scales.get(key)) != (key in current, current.get(key)))


@dataclass(frozen=True)
class ModelMetadata:
    """The checked content of a model's ``metadata.json`` (module notes)."""

    variant: Variant
    temperature: float
    p_rigids: tuple[float, ...]
    interval_level: float
    floor_methods: tuple[str, ...]
    floor_leak: float
    force_band_edges_n: tuple[float, ...]
    interval_scales: tuple[float, ...]
    soft_pa: float
    raw: Mapping[str, Any]

    def band(self, peak_force_n: float) -> int:
        """The force band of a grasp of peak force ``peak_force_n`` (N): an index into the per-band fields."""
        return int(force_band(peak_force_n, self.force_band_edges_n))

    def interval_scale_at(self, peak_force_n: float) -> float:
        """The calibrated interval half-width (spreads) for a grasp of peak force ``peak_force_n`` (N)."""
        return self.interval_scales[self.band(peak_force_n)]

    def p_rigid_at(self, peak_force_n: float) -> float:
        """The calibrated ``p_rigid`` for a grasp of peak force ``peak_force_n`` (N)."""
        return self.p_rigids[self.band(peak_force_n)]

    def force_band_at(self, peak_force_n: float) -> str:
        """The force band of a grasp of peak force ``peak_force_n`` (N) in words (``"below 10 N"``)."""
        return band_names(self.force_band_edges_n)[self.band(peak_force_n)]

    @classmethod
    def from_json(cls, data: Any, source: str) -> ModelMetadata:
        """Check ``data`` (parsed JSON) and build the metadata; ModelError names ``source``."""
        if not isinstance(data, dict) or data.get("format") != MODEL_FORMAT:
            raise ModelError(f"{source}: not a {MODEL_FORMAT} metadata file")
        data = _series_renamed(data)
        if data.get("version") != MODEL_VERSION:
            raise ModelError(f"{source}: metadata version {data.get('version')!r}, this software reads "
                             f"{MODEL_VERSION}; retrain the model (`estimator train`, the 'train' extra; in a checkout `make model`, the model card's recipe)")
        try:
            spec = data["variant"]
            window = spec.get("window_m")
            variant = Variant.parse(spec["name"], n_frames=int(spec["n_frames"]),
                                    size_px=tuple(int(v) for v in spec["size_px"]),
                                    window_m=None if window is None else tuple(float(v) for v in window))
            cal = data["calibration"]
            values = {k: float(cal[k]) for k in ("temperature", "level", "soft_pa")}
            edges, p_rigids, scales = force_bands(cal)
            floor = cal.get("floor") or {"methods": [], "leak": 1.0}
            floor_methods, floor_leak = tuple(str(m) for m in floor["methods"]), float(floor["leak"])
        except (AttributeError, KeyError, TypeError, ValueError) as exc:
            raise ModelError(f"{source}: missing or malformed field ({exc!r})") from exc
        if not all(math.isfinite(v) for v in (*values.values(), *edges, *scales)) or not (
                values["temperature"] > 0 and 0 < values["level"] < 1 and min(scales) > 0
                and values["soft_pa"] > 0 and all(0 < p < 1 for p in p_rigids)
                and len(scales) == len(p_rigids) == len(edges) + 1 and list(edges) == sorted(set(edges))
                and 0 < floor_leak <= 1 and set(floor_methods) <= set(inputs.ANALYTICAL_METHODS)):
            raise ModelError(f"{source}: calibration {cal}: expected temperature > 0, 0 < level < 1, "
                             "soft_pa > 0, rising force_band_edges_n, one interval scale > 0 and one "
                             "0 < p_rigid < 1 per force band and a floor of analytical methods leaking 0-1")
        differ = _scales_differ(data.get("scales"), analytical=variant.analytical)
        if differ:
            raise ModelError(f"{source}: trained with input scales that differ from this code's: {differ}; "
                             "retrain the model")
        if variant.window_m is None:
            variant = replace(variant, window_m=default_window_m())
            log.info("%s: no variant.window_m (a model from before the key): it reads the pad of the sensor the "
                     "shipped models were trained on, the simulated Wedge's %.2f x %.2f mm", source,
                     *(v * 1e3 for v in variant.window_m))
        expected = {name: [None, *shape] for name, shape in variant.input_shapes.items()}
        if data.get("inputs") != expected:
            raise ModelError(f"{source}: inputs {data.get('inputs')} do not match variant {variant.name} ({expected})")
        return cls(variant=variant, temperature=values["temperature"], p_rigids=p_rigids,
                   interval_level=values["level"], floor_methods=floor_methods, floor_leak=floor_leak,
                   force_band_edges_n=edges, interval_scales=scales,
                   soft_pa=values["soft_pa"], raw=data)


def _series_renamed(data: dict[str, Any]) -> dict[str, Any]:
    """A copy of a model's metadata with every method named as it is now
    (:func:`~teleop.scene.current_method`): in the method lists, the per-method metrics and
    ``auto``'s fields, so that a model trained before a rename loads and answers as it did."""
    data = copy.deepcopy(data)

    def at(*path: str) -> Any:
        node: Any = data
        for key in path:
            node = node.get(key) if isinstance(node, dict) else None
        return node

    for path, key in ((("scales",), "analytical_methods"), (("calibration", "floor"), "methods"),
                      (("recalibrated", "previous", "floor"), "methods")):
        holder = at(*path)
        if isinstance(holder, dict) and isinstance(holder.get(key), list):
            holder[key] = [current_method(m) for m in holder[key]]
    metrics = at("metrics")
    for part, figures in metrics.items() if isinstance(metrics, dict) else ():
        if isinstance(figures, dict):
            metrics[part] = {current_method(k): v for k, v in figures.items()}
    auto = at("auto")
    if isinstance(auto, dict):
        # auto's fields name the series fit: its interval threshold and its column of the table.
        renamed = {"max_split_interval_decades": "max_series_interval_decades",
                   "split_log10_error": "series_log10_error"}
        data["auto"] = auto = {renamed.get(k, k): v for k, v in auto.items()}
        if isinstance(auto.get("table"), list):
            auto["table"] = [{renamed.get(k, k): v for k, v in row.items()} if isinstance(row, dict) else row
                             for row in auto["table"]]
    return data


def force_bands(calibration: Mapping[str, Any]) -> tuple[tuple[float, ...], tuple[float, ...], tuple[float, ...]]:
    """``(force_band_edges_n, p_rigids, interval_scales)`` of a model's calibration, one ``p_rigid`` and
    one scale per band; a model from before the bands has one band (its ``interval_scale``), and one
    from before ``p_rigids`` the same ``p_rigid`` in every band."""
    if "interval_scales" not in calibration:
        edges, scales = (), (float(calibration["interval_scale"]),)
    else:
        edges = tuple(float(v) for v in calibration["force_band_edges_n"])
        scales = tuple(float(v) for v in calibration["interval_scales"])
    p_rigids = calibration.get("p_rigids") or [calibration["p_rigid"]] * len(scales)
    return edges, tuple(float(v) for v in p_rigids), scales


def band_names(edges_n: tuple[float, ...]) -> list[str]:
    """Each force band of ``edges_n`` (N) in words: ``["below 10 N", "at 10-20 N", "from 20 N"]``."""
    if not edges_n:
        return ["at any force"]
    return [f"below {edges_n[0]:g} N", *(f"at {a:g}-{b:g} N" for a, b in itertools.pairwise(edges_n)),
            f"from {edges_n[-1]:g} N"]


def bands_text(calibration: Mapping[str, Any]) -> str:
    """A calibration's force bands in words: ``"below 10 N: lower bound from P(E >= limit) >= 0.98,
    interval -/+ 4.1 spreads; ..."``."""
    edges, p_rigids, scales = force_bands(calibration)
    return "; ".join(f"{where}: lower bound from P(E >= limit) >= {p:g}, interval -/+ {s:.3g} spreads"
                     for where, p, s in zip(band_names(edges), p_rigids, scales, strict=True))


def _session_options(threads: int) -> ort.SessionOptions:
    options = ort.SessionOptions()
    options.intra_op_num_threads = threads
    options.inter_op_num_threads = 1
    options.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
    options.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
    return options


class CompliancePredictor:
    """A trained model loaded for inference (onnxruntime, CPU).

    Parameters
    ----------
    model_dir : path
        Holds ``model.onnx`` and ``metadata.json``.
    threads : int
        onnxruntime intra-op threads (1: one core, as the latency figures are taken).

    Attributes
    ----------
    model_id : str
        :func:`model_id` of the bytes it loaded (each file is read once).

    Raises
    ------
    ModelError
        A file is missing (named) or unreadable, the metadata is malformed or was
        made with other input scales, or the ONNX inputs do not match it.
    """

    def __init__(self, model_dir: str | Path, *, threads: int = 1):
        self.model_dir = Path(model_dir)
        meta_path, onnx_path = self.model_dir / "metadata.json", self.model_dir / "model.onnx"
        files = model_files(self.model_dir)
        contents = []
        for path in files:
            try:
                contents.append((path.name, path.read_bytes()))
            except OSError as exc:
                raise ModelError(f"{path}: not a readable model file ({exc.strerror or exc})") from exc
        self.model_id = _digest_id(self.model_dir, contents)
        blobs = dict(contents)
        try:
            data = json.loads(blobs["metadata.json"])
        except (UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise ModelError(f"{meta_path}: not a readable model metadata file ({exc})") from exc
        self.metadata = ModelMetadata.from_json(data, str(meta_path))
        if threads < 1:
            raise ModelError(f"threads {threads}: expected at least 1")
        try:
            # From the bytes read above, not the path: the session runs the model the id names.
            self.session = ort.InferenceSession(blobs["model.onnx"], sess_options=_session_options(threads),
                                                providers=["CPUExecutionProvider"])
        except Exception as exc:  # onnxruntime raises its own untyped errors
            raise ModelError(f"{onnx_path}: onnxruntime cannot load it ({exc})") from exc
        found = {i.name: [d if isinstance(d, int) else None for d in i.shape] for i in self.session.get_inputs()}
        expected = dict(self.metadata.raw["inputs"])
        if found != expected:
            raise ModelError(f"{onnx_path}: inputs {found} differ from its metadata {expected}")
        outputs = [o.name for o in self.session.get_outputs()]
        if outputs != [OUTPUT_NAME]:
            raise ModelError(f"{onnx_path}: outputs {outputs}, expected [{OUTPUT_NAME!r}]")
        if not self.measurement_code_matches:
            log.warning("model %s was trained on inputs measured by other code than this (measurement "
                        "fingerprint differs): its estimates may be off; retrain it", self.model_dir)

    @property
    def variant(self) -> Variant:
        return self.metadata.variant

    @property
    def depth_binning(self) -> int:
        """The depth binning its training inputs were measured with (1 for models from before the setting)."""
        return int((self.metadata.raw.get("data") or {}).get("depth_binning") or 1)

    @property
    def measurement_code_matches(self) -> bool:
        """Whether this code measures grasps as the code that built the model's training data did
        (the same :data:`~estimator.inference.inputs.MEASUREMENT_VERSION`)."""
        data = self.metadata.raw.get("data") or {}
        return data.get("measurement_version") == MEASUREMENT_VERSION

    @property
    def rig_range(self) -> dict[str, list[float]]:
        """[least, most] of each rig quantity it was trained on (``data.rig_range``; empty for a model
        from before the key or trained on samples that do not record their rig)."""
        return dict((self.metadata.raw.get("data") or {}).get("rig_range") or {})

    @property
    def calibration_smoothing_px(self) -> tuple[float, ...]:
        """The colour smoothings (px) of the calibrations whose depth it was trained on
        (:func:`~estimator.inference.inputs.calibration_smoothings` of ``data``)."""
        return calibration_smoothings(self.metadata.raw.get("data") or {})

    @property
    def interval_level(self) -> float:
        """The coverage its ``ok`` intervals state (calibrated on the validation objects)."""
        return self.metadata.interval_level

    def predict_logits(self, batch: Mapping[str, np.ndarray]) -> np.ndarray:
        """Model output (B, N_BINS): logits over the log10 E bins, for encoded inputs
        (:func:`~estimator.inference.inputs.encode`).

        Raises
        ------
        ModelError
            An input is missing, of the wrong shape, or the output is not finite.
        """
        shapes = self.variant.input_shapes
        if set(batch) != set(shapes):
            raise ModelError(f"model inputs {sorted(batch)}: expected {sorted(shapes)}")
        feed = {}
        for name, shape in shapes.items():
            array = np.asarray(batch[name], dtype=np.float32)
            if array.ndim != len(shape) + 1 or array.shape[1:] != shape:
                raise ModelError(f"model input {name!r}: expected (B, {', '.join(map(str, shape))}), got {array.shape}")
            feed[name] = array
        out = self.session.run([OUTPUT_NAME], feed)[0]
        if out.shape != (feed["frames"].shape[0], distribution.N_BINS) or not np.all(np.isfinite(out)):
            raise ModelError(f"model {self.model_dir}: output {out.shape} is not finite logits over "
                             f"{distribution.N_BINS} bins")
        return out

    def predict_distribution(self, items: Sequence[ModelInputs]) -> np.ndarray:
        """Calibrated bin probabilities (B, N_BINS) per item: encode, run, floor at the analytical lower
        bounds (a model calibrated with that floor), temperature-scale."""
        logits = self.predict_logits(encode(self.variant, items))
        weights = None
        if self.metadata.floor_methods:
            floors = [self.floor(item)[0] for item in items]
            weights = floor_log_weights(np.array(floors), leak=self.metadata.floor_leak)
        return probabilities(logits, temperature=self.metadata.temperature, log_weights=weights)

    def floor(self, item: ModelInputs) -> tuple[float, str | None]:
        """The item's analytical floor on the reference gel, log10 Pa, and the method that sets it
        (``(-inf, None)`` for none, or a model calibrated without a floor)."""
        return inputs.analytical_floor(item.estimates, methods=self.metadata.floor_methods,
                                       scale=inputs.gel_scale(item.gel_modulus_pa))

    def describe(self, probs: np.ndarray, *, limit_pa: float, peak_force_n: float, widen: float = 1.0,
                 gel_scale: float = 1.0) -> Described:
        """State, value and calibrated interval of one item's distribution, bounded above at the
        sensor's resolution limit ``limit_pa`` (:func:`~estimator.inference.distribution.describe_on_gel`,
        as calibration scores it), its interval scale and ``p_rigid`` those of the force band of the
        grasp's peak force ``peak_force_n`` (N).
        ``widen`` (>= 1) multiplies the calibrated interval scale (a grasp outside the training
        range: :func:`~estimator.inference.window.input_range`); bounds and the value are not moved by it.
        ``gel_scale`` is the item's :func:`~estimator.inference.inputs.gel_scale`: the distribution
        is over moduli on the reference gel, the answer in the measuring gel's."""
        if not (math.isfinite(widen) and widen >= 1.0):
            raise ModelError(f"widen {widen!r}: expected a finite factor >= 1")
        if not (math.isfinite(gel_scale) and gel_scale > 0):
            raise ModelError(f"gel_scale {gel_scale!r}: expected a finite factor > 0")
        if not math.isfinite(peak_force_n):
            raise ModelError(f"peak_force_n {peak_force_n!r}: expected a finite force (N)")
        return describe_on_gel(probs, scale=self.metadata.interval_scale_at(peak_force_n), limit_pa=limit_pa,
                               soft_pa=self.metadata.soft_pa, p_rigid=self.metadata.p_rigid_at(peak_force_n),
                               gel_scale=gel_scale, widen=widen)


def load_predictor(model_dir: str | Path | None = None, *, settings: Settings | None = None,
                   threads: int = 1) -> CompliancePredictor:
    """The model in ``model_dir``; else ``estimator_settings(settings).model_path``; else the shipped default.

    ``model_path`` names the model directory or its ``model.onnx``; a relative path is
    under ``configs/``, like calibration files.
    """
    if model_dir is None and settings is not None and estimator_settings(settings).model_path:
        path = resolve_path(estimator_settings(settings).model_path)
        model_dir = path.parent if path.suffix == ".onnx" else path
    return CompliancePredictor(default_model_dir() if model_dir is None else model_dir, threads=threads)
