"""A model command whose disk fills or is read-only: one error naming the folder and the reason,
not a traceback nor an "export failed"; the earlier model there whole and no temporary left."""

from __future__ import annotations

import errno
import os
import pathlib
import shutil
from types import SimpleNamespace

import numpy as np
import pytest

from estimator.cli import main
from estimator.errors import EstimatorError, ModelError
from estimator.inference.inputs import Variant
from estimator.training import export as export_module
from estimator.training import train as train_module
from estimator.training.model import ComplianceNet
from estimator.training.recipe import TrainConfig

NO_SPACE = os.strerror(errno.ENOSPC)
READ_ONLY = os.strerror(errno.EROFS)
VARIANT = Variant.parse("depth", n_frames=3, size_px=(16, 22))


def _fail(code):
    def write(*args, **kwargs):
        raise OSError(code, os.strerror(code))
    return write


def _earlier_model(folder):
    folder.mkdir()
    files = {"model.onnx": b"earlier network", "metadata.json": b"{}", "training_curve.png": b"earlier curve"}
    for name, content in files.items():
        (folder / name).write_bytes(content)
    return files


def _held(folder):
    return {p.name: p.read_bytes() for p in folder.iterdir()}


@pytest.fixture
def untrained(monkeypatch):
    """train_model with no training: the writes are what these tests are about."""
    history = [{"epoch": 1, "train_loss": 1.0, "val_loss": 1.0, "train_log10_error": 1.0, "val_log10_error": 1.0}]
    monkeypatch.setattr(train_module, "_fit", lambda train, val, variant, config, progress:
                        train_module.Fitted(ComplianceNet(variant).eval(), history, 1, 1.0))
    monkeypatch.setattr(train_module, "export_onnx", lambda model, path, example: path.write_bytes(b"new network"))


@pytest.mark.parametrize("failing", ["export_onnx", "_plot"])
def test_a_full_disk_while_training_names_the_folder_and_keeps_the_earlier_model(
        failing, untrained, synthetic_dataset, tmp_path, monkeypatch):
    out = tmp_path / "model"
    earlier = _earlier_model(out)
    monkeypatch.setattr(train_module, failing, _fail(errno.ENOSPC))
    with pytest.raises(EstimatorError) as raised:
        train_module.train_model(synthetic_dataset, out, variant=VARIANT, config=TrainConfig(epochs=1),
                                 progress=False, overwrite=True)
    assert str(raised.value).startswith(f"cannot write the model into {out}: {NO_SPACE}; the earlier model "
                                        "there is kept")
    assert _held(out) == earlier  # and no .partial left


def test_a_read_only_folder_is_the_error_not_the_cleanup_of_a_temporary_never_written(
        untrained, synthetic_dataset, tmp_path, monkeypatch):
    out = tmp_path / "model"
    earlier = _earlier_model(out)
    monkeypatch.setattr(train_module, "export_onnx", _fail(errno.EROFS))
    # A read-only file system refuses even a missing file's unlink.
    monkeypatch.setattr(pathlib.Path, "unlink", _fail(errno.EROFS))
    with pytest.raises(EstimatorError, match=f"cannot write the model into {out}: {READ_ONLY};"):
        train_module.train_model(synthetic_dataset, out, variant=VARIANT, config=TrainConfig(epochs=1),
                                 progress=False, overwrite=True)
    assert _held(out) == earlier


def _zeros():
    return {n: np.zeros((2, *s), np.float32) for n, s in VARIANT.input_shapes.items()}


def _fake_exporter(monkeypatch, program):
    monkeypatch.setattr(export_module.torch.onnx, "export", lambda *args, **kwargs: program)


def test_export_onnx_passes_a_write_error_on_rather_than_blaming_the_export(tmp_path, monkeypatch):
    _fake_exporter(monkeypatch, SimpleNamespace(save=_fail(errno.ENOSPC)))
    with pytest.raises(OSError) as raised:
        export_module.export_onnx(ComplianceNet(VARIANT), tmp_path / "model.onnx", example=_zeros())
    assert raised.value.errno == errno.ENOSPC and not isinstance(raised.value, ModelError)


def test_export_onnx_still_reports_a_failing_export_as_one(tmp_path, monkeypatch):
    def broken(*args, **kwargs):
        raise RuntimeError("unsupported operator")

    monkeypatch.setattr(export_module.torch.onnx, "export", broken)
    with pytest.raises(ModelError, match="ONNX export of variant depth failed: unsupported operator"):
        export_module.export_onnx(ComplianceNet(VARIANT), tmp_path / "model.onnx", example=_zeros())


@pytest.mark.parametrize("elsewhere", [False, True])
def test_a_full_disk_while_recalibrating_names_the_folder_and_keeps_the_earlier_model(
        elsewhere, trained_model, synthetic_dataset, tmp_path, monkeypatch, capsys):
    model = shutil.copytree(trained_model, tmp_path / "model")
    out = tmp_path / "out" if elsewhere else model
    if elsewhere:
        _earlier_model(out)
    earlier = _held(out)
    monkeypatch.setattr(pathlib.Path, "write_text", _fail(errno.ENOSPC))
    argv = ["recalibrate", "--model", str(model), "--data", str(synthetic_dataset)]
    assert main(argv + (["--out", str(out), "--overwrite"] if elsewhere else [])) == 2
    assert f"cannot write the model into {out}: {NO_SPACE}; the earlier model there is kept" in capsys.readouterr().err
    assert _held(out) == earlier
