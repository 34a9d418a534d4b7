"""Training: early stopping, what a model directory holds, leaks and mismatches refused."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from estimator.errors import EstimatorError, SampleError
from estimator.inference.inputs import MEASUREMENT_VERSION, Variant, default_window_m
from estimator.inference.provenance import load_split
from estimator.training.recipe import TrainConfig
from estimator.training.splits import load_split_data, rig_range
from estimator.training.train import train_model


@pytest.mark.slow
def test_trained_model_directory(trained_model, synthetic_dataset, synthetic):
    assert {p.name for p in trained_model.iterdir()} >= {"model.onnx", "metadata.json", "training_curve.png"}
    assert (trained_model / "training_curve.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    meta = json.loads((trained_model / "metadata.json").read_text())
    assert meta["variant"] == {"name": "depth+fw+analytical", "n_frames": 3, "size_px": [16, 22],
                               "window_m": list(default_window_m()), "method": "hybrid"}
    assert meta["inputs"]["frames"] == [None, 3, 1, 16, 22]
    training = meta["training"]
    assert training["seed"] == 1 and 1 <= training["best_epoch"] <= training["epochs_run"] <= 4
    assert len(training["history"]) == training["epochs_run"]
    for split in ("val", "test"):
        metrics = meta["metrics"][split]
        assert metrics["hybrid"]["n"] > 0 and metrics["hybrid"]["interval_level"] == 0.9
        assert 0 <= metrics["hybrid"]["felt_log10_error"] <= 3.2  # the display spans 3.1 decades
        assert metrics["series"]["n"] > 0 and "no_tactile" in metrics  # the analytical methods on the same grasps
    cal = meta["calibration"]
    live_val = len(list((synthetic_dataset / "val").rglob("*_a0.npz")))  # scored on the live sampling only
    assert cal["n"] == live_val < meta["data"]["samples"]["val"] and cal["chosen_on"] == "val"
    assert cal["temperature"] > 0 and min(cal["interval_scales"]) > 0 and all(0.5 <= p < 1 for p in cal["p_rigids"])
    assert len(cal["interval_scales"]) == len(cal["p_rigids"]) == len(cal["force_band_edges_n"]) + 1
    assert cal["floor"] == {"methods": ["no_tactile", "series"], "leak": 0.01}  # the fixture reads the fits
    train_objects = json.loads((synthetic_dataset / "split.json").read_text())["train"]
    assert cal["level"] == 0.9 and cal["soft_pa"] == min(synthetic.OBJECTS[n][1] for n in train_objects)
    assert meta["data"]["measurement_version"] == MEASUREMENT_VERSION
    assert set(meta["reference"]["inputs"]) == {"frames_sum", "frames_abs_sum", "frames_peak", "force_width",
                                                "analytical"}
    assert meta["metrics"]["test"]["hybrid"]["n"] == len(list((synthetic_dataset / "test").rglob("*_a0.npz")))
    assert meta["auto"]["max_series_interval_decades"] >= 0 and meta["auto"]["table"]
    split = json.loads((synthetic_dataset / "split.json").read_text())
    assert meta["data"]["objects"] == {name: sorted(split[name]) for name in ("train", "val", "test")}


@pytest.mark.slow
def test_training_stops_early_when_validation_stops_improving(synthetic_dataset, tmp_path):
    variant = Variant.parse("depth", n_frames=3, size_px=(16, 22))
    config = TrainConfig(epochs=50, patience=2, lr=1e-12, batch_size=16, seed=0)  # nothing to gain after epoch 1
    meta = train_model(synthetic_dataset, tmp_path / "m", variant=variant, config=config, progress=False)
    training = meta["training"]
    assert training["epochs_run"] == training["best_epoch"] + 2 < 50
    assert meta["training"]["best_val_loss"] == pytest.approx(min(h["val_loss"] for h in training["history"]))


def test_the_rig_range_spans_the_samples_that_record_their_rig():
    rows = [{"gel_modulus_pa": 2.5e5, "gel_thickness_m": 3e-3, "finger_stiffness_n_per_m": None},
            {"gel_modulus_pa": 1.2e5, "gel_thickness_m": None, "finger_stiffness_n_per_m": None},
            {"gel_modulus_pa": 4.0e5, "gel_thickness_m": 4.5e-3, "finger_stiffness_n_per_m": None}]
    assert rig_range(rows) == {"gel_modulus_pa": [1.2e5, 4.0e5], "gel_thickness_m": [3e-3, 4.5e-3]}


def test_a_sample_in_the_wrong_split_is_a_leak(synthetic_dataset, tmp_path):
    data = tmp_path / "leaky"
    shutil.copytree(synthetic_dataset, data)
    victim = load_split(data / "split.json")["val"][0]
    moved = sorted((data / "val" / victim).glob("*.npz"))[0]
    (data / "train" / victim).mkdir(exist_ok=True)
    shutil.copy(moved, data / "train" / victim / moved.name)
    with pytest.raises(SampleError, match=f"object '{victim}' is not in the train split"):
        load_split_data(data, Variant.parse("depth", n_frames=3, size_px=(16, 22)))


def test_split_data_follows_the_split_file(synthetic_dataset):
    data = load_split_data(synthetic_dataset, Variant.parse("depth+fw+analytical", n_frames=3, size_px=(16, 22)))
    split = load_split(synthetic_dataset / "split.json")
    for name, part in data.items():
        assert {r["object"] for r in part.rows} == set(split[name])
        assert part.inputs["frames"].shape[0] == len(part) == part.label.shape[0]
        assert np.all((part.label >= 3) & (part.label <= 12))  # log10 E (Pa)


def test_mismatched_variant_or_empty_split_is_refused(synthetic, tmp_path):
    plain = synthetic.write_dataset(tmp_path / "plain", markers=False, grasps=1, shifts=1)
    with pytest.raises(EstimatorError, match="built without --markers"):
        train_model(plain, tmp_path / "m", variant=Variant.parse("rgb+markers", n_frames=3, size_px=(16, 22)),
                    progress=False)
    shutil.rmtree(plain / "val")
    with pytest.raises(EstimatorError, match="0 val samples"):
        train_model(plain, tmp_path / "m", variant=Variant.parse("depth", n_frames=3, size_px=(16, 22)),
                    progress=False)
    with pytest.raises(EstimatorError, match="--label-sd -0.1: expected a finite value >= 0"):
        TrainConfig(label_sd_decades=-0.1)


@pytest.mark.parametrize(("field", "option"), [("epochs", "--epochs"), ("patience", "--patience"),
                                               ("batch_size", "--batch-size"), ("threads", "--threads")])
def test_a_recipe_count_below_one_names_its_option_and_value(field, option):
    with pytest.raises(EstimatorError, match=f"^{option} 0: expected a whole number >= 1$"):
        TrainConfig(**{field: 0})


def test_a_variant_naming_a_part_twice_is_refused():
    from estimator.errors import ModelError

    with pytest.raises(ModelError, match=r"'rgb\+fw\+analytical\+fw': \+fw given more than once"):
        Variant.parse("rgb+fw+analytical+fw")
    assert Variant.parse("depth+analytical+fw") == Variant.parse("depth+fw+analytical")


def test_training_curve_has_a_linear_loss_axis_an_honest_loss_unit_and_names_the_variant(tmp_path, monkeypatch):
    from types import SimpleNamespace

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from estimator.training.train import Fitted, _plot

    history = [{"epoch": e, "train_loss": 0.7 - 0.05 * e, "val_loss": 0.72 - 0.04 * e,
                "train_log10_error": 0.5 - 0.03 * e, "val_log10_error": 0.55 - 0.02 * e} for e in range(1, 9)]
    model = SimpleNamespace(variant=SimpleNamespace(name="depth+fw 3f 64x88"))
    monkeypatch.setattr(plt, "close", lambda *args, **kwargs: None)
    _plot(Fitted(model=model, history=history, best_epoch=6, best_val_loss=0.48), tmp_path / "curve.png")
    ax_loss, ax_err = plt.gcf().axes
    assert ax_loss.get_yscale() == "linear"  # 0.3-0.7: less than a decade
    assert "(decades)" not in ax_loss.get_ylabel().replace("CRPS (decades)", "")  # the sum is not in decades
    assert "nats" in ax_loss.get_ylabel()
    assert all("depth+fw 3f 64x88" in ax.get_title() for ax in (ax_loss, ax_err))
    plt.close(plt.gcf())


def test_a_diverging_run_stops_naming_lr_and_writes_nothing(synthetic_dataset, tmp_path):
    variant = Variant.parse("depth", n_frames=3, size_px=(16, 22))
    config = TrainConfig(epochs=2, lr=1e6, batch_size=16, seed=0)
    with pytest.raises(EstimatorError, match=r"^training diverged: \w+ loss \S+ at epoch 1 \(--lr 1e\+06\): "
                                             "lower --lr$"):
        train_model(synthetic_dataset, tmp_path / "m", variant=variant, config=config, progress=False)
    assert not (tmp_path / "m").exists()


def test_a_loss_past_the_divergence_bound_or_weights_not_finite_stop_the_run():
    import torch

    from estimator.training.train import DIVERGED_LOSS, check_converging

    model = torch.nn.Linear(2, 1)
    check_converging(model, {"training loss": 1.5, "validation loss": DIVERGED_LOSS}, 3, 2e-3, "training")
    with pytest.raises(EstimatorError, match=r"^training diverged: validation loss 1.08e\+10 at epoch 3 \(--lr 1\)"):
        check_converging(model, {"training loss": 1.5, "validation loss": 1.08e10}, 3, 1.0, "training")
    with torch.no_grad():
        model.weight[0, 0] = float("inf")
    with pytest.raises(EstimatorError, match=r"^fine-tuning diverged: weights not finite at epoch 2 \(--lr 0.1\)"):
        check_converging(model, {"training loss": 1.5}, 2, 0.1, "fine-tuning")


def test_seeds_below_2_64_seed_torch_as_themselves_and_larger_ones_train_too(synthetic_dataset, tmp_path):
    from estimator.training.train import torch_seed

    # The seeds models were trained with so far keep their weights.
    assert [torch_seed(s) for s in (0, 1, 2**63, 2**64 - 1)] == [0, 1, 2**63, 2**64 - 1]
    variant = Variant.parse("depth", n_frames=3, size_px=(16, 22))
    meta = train_model(synthetic_dataset, tmp_path / "m", variant=variant,
                       config=TrainConfig(epochs=1, batch_size=16, seed=2**64), progress=False)
    assert meta["training"]["seed"] == 2**64


def test_threads_past_the_cap_are_refused_by_the_command_line(tmp_path, capsys):
    from estimator.cli import main
    from estimator.training.train_cli import MAX_THREADS

    with pytest.raises(SystemExit) as exit_:
        main(["train", "--data", str(tmp_path), "--out", str(tmp_path / "m"), "--threads", str(2**64)])
    assert exit_.value.code == 2
    assert f"--threads: '{2**64}': expected a whole number from 1 to {MAX_THREADS}" in capsys.readouterr().err


@pytest.mark.slow
def test_the_written_model_is_the_best_epochs_not_the_last(synthetic_dataset, tmp_path):
    import torch

    from estimator.inference.distribution import censor
    from estimator.inference.infer import CompliancePredictor
    from estimator.training.train import distribution_loss

    variant = Variant.parse("depth", n_frames=3, size_px=(16, 22))
    config = TrainConfig(epochs=6, patience=6, lr=0.05, batch_size=8, seed=0)  # best at epoch 4 of 6 (seeded)
    meta = train_model(synthetic_dataset, tmp_path / "m", variant=variant, config=config, progress=False)
    training = meta["training"]
    assert training["best_epoch"] < training["epochs_run"]
    assert abs(training["best_val_loss"] - training["history"][-1]["val_loss"]) > 1e-3  # the epochs tell apart
    val = load_split_data(synthetic_dataset, variant)["val"].live()
    logits = CompliancePredictor(tmp_path / "m").predict_logits(val.inputs)
    written = float(distribution_loss(torch.from_numpy(np.asarray(logits, np.float32)),
                                      torch.from_numpy(censor(val.label).astype(np.float32))))
    assert written == pytest.approx(training["best_val_loss"], abs=1e-4)


def test_a_variant_window_other_than_the_datasets_is_refused(synthetic_dataset, tmp_path):
    # Images of one window under metadata naming another would be fed to the model at the wrong scale.
    variant = Variant.parse("depth", n_frames=3, size_px=(16, 22), window_m=(0.01, 0.013))
    with pytest.raises(EstimatorError, match=r"^variant window .* holds images of a"):
        train_model(synthetic_dataset, tmp_path / "m", variant=variant, config=TrainConfig(epochs=1), progress=False)
    assert not (tmp_path / "m").exists()


def test_a_loss_of_ten_thousand_per_sample_is_divergence():
    import torch

    from estimator.training.train import check_converging

    # An uninformed network scores about 2 per sample; a run at --lr 1 scores 1e4 to 1e10.
    model = torch.nn.Linear(2, 1)
    check_converging(model, {"training loss": 2.0, "validation loss": 5.0}, 1, 2e-3, "training")
    with pytest.raises(EstimatorError, match=r"^training diverged: training loss 1e\+04 at epoch 4 \(--lr 1\)"):
        check_converging(model, {"training loss": 1e4, "validation loss": 5.0}, 4, 1.0, "training")


@pytest.mark.parametrize("value", [float("inf"), float("nan")])
def test_a_label_sd_that_is_not_finite_is_refused(value):
    with pytest.raises(EstimatorError, match="--label-sd .*: expected a finite value >= 0"):
        TrainConfig(label_sd_decades=value)


@pytest.mark.parametrize("lr", [0.0, -1e-3, float("inf"), float("nan")])
def test_a_learning_rate_that_is_not_positive_and_finite_is_refused(lr):
    # At --lr 0 a run would train nothing and ship its initial weights.
    with pytest.raises(EstimatorError, match=r"^--lr .*: expected a finite value > 0$"):
        TrainConfig(lr=lr)


def test_flips_mirror_whole_samples_and_every_kind_happens():
    import torch

    from estimator.training.train import _flip

    frames = torch.from_numpy(np.random.default_rng(0).normal(size=(64, 3, 1, 4, 5)).astype(np.float32))
    out = _flip(frames, np.random.default_rng(1))
    kinds = []
    for before, after in zip(frames, out, strict=True):
        options = {"none": before, "lr": before.flip(-1), "ud": before.flip(-2), "both": before.flip(-1).flip(-2)}
        matching = [kind for kind, flipped in options.items() if torch.equal(flipped, after)]
        assert len(matching) == 1  # every frame of the sample flipped alike
        kinds.append(matching[0])
    assert set(kinds) == {"none", "lr", "ud", "both"}


def test_an_epochs_loss_is_the_mean_loss_per_sample():
    import torch

    from estimator.inference.distribution import censor
    from estimator.training.model import ComplianceNet
    from estimator.training.splits import SplitData
    from estimator.training.train import distribution_loss, predict, train_epoch

    n = 8
    variant = Variant.parse("depth", n_frames=3, size_px=(16, 22))
    inputs = {name: np.zeros((n, *shape), np.float32) for name, shape in variant.input_shapes.items()}  # flips: no-op
    data = SplitData(inputs, np.random.default_rng(0).uniform(4.0, 11.0, n).astype(np.float32), [{}] * n)
    torch.manual_seed(0)
    model = ComplianceNet(variant).eval()  # running statistics: every batch answers as the whole would
    expected = float(distribution_loss(torch.from_numpy(predict(model, data)),
                                       torch.from_numpy(censor(data.label).astype(np.float32))))
    optimiser = torch.optim.SGD(model.parameters(), lr=0.0)
    got = train_epoch(model, data, optimiser, TrainConfig(batch_size=2, label_sd_decades=0.0),
                      np.random.default_rng(0))
    assert got == pytest.approx(expected, rel=1e-5)
