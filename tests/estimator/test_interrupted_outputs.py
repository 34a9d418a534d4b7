"""An interrupted write (Ctrl-C: KeyboardInterrupt) leaves the earlier output intact and no temporary."""

from __future__ import annotations

import zipfile

import numpy as np
import pytest

from estimator.errors import CalibrationError
from estimator.inference.inputs import Variant
from estimator.perception.calibration import load_calibration
from estimator.perception.presses import load_presses
from estimator.training.recipe import TrainConfig
from teleop.sim.presses import write_presses

OLD = {"model.onnx": b"old network", "metadata.json": b'{"old": true}', "training_curve.png": b"old curve"}


def _old_model(folder):
    folder.mkdir(parents=True, exist_ok=True)
    for name, content in OLD.items():
        (folder / name).write_bytes(content)
    return folder


def _assert_old_model(folder):
    assert {p.name: p.read_bytes() for p in folder.iterdir()} == OLD  # no .partial left either


def _interrupt_writing(path, *args, **kwargs):
    with open(path, "wb") as fh:
        fh.write(b"half")
    raise KeyboardInterrupt


@pytest.mark.slow
@pytest.mark.train
def test_interrupted_train_overwrite_keeps_the_earlier_model(synthetic_dataset, tmp_path, monkeypatch):
    import estimator.training.train as train

    out = _old_model(tmp_path / "m")
    monkeypatch.setattr(train, "_plot", lambda fitted, path: _interrupt_writing(path))  # the last file written
    with pytest.raises(KeyboardInterrupt):
        train.train_model(synthetic_dataset, out, variant=Variant.parse("depth", n_frames=3, size_px=(16, 22)),
                          config=TrainConfig(epochs=1, batch_size=16, seed=0), progress=False, overwrite=True)
    _assert_old_model(out)


@pytest.mark.slow
def test_interrupted_fine_tune_overwrite_keeps_the_earlier_model(trained_model, synthetic_dataset, tmp_path,
                                                                 monkeypatch):
    import estimator.training.finetune as finetune

    out = _old_model(tmp_path / "tuned")
    monkeypatch.setattr(finetune, "export_onnx", lambda model, path, example: _interrupt_writing(path))
    with pytest.raises(KeyboardInterrupt):
        finetune.fine_tune(trained_model, synthetic_dataset, out, config=TrainConfig(epochs=1, batch_size=8, seed=0),
                           progress=False, overwrite=True)
    _assert_old_model(out)


def _interrupting_savez(fh, **members):
    fh.write(b"PK\x03\x04 half an archive")
    raise KeyboardInterrupt


def test_interrupted_calibration_save_keeps_the_earlier_calibration(calibration, tmp_path, monkeypatch):
    path = calibration.save(tmp_path / "cal.npz")
    before = path.read_bytes()
    monkeypatch.setattr(np, "savez_compressed", _interrupting_savez)
    with pytest.raises(KeyboardInterrupt):
        calibration.save(path)
    monkeypatch.undo()
    assert path.read_bytes() == before and [p.name for p in tmp_path.iterdir()] == ["cal.npz"]
    assert load_calibration(path).image_shape == calibration.image_shape


def _pack(n=2):
    rng = np.random.default_rng(0)
    return {"f0": rng.integers(0, 255, (8, 10, 3), dtype=np.uint8),
            "imgs": rng.integers(0, 255, (n, 8, 10, 3), dtype=np.uint8),
            "touch_center": np.full((n, 2), 4.0), "touch_radius": np.full(n, 2.0)}


def test_interrupted_write_presses_keeps_the_earlier_file(tmp_path, monkeypatch):
    path = write_presses(tmp_path / "pr.npz", _pack())
    before = path.read_bytes()
    monkeypatch.setattr(np, "savez_compressed", _interrupting_savez)
    with pytest.raises(KeyboardInterrupt):
        write_presses(path, _pack(3))
    monkeypatch.undo()
    assert path.read_bytes() == before and [p.name for p in tmp_path.iterdir()] == ["pr.npz"]
    assert len(load_presses(path)) == 2


def test_damaged_presses_are_a_calibration_error_naming_the_file(tmp_path):
    path = write_presses(tmp_path / "pr.npz", _pack())
    with zipfile.ZipFile(path) as archive:
        info = archive.getinfo("imgs.npy")
    data = bytearray(path.read_bytes())
    start = info.header_offset + 30 + len(info.filename) + len(info.extra)
    for i in range(start + 4, start + min(info.compress_size, 64)):
        data[i] ^= 0x5A  # damage the deflated stream: zlib fails on it
    path.write_bytes(bytes(data))
    with pytest.raises(CalibrationError, match="pr.npz"):
        load_presses(path)
