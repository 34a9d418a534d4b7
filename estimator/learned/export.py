"""Export a trained :class:`~estimator.learned.model.ComplianceNet` to ONNX (torch; training only).

The graph is exported with the ``torch.export``-based exporter (``dynamo=True``,
onnxscript) at opset 18, the batch axis dynamic, and checked against torch in
onnxruntime before it is kept.
"""

from __future__ import annotations

import contextlib
import io
import logging
import warnings
from collections.abc import Mapping
from pathlib import Path

import numpy as np
import torch

from estimator.errors import ModelError
from estimator.learned.infer import OUTPUT_NAME
from estimator.learned.model import ComplianceNet

__all__ = ["OPSET", "export_onnx", "max_disagreement"]

OPSET = 18
AGREEMENT_ATOL = 1e-4


def export_onnx(model: ComplianceNet, path: str | Path, *, example: Mapping[str, np.ndarray]) -> Path:
    """Write ``model`` (in eval mode) to ``path`` as ONNX and check onnxruntime agrees with torch.

    Parameters
    ----------
    model : ComplianceNet
    path : path
        The ``.onnx`` file to write.
    example : mapping
        Encoded inputs (at least 2 in the batch) used to trace the graph and to
        check it: torch and onnxruntime must agree within 1e-4 on the output.

    Raises
    ------
    ModelError
        The export fails or the exported graph disagrees with torch.
    """
    path = Path(path)
    model = model.eval()
    names = list(model.variant.input_shapes)
    args = tuple(torch.from_numpy(np.asarray(example[n], dtype=np.float32)) for n in names)
    batch = torch.export.Dim("batch", min=1, max=4096)
    # The exporter narrates on stdout and warns through logging; keep both off the command's output.
    logging.getLogger("torch.onnx").setLevel(logging.ERROR)
    try:
        with contextlib.redirect_stdout(io.StringIO()), warnings.catch_warnings():
            warnings.simplefilter("ignore", (UserWarning, FutureWarning, DeprecationWarning))
            program = torch.onnx.export(
                model, args, input_names=names, output_names=[OUTPUT_NAME], opset_version=OPSET, dynamo=True,
                dynamic_shapes=(tuple({0: batch} for _ in names),), verbose=False,
            )
            program.save(str(path))
    except Exception as exc:  # the exporter raises many unrelated types
        raise ModelError(f"ONNX export of variant {model.variant.name} failed: {exc}") from exc
    worst = max_disagreement(model, path, example)
    if not worst <= AGREEMENT_ATOL:
        raise ModelError(f"{path}: onnxruntime and torch differ by {worst:.3g} (> {AGREEMENT_ATOL}) on the output")
    return path


def max_disagreement(model: ComplianceNet, path: str | Path, batch: Mapping[str, np.ndarray]) -> float:
    """Largest |torch - onnxruntime| on the normalised output for ``batch``."""
    import onnxruntime as ort

    names = list(model.variant.input_shapes)
    feed = {n: np.asarray(batch[n], dtype=np.float32) for n in names}
    with torch.no_grad():
        expected = model.eval()(*(torch.from_numpy(feed[n]) for n in names)).numpy().reshape(-1)
    session = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    got = session.run([OUTPUT_NAME], feed)[0].reshape(-1)
    return float(np.max(np.abs(got - expected)))
