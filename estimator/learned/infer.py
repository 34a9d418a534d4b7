"""Run a trained model with onnxruntime; never imports torch.

A model directory holds ``model.onnx`` and ``metadata.json`` (written by
``estimator train``):

``format``, ``version``
    ``"compliance-teleop.model"``, 1.
``variant``
    ``{"name", "n_frames", "size_px"}``: the inputs it reads (:class:`~estimator.learned.inputs.Variant`).
``inputs``
    Input name -> shape with ``null`` for the batch axis; ``output``: the output's name.
``scales``
    The input and output scales it was trained with (checked against this code's).
``residual_log10``
    Quantiles of ``log10 E_hat - log10 E`` on the validation objects (``q025``,
    ``q975``, ``median_abs``, ``n``): the run-time interval.
``metrics``, ``training``, ``data``
    What it scored on val and test objects, how and on what it was trained;
    ``data.measurement_fingerprint`` identifies the measurement code that made
    its inputs (:func:`~estimator.learned.inputs.measurement_fingerprint`), and
    ``data.depth_binning`` the depth grid they were measured on
    (:attr:`~teleop.settings.EstimatorSettings.depth_binning`; 1 when absent).
"""

from __future__ import annotations

import json
import logging
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import onnxruntime as ort

from estimator.errors import ModelError
from estimator.learned import inputs
from estimator.learned.inputs import (
    ModelInputs,
    Variant,
    encode,
    measurement_fingerprint,
    modulus_from_normalised,
)
from teleop.settings import CONFIG_DIR, Settings

__all__ = [
    "MODEL_FORMAT",
    "CompliancePredictor",
    "ModelMetadata",
    "current_scales",
    "default_model_dir",
    "load_predictor",
]

log = logging.getLogger(__name__)

MODEL_FORMAT = "compliance-teleop.model"
MODEL_VERSION = 1
OUTPUT_NAME = "e_norm"


def default_model_dir() -> Path:
    """The shipped default model (``estimator/models/default``)."""
    return Path(__file__).resolve().parent.parent / "models" / "default"


def current_scales() -> dict[str, Any]:
    """The input and output scales of this code (a model must have been trained with them)."""
    return {
        "log10_e_range": list(inputs.LOG10_E_RANGE),
        "force_scale_n": inputs.FORCE_SCALE_N,
        "width_scale_m": inputs.WIDTH_SCALE_M,
        "depth_scale_m": inputs.DEPTH_SCALE_M,
        "rgb_scale": inputs.RGB_SCALE,
        "analytical_methods": list(inputs.ANALYTICAL_METHODS),
        "features_per_method": inputs.FEATURES_PER_METHOD,
    }


@dataclass(frozen=True)
class ModelMetadata:
    """The checked content of a model's ``metadata.json`` (module notes)."""

    variant: Variant
    residual_q025: float
    residual_q975: float
    raw: Mapping[str, Any]

    @classmethod
    def from_json(cls, data: Any, source: str) -> ModelMetadata:
        """Check ``data`` (parsed JSON) and build the metadata; ModelError names ``source``."""
        if not isinstance(data, dict) or data.get("format") != MODEL_FORMAT:
            raise ModelError(f"{source}: not a {MODEL_FORMAT} metadata file")
        if data.get("version") != MODEL_VERSION:
            raise ModelError(f"{source}: metadata version {data.get('version')!r}, this software reads {MODEL_VERSION}")
        try:
            spec = data["variant"]
            variant = Variant.parse(spec["name"], n_frames=int(spec["n_frames"]),
                                    size_px=tuple(int(v) for v in spec["size_px"]))
            residual = data["residual_log10"]
            q025, q975 = float(residual["q025"]), float(residual["q975"])
        except (KeyError, TypeError, ValueError) as exc:
            raise ModelError(f"{source}: missing or malformed field ({exc!r})") from exc
        if not (math.isfinite(q025) and math.isfinite(q975) and q025 <= q975):
            raise ModelError(f"{source}: residual_log10 q025 {q025} and q975 {q975} must be finite, q025 <= q975")
        if data.get("scales") != current_scales():
            raise ModelError(f"{source}: trained with input scales {data.get('scales')}, this code uses "
                             f"{current_scales()}; retrain the model")
        expected = {name: [None, *shape] for name, shape in variant.input_shapes.items()}
        if data.get("inputs") != expected:
            raise ModelError(f"{source}: inputs {data.get('inputs')} do not match variant {variant.name} ({expected})")
        return cls(variant=variant, residual_q025=q025, residual_q975=q975, raw=data)


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

    Raises
    ------
    ModelError
        A file is missing or unreadable, the metadata is malformed or was
        made with other input scales, or the ONNX inputs do not match it.
    """

    def __init__(self, model_dir: str | Path, *, threads: int = 1):
        self.model_dir = Path(model_dir)
        meta_path, onnx_path = self.model_dir / "metadata.json", self.model_dir / "model.onnx"
        try:
            data = json.loads(meta_path.read_text())
        except (OSError, json.JSONDecodeError) as exc:
            raise ModelError(f"{meta_path}: not a readable model metadata file ({exc})") from exc
        self.metadata = ModelMetadata.from_json(data, str(meta_path))
        if threads < 1:
            raise ModelError(f"threads {threads}: expected at least 1")
        try:
            self.session = ort.InferenceSession(str(onnx_path), sess_options=_session_options(threads),
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
        """Whether this code measures grasps as the code that built the model's training data."""
        data = self.metadata.raw.get("data") or {}
        return data.get("measurement_fingerprint") == measurement_fingerprint()

    def predict_normalised(self, batch: Mapping[str, np.ndarray]) -> np.ndarray:
        """Model output (B,) on the [0, 1] scale for encoded inputs (:func:`~estimator.learned.inputs.encode`).

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
        out = self.session.run([OUTPUT_NAME], feed)[0].reshape(-1)
        if not np.all(np.isfinite(out)):
            raise ModelError(f"model {self.model_dir}: output is not finite")
        return out

    def predict(self, items: Sequence[ModelInputs]) -> np.ndarray:
        """Modulus (Pa) per item: encode, run, and map back from the [0, 1] scale."""
        return modulus_from_normalised(self.predict_normalised(encode(self.variant, items)))

    def interval(self, e_pa: float) -> tuple[float, float]:
        """The ~95 % interval of an estimate from the validation residuals (Pa), widened to hold it."""
        low = e_pa * 10.0 ** -self.metadata.residual_q975
        high = e_pa * 10.0 ** -self.metadata.residual_q025
        return min(low, e_pa), max(high, e_pa)


def load_predictor(model_dir: str | Path | None = None, *, settings: Settings | None = None,
                   threads: int = 1) -> CompliancePredictor:
    """The model in ``model_dir``; else ``settings.estimator.model_path``; else the shipped default.

    ``model_path`` names the model directory or its ``model.onnx``; a relative path is
    under ``configs/``, like calibration files.
    """
    if model_dir is None and settings is not None and settings.estimator.model_path:
        path = Path(settings.estimator.model_path)
        path = path if path.is_absolute() else CONFIG_DIR / path
        model_dir = path.parent if path.suffix == ".onnx" else path
    return CompliancePredictor(default_model_dir() if model_dir is None else model_dir, threads=threads)
