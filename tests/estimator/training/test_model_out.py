"""The model commands' --out: a model already there is never replaced unasked, a bad --out is refused
before any training, and the training bar's best epoch is the one the metadata keeps."""

from __future__ import annotations

import json

import pytest

from estimator.cli import main
from estimator.errors import EstimatorError
from estimator.inference.inputs import Variant
from estimator.training import train as train_module
from estimator.training.outdir import check_out_dir
from estimator.training.recipe import TrainConfig
from estimator.training.splits import load_split_data


def _earlier_model(folder):
    """A folder holding an earlier model's files (and a record that is not one)."""
    folder.mkdir()
    for name in ("model.onnx", "metadata.json", "training_curve.png", "kept.grasp"):
        (folder / name).write_bytes(b"earlier " + name.encode())
    return {p.name: p.read_bytes() for p in folder.iterdir()}


def test_the_check_takes_a_new_or_empty_folder_and_refuses_the_rest_creating_nothing(tmp_path):
    check_out_dir(tmp_path / "new" / "model", overwrite=False)
    (tmp_path / "empty").mkdir()
    check_out_dir(tmp_path / "empty", overwrite=False)
    _earlier_model(tmp_path / "full")
    with pytest.raises(EstimatorError, match=r"--out .*full: not empty \(holds kept.grasp, metadata.json, "
                                             r"model.onnx, \.\.\.\).*--overwrite"):
        check_out_dir(tmp_path / "full", overwrite=False)
    check_out_dir(tmp_path / "full", overwrite=True)
    (tmp_path / "file").write_text("x")
    for out in (tmp_path / "file", tmp_path / "file" / "model"):
        with pytest.raises(EstimatorError, match=r"--out .*: .*file is a file; expected a folder"):
            check_out_dir(out, overwrite=True)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["empty", "file", "full"]


# fine-tune --check would fine-tune once per object before the model is written: refused before it too.
@pytest.mark.parametrize("command", [["fine-tune", "--check", "--model"], ["train", "--init"]])
def test_fine_tuning_into_a_model_or_a_file_is_refused_before_any_training(command, trained_model, synthetic,
                                                                          tmp_path, capsys):
    data = synthetic.write_dataset(tmp_path / "d", seed=5)
    before = _earlier_model(tmp_path / "m")
    (tmp_path / "file").write_text("x")
    for out, why in ((tmp_path / "file", "is a file"), (tmp_path / "m", "not empty")):
        assert main([*command, str(trained_model), "--data", str(data), "--out", str(out)]) == 2
        err = capsys.readouterr().err
        assert f"--out {out}:" in err and why in err and "Traceback" not in err and "leaving one" not in err
    assert {p.name: p.read_bytes() for p in (tmp_path / "m").iterdir()} == before


def test_training_into_a_model_or_a_file_is_refused_before_any_training(synthetic_dataset, tmp_path, capsys):
    before = _earlier_model(tmp_path / "m")
    (tmp_path / "file").write_text("x")
    for out, why in ((tmp_path / "file", "is a file"), (tmp_path / "m", "pass --overwrite")):
        assert main(["train", "--data", str(synthetic_dataset), "--out", str(out), "--variant", "depth"]) == 2
        err = capsys.readouterr().err
        assert f"--out {out}:" in err and why in err and "Traceback" not in err
    assert {p.name: p.read_bytes() for p in (tmp_path / "m").iterdir()} == before


def test_pooling_into_a_model_is_refused_before_reading_the_members(tmp_path, capsys):
    before = _earlier_model(tmp_path / "m")
    assert main(["pool", "--model", str(tmp_path / "a"), "--model", str(tmp_path / "b"), "--data", str(tmp_path),
                 "--out", str(tmp_path / "m")]) == 2
    assert f"--out {tmp_path / 'm'}: not empty" in capsys.readouterr().err
    assert {p.name: p.read_bytes() for p in (tmp_path / "m").iterdir()} == before


def test_recalibrating_into_another_model_needs_overwrite_which_drops_its_stale_curve(trained_model, synthetic_dataset,
                                                                                     tmp_path, capsys):
    out = tmp_path / "m"
    before = _earlier_model(out)
    args = ["recalibrate", "--model", str(trained_model), "--data", str(synthetic_dataset), "--out", str(out)]
    assert main(args) == 2
    assert f"--out {out}: not empty" in capsys.readouterr().err
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before
    assert main([*args, "--overwrite"]) == 0
    assert {p.name for p in out.iterdir()} == {"model.onnx", "metadata.json", "kept.grasp"}  # curve: another net's
    assert (out / "model.onnx").read_bytes() == (trained_model / "model.onnx").read_bytes()
    assert json.loads((out / "metadata.json").read_text())["recalibrated"]["data"] == str(synthetic_dataset)
    assert main(["recalibrate", "--model", str(trained_model), "--data", str(synthetic_dataset), "--overwrite"]) == 2
    assert "--overwrite: replaces a model in --out" in capsys.readouterr().err


def test_the_bar_shows_the_best_epoch_so_far_as_the_metadata_counts_it(synthetic_dataset, tmp_path, monkeypatch):
    shown = []

    class Bar:
        def __init__(self, iterable, **_):
            self.iterable = iterable

        def __iter__(self):
            return iter(self.iterable)

        def set_postfix(self, **fields):
            shown.append(fields["best"])

    monkeypatch.setattr(train_module, "progress_bar", Bar)
    variant = Variant.parse("depth", n_frames=3, size_px=(16, 22))
    data = load_split_data(synthetic_dataset, variant, ("train", "val"))
    fitted = train_module._fit(data["train"], data["val"].live(), variant,
                               TrainConfig(epochs=2, patience=2, batch_size=16, seed=0), progress=False)
    losses = [h["val_loss"] for h in fitted.history]
    assert shown == [1 + losses[:epoch].index(min(losses[:epoch])) for epoch in range(1, len(losses) + 1)]
    assert shown[-1] == fitted.best_epoch  # the metadata's best_epoch


@pytest.mark.slow
def test_fine_tuning_with_overwrite_replaces_the_model_and_drops_its_stale_curve(trained_model, synthetic, tmp_path):
    data = synthetic.write_dataset(tmp_path / "d", seed=5)
    out = tmp_path / "m"
    _earlier_model(out)
    assert main(["fine-tune", "--model", str(trained_model), "--data", str(data), "--out", str(out), "--epochs", "1",
                 "--batch-size", "64", "--overwrite", "--json"]) == 0
    assert {p.name for p in out.iterdir()} == {"model.onnx", "metadata.json", "kept.grasp"}
    assert json.loads((out / "metadata.json").read_text())["fine_tuning"]["base"] == str(trained_model)
