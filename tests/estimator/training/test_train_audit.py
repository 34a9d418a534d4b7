"""Training's loss, epochs and batches: the figures it reports and what every step does."""

from __future__ import annotations

import json
import logging

import numpy as np
import pytest
import torch

from estimator.errors import EstimatorError
from estimator.inference import distribution
from estimator.inference.distribution import censor
from estimator.inference.inputs import LOG10_E_RANGE, Variant
from estimator.training import train as train_module
from estimator.training.model import ComplianceNet
from estimator.training.recipe import TrainConfig
from estimator.training.splits import SplitData
from estimator.training.train import (
    _fit,
    _mean_log10_error,
    check_converging,
    distribution_loss,
    predict,
    train_epoch,
    train_model,
)

VARIANT = Variant.parse("depth", n_frames=3, size_px=(16, 22))


def _data(n: int, *, seed: int = 0, zeros: bool = True) -> SplitData:
    rng = np.random.default_rng(seed)
    inputs = {name: (np.zeros if zeros else lambda s: rng.normal(size=s))((n, *shape)).astype(np.float32)
              for name, shape in VARIANT.input_shapes.items()}
    return SplitData(inputs, rng.uniform(4.0, 11.0, n).astype(np.float32), [{}] * n)


def _still_model() -> ComplianceNet:
    torch.manual_seed(0)
    return ComplianceNet(VARIANT).eval()  # running statistics: a batch answers as the whole would


def _per_sample_losses(model: ComplianceNet, data: SplitData) -> np.ndarray:
    logits = torch.from_numpy(predict(model, data))
    labels = torch.from_numpy(censor(data.label).astype(np.float32))
    return np.array([float(distribution_loss(logits[i:i + 1], labels[i:i + 1])) for i in range(len(data))])


def test_the_loss_is_the_crps_in_decades_plus_a_twentieth_of_the_log_score():
    rng = np.random.default_rng(3)
    logits = rng.normal(0.0, 2.0, (3, distribution.N_BINS))
    labels = np.array([4.37, 7.91, 10.02])
    probs = np.exp(logits) / np.exp(logits).sum(axis=1, keepdims=True)
    cdf = probs.cumsum(axis=1)[:, :-1]
    step = (labels[:, None] <= distribution.EDGES_LOG10[None, 1:-1]).astype(float)
    crps = ((cdf - step) ** 2).sum(axis=1) * distribution.BIN_DECADES
    log_score = -np.log(probs[np.arange(3), distribution.bin_index(labels)])
    expected = crps.mean() + 0.05 * log_score.mean()
    got = float(distribution_loss(torch.from_numpy(logits.astype(np.float32)),
                                  torch.from_numpy(labels.astype(np.float32))))
    assert got == pytest.approx(expected, rel=1e-4)


def test_a_label_on_a_bin_edge_is_scored_as_at_or_below_the_edge(monkeypatch):
    # CRPS of a point mass: its CDF is 1 from the label on, edge included.
    monkeypatch.setattr(train_module, "NLL_WEIGHT", 0.0)
    k = 40
    edge = train_module._EDGES[k]  # the upper edge of bin k
    logits = torch.full((1, distribution.N_BINS), -60.0)
    logits[0, k] = 60.0  # every bit of mass in the bin just below the label
    assert float(distribution_loss(logits, edge.reshape(1))) == pytest.approx(0.0, abs=1e-6)


def test_a_lone_last_sample_is_left_out_of_the_epochs_mean():
    data = _data(5)
    model = _still_model()
    losses = _per_sample_losses(model, data)
    order = np.random.default_rng(0).permutation(len(data))  # train_epoch's first draw
    got = train_epoch(model, data, torch.optim.SGD(model.parameters(), lr=0.0),
                      TrainConfig(batch_size=2, label_sd_decades=0.0), np.random.default_rng(0))
    assert got == pytest.approx(losses[order[:4]].mean(), rel=1e-5)  # batches 2, 2 and a skipped 1


@pytest.mark.parametrize(("n", "batch_size"), [(8, 1), (1, 4)])
def test_an_epoch_without_a_batch_of_two_is_refused_naming_batch_size(n, batch_size):
    # Batch norm needs two samples a batch: otherwise nothing trains and the initial weights would ship.
    model = _still_model()
    with pytest.raises(EstimatorError, match=rf"^--batch-size {batch_size}: .*{n} sample"):
        train_epoch(model, _data(n), torch.optim.SGD(model.parameters(), lr=0.0),
                    TrainConfig(batch_size=batch_size), np.random.default_rng(0))


