"""Export a trained :class:`~estimator.training.model.ComplianceNet` to ONNX and back (torch; training only).

The graph is exported with the ``torch.export``-based exporter (``dynamo=True``,
onnxscript) at opset 18, the batch axis dynamic, and checked against torch in
onnxruntime before it is kept. :func:`network_from_onnx` rebuilds the network
from such a file's weights (to fine-tune a shipped model, which ships as ONNX
only): the exporter names the initialisers after the parameters and folds each
batch norm into the convolution before it, so the rebuilt batch norms are
identities that carry the folded bias.
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
from torch import nn

from estimator.errors import ModelError
from estimator.inference.infer import OUTPUT_NAME
from estimator.inference.inputs import Variant
from estimator.training.model import ComplianceNet

__all__ = ["OPSET", "check_rebuilt", "export_onnx", "load_exported_weights", "max_disagreement", "network_from_onnx",
           "onnx_weights"]

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
    OSError
        ``path`` cannot be written (a full or read-only disk).
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
    except OSError:
        raise  # writing failed (a full or read-only disk), not the export: the caller names the folder
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


def onnx_weights(path: str | Path) -> dict[str, np.ndarray]:
    """The initialisers of an ONNX file by name; ModelError when it is unreadable."""
    import onnx
    from onnx import numpy_helper

    try:
        return {i.name: numpy_helper.to_array(i) for i in onnx.load(str(path)).graph.initializer}
    except Exception as exc:  # onnx raises protobuf and OS errors alike
        raise ModelError(f"{path}: not a readable ONNX file ({exc})") from exc


def load_exported_weights(model: ComplianceNet, weights: Mapping[str, np.ndarray], *, prefix: str = "",
                          source: str) -> ComplianceNet:
    """Load into ``model`` the weights :func:`export_onnx` wrote for it (named ``prefix`` + its parameter
    names; batch norms folded into the convolutions before them, so they become identities carrying the
    folded bias). ModelError names ``source`` when a weight is missing or of another shape."""
    variant = model.variant
    state = model.state_dict()
    batch_norms = tuple(f"{name}." for name, module in model.named_modules() if isinstance(module, nn.BatchNorm2d))
    for name, value in model.named_parameters():
        if name.startswith(batch_norms):
            continue
        found = weights.get(prefix + name)
        if found is None or found.shape != tuple(value.shape):
            raise ModelError(f"{source}: {prefix}{name} of variant {variant.name} should be {tuple(value.shape)}, "
                             f"the file has {'none' if found is None else found.shape}: another variant's model?")
        state[name] = torch.from_numpy(found.copy())
    for name, module in model.named_modules():
        if isinstance(module, nn.BatchNorm2d):
            conv = prefix + name.rsplit(".", 1)[0] + ".0.weight"  # the Conv2d before it in the same Sequential
            folded = weights.get(conv + "_bias")
            if folded is None:
                raise ModelError(f"{source}: no folded batch-norm bias {conv}_bias for {prefix}{name}")
            state[f"{name}.weight"] = torch.ones_like(state[f"{name}.weight"])
            state[f"{name}.bias"] = torch.from_numpy(folded.copy())
            state[f"{name}.running_mean"] = torch.zeros_like(state[f"{name}.running_mean"])
            state[f"{name}.running_var"] = torch.full_like(state[f"{name}.running_var"], 1.0 - module.eps)
    model.load_state_dict(state)
    return model


def check_rebuilt(model: nn.Module, path: str | Path, check: Mapping[str, np.ndarray]) -> nn.Module:
    """``model`` in eval mode, once it agrees with the ONNX file at ``path`` within 1e-4 on ``check``."""
    worst = max_disagreement(model, path, check)
    if not worst <= AGREEMENT_ATOL:
        raise ModelError(f"{path}: the network rebuilt from its weights differs from onnxruntime by {worst:.3g} "
                         f"(> {AGREEMENT_ATOL}); was it exported by this code?")
    return model.eval()


def network_from_onnx(path: str | Path, variant: Variant, *, check: Mapping[str, np.ndarray]) -> ComplianceNet:
    """The network ``path`` (written by :func:`export_onnx`) computes, rebuilt in torch (eval mode).

    Parameters
    ----------
    path : path
        The ``.onnx`` file.
    variant : Variant
        Its variant (from its ``metadata.json``).
    check : mapping
        Encoded inputs (at least 2 in the batch): the rebuilt network must agree with
        onnxruntime within 1e-4 on them.

    Raises
    ------
    ModelError
        The file is unreadable, lacks a parameter of the variant's network, or the
        rebuilt network disagrees with it.
    """
    model = load_exported_weights(ComplianceNet(variant), onnx_weights(path), source=str(path))
    return check_rebuilt(model, path, check)