def test_every_batch_is_flipped_and_its_labels_jittered(monkeypatch):
    data = _data(8)
    flipped = []
    real = train_module._flip
    monkeypatch.setattr(train_module, "_flip", lambda frames, rng: flipped.append(len(frames)) or real(frames, rng))
    losses = {}
    for sd in (0.0, 1.0):
        model = _still_model()
        losses[sd] = train_epoch(model, data, torch.optim.SGD(model.parameters(), lr=0.0),
                                 TrainConfig(batch_size=4, label_sd_decades=sd), np.random.default_rng(0))
    assert flipped == [4, 4, 4, 4]
    assert abs(losses[1.0] - losses[0.0]) > 1e-3


def test_predictions_in_small_batches_answer_every_sample_as_one_batch_does():
    data, model = _data(7, zeros=False), _still_model()
    whole = predict(model, data)
    assert whole.shape == (7, distribution.N_BINS)
    np.testing.assert_allclose(predict(model, data, batch_size=3), whole, atol=1e-6)
    assert predict(model, _data(0)).shape == (0, distribution.N_BINS)


def test_the_history_error_is_the_medians_distance_from_the_label():
    middle = (LOG10_E_RANGE[0] + LOG10_E_RANGE[1]) / 2
    uniform = np.zeros((2, distribution.N_BINS))
    assert _mean_log10_error(uniform, np.array([middle, middle + 0.5])) == pytest.approx(0.25, abs=1e-6)


def test_the_learning_rate_decays_once_an_epoch_over_the_epochs(monkeypatch):
    made = []

    class Spy(torch.optim.lr_scheduler.CosineAnnealingLR):
        def __init__(self, optimiser, T_max):  # noqa: N803 - torch's name
            made.append({"T_max": T_max, "steps": 0})
            super().__init__(optimiser, T_max=T_max)

        def step(self, *args, **kwargs):
            if made:
                made[-1]["steps"] += 1
            return super().step(*args, **kwargs)

    monkeypatch.setattr(torch.optim.lr_scheduler, "CosineAnnealingLR", Spy)
    fitted = _fit(_data(8, zeros=False), _data(4, seed=1, zeros=False), VARIANT,
                  TrainConfig(epochs=3, patience=3, batch_size=4), progress=False)
    assert len(fitted.history) == 3
    # The constructor steps once (torch's own initial step); then one per epoch.
    assert made == [{"T_max": 3, "steps": 1 + 3}]


@pytest.mark.filterwarnings("ignore::UserWarning")  # the scheduler steps with no optimiser step
def test_the_kept_epoch_is_the_best_and_patience_stops_after_it(monkeypatch):
    losses = iter([5.0, 3.0, 3.0, 4.0, 2.0, 9.0])  # best at epoch 2, then two epochs without improving
    monkeypatch.setattr(train_module, "distribution_loss", lambda *args: torch.tensor(next(losses)))
    monkeypatch.setattr(train_module, "train_epoch", lambda *args: 1.0)
    fitted = _fit(_data(4), _data(4, seed=1), VARIANT, TrainConfig(epochs=6, patience=2), progress=False)
    assert (fitted.best_epoch, fitted.best_val_loss, len(fitted.history)) == (2, 3.0, 4)


def test_a_loss_of_minus_infinity_is_not_finite_and_stops_the_run():
    with pytest.raises(EstimatorError, match=r"^training diverged: training loss -inf at epoch 1"):
        check_converging(torch.nn.Linear(2, 1), {"training loss": float("-inf")}, 1, 1e-3, "training")


def test_a_dataset_of_other_measurement_code_is_warned_of_by_name(synthetic, tmp_path, caplog):
    plain = synthetic.write_dataset(tmp_path / "plain", markers=False, grasps=1, shifts=1)
    markers = Variant.parse("rgb+markers", n_frames=3, size_px=(16, 22))
    for version, warned in ((None, False), (-1, True)):
        if version is not None:
            manifest = json.loads((plain / "dataset.json").read_text())
            (plain / "dataset.json").write_text(json.dumps({**manifest, "measurement_version": version}))
        caplog.clear()
        with caplog.at_level(logging.WARNING, logger=train_module.__name__), \
                pytest.raises(EstimatorError, match="built without --markers"):  # stops right after the check
            train_model(plain, tmp_path / "m", variant=markers, progress=False)
        assert any("measurement version -1" in r.getMessage() for r in caplog.records) is warned
