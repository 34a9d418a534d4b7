"""The predictive distribution over log10 E: quantiles, temperature, the states it gives, the loss."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.stats import norm

from estimator.errors import ModelError
from estimator.inference.distribution import (
    BIN_DECADES,
    CENSOR_PA,
    EDGES_LOG10,
    HEDGE_FROM_DECADES,
    HEDGE_WEIGHT,
    N_BINS,
    SPREAD_FLOOR_DECADES,
    cdf_at,
    censor,
    conformal_scale,
    describe,
    fit_temperature,
    floor_log_weights,
    force_band,
    hedged_point,
    interval_score,
    probabilities,
    quantile,
    spread,
)

CENTRES = (EDGES_LOG10[:-1] + EDGES_LOG10[1:]) / 2
LIMIT_PA = 6.75e6
SOFT_PA = 5e3


def gaussian(mean: float, sd: float) -> np.ndarray:
    """Bin probabilities of a normal distribution of log10 E."""
    mass = np.diff(norm.cdf(EDGES_LOG10, mean, sd))
    return mass / mass.sum()


def test_bins_span_the_model_scale_at_a_tenth_of_a_decade():
    assert N_BINS == 90 and EDGES_LOG10[0] == 3.0 and EDGES_LOG10[-1] == 12.0
    assert np.allclose(np.diff(EDGES_LOG10), BIN_DECADES)


def test_quantiles_invert_the_cdf_and_stay_inside_the_scale():
    probs = np.stack([gaussian(5.2, 0.3), gaussian(9.0, 0.8)])
    assert quantile(probs, 0.5) == pytest.approx([5.2, 9.0], abs=0.01)
    q = quantile(probs, np.array([0.05, 0.95]))
    assert q[0] == pytest.approx([5.2 - 1.645 * 0.3, 5.2 + 1.645 * 0.3], abs=0.02)
    assert cdf_at(probs, q[:, 1]) == pytest.approx([0.95, 0.95], abs=1e-6)
    one_bin = np.zeros(N_BINS)
    one_bin[0] = 1.0
    assert 3.0 <= quantile(one_bin, 0.0) <= quantile(one_bin, 1.0) <= 3.0 + BIN_DECADES


def test_spread_and_the_score_of_a_truth():
    probs = np.stack([gaussian(6.05, 0.5), gaussian(5.05, 0.01)])  # the second within one bin
    assert spread(probs) == pytest.approx([0.5, SPREAD_FLOOR_DECADES], rel=0.05)
    assert interval_score(probs[:1], np.array([6.05 + 0.75])) == pytest.approx([1.5], rel=0.05)
    # The truth is censored as the labels were: a metal is scored against 100 MPa.
    rigid = gaussian(7.9, 0.2)[None]
    assert interval_score(rigid, np.array([11.3])) == pytest.approx(interval_score(rigid, np.array([8.0])))


def test_conformal_scale_is_the_finite_sample_quantile():
    scores = np.linspace(0.1, 0.9, 9)
    assert conformal_scale(scores, 0.9) == pytest.approx(0.9)  # rank ceil(10 * 0.9) = 9 of 9
    assert conformal_scale(scores, 0.5) == pytest.approx(0.5)  # rank 5
    assert conformal_scale(scores[:5], 0.9) == math.inf  # too few to promise 90 %
    assert conformal_scale(np.array([]), 0.9) == math.inf
    assert conformal_scale(scores, 1.0) == math.inf  # no finite sample promises every truth


@pytest.mark.parametrize("level", [0.0, -0.1, 1.5, float("nan")])
def test_conformal_scale_refuses_a_level_outside_zero_to_one(level):
    with pytest.raises(ModelError, match="level"):
        conformal_scale(np.arange(10.0), level)


def test_temperature_refuses_truths_without_a_bin():
    with pytest.raises(ModelError, match="log10_truth"):
        fit_temperature(np.zeros((3, N_BINS)), np.array([np.nan, 1.0, 2.0]))
    with pytest.raises(ModelError, match="log10_truth"):
        fit_temperature(np.zeros((2, N_BINS)), np.array([5.0, np.inf]))


def test_temperature_widens_an_overconfident_model_and_intervals_then_cover():
    rng = np.random.default_rng(0)
    means = rng.uniform(4.0, 6.5, 400)
    truth = means + rng.normal(0.0, 0.4, means.size)  # the truth scatters 0.4 decade
    logits = np.stack([-((CENTRES - m) ** 2) / (2 * 0.1**2) for m in means])  # the model claims 0.1
    temperature = fit_temperature(logits, truth)
    assert temperature > 4.0
    probs = probabilities(logits, temperature=temperature)
    scale = conformal_scale(interval_score(probs[:200], truth[:200]), 0.9)
    held = [describe(p, scale=scale, limit_pa=LIMIT_PA, soft_pa=SOFT_PA) for p in probs[200:]]
    covered = np.mean([d.low_pa <= 10**t <= d.high_pa for d, t in zip(held, truth[200:], strict=True)])
    assert 0.85 <= covered <= 0.97
    widths = [math.log10(d.high_pa / d.low_pa) for d in held]
    assert np.median(widths) == pytest.approx(2 * 1.645 * 0.4, rel=0.2)


def test_labels_are_censored_at_a_hundred_megapascal():
    assert censor(np.array([5.0, 8.0, 11.3])).tolist() == [5.0, 8.0, math.log10(CENSOR_PA)]


def test_states_follow_the_mass_above_the_resolution_limit_and_the_median():
    rigid = describe(gaussian(8.0, 0.5), scale=1.645, limit_pa=LIMIT_PA, soft_pa=SOFT_PA, p_rigid=0.8)
    assert (rigid.state, rigid.e_pa, rigid.low_pa, rigid.high_pa) == ("lower_bound", LIMIT_PA, LIMIT_PA, None)
    assert rigid.p_above_limit > 0.8
    # Probably rigid, but not as sure as p_rigid asks: a number whose interval is open to the top
    # of the scale, since the censored value stands for anything stiffer; rendered at the rigid end.
    unsure = describe(0.3 * gaussian(5.5, 0.2) + 0.7 * gaussian(8.0, 0.04), scale=1.645, limit_pa=LIMIT_PA,
                      soft_pa=SOFT_PA, p_rigid=0.8)
    assert unsure.state == "ok" and unsure.e_pa == pytest.approx(LIMIT_PA) and unsure.high_pa == pytest.approx(1e12)
    soft = describe(gaussian(3.4, 0.2), scale=1.645, limit_pa=LIMIT_PA, soft_pa=SOFT_PA)
    assert (soft.state, soft.e_pa, soft.low_pa, soft.high_pa) == ("upper_bound", SOFT_PA, None, SOFT_PA)
    rubber = describe(gaussian(5.9, 0.2), scale=1.645, limit_pa=LIMIT_PA, soft_pa=SOFT_PA)
    assert rubber.state == "ok" and rubber.low_pa < rubber.e_pa < rubber.high_pa
    assert math.log10(rubber.e_pa) == pytest.approx(5.9, abs=0.01)
    assert math.log10(rubber.high_pa / rubber.low_pa) == pytest.approx(2 * 1.645 * 0.2, abs=0.1)  # whole bins
    # Just under the limit the answer is a number, even with much of the mass above it.
    near = describe(gaussian(math.log10(LIMIT_PA) - 0.05, 0.5), scale=1.645, limit_pa=LIMIT_PA, soft_pa=SOFT_PA)
    assert near.state == "ok" and 0.4 < near.p_above_limit < 0.5


def test_describe_refuses_meaningless_arguments():
    with pytest.raises(ModelError, match="scale"):
        describe(gaussian(6, 1), scale=0.0, limit_pa=LIMIT_PA, soft_pa=SOFT_PA)
    with pytest.raises(ModelError, match="soft_pa"):
        describe(gaussian(6, 1), scale=1.645, limit_pa=1e3, soft_pa=SOFT_PA)
    with pytest.raises(ModelError, match="limit_pa"):
        describe(gaussian(6, 1), scale=1.645, limit_pa=1e9, soft_pa=SOFT_PA)
    with pytest.raises(ModelError, match="p_rigid"):
        describe(gaussian(6, 1), scale=1.645, limit_pa=LIMIT_PA, soft_pa=SOFT_PA, p_rigid=1.0)
    with pytest.raises(ModelError, match="temperature"):
        probabilities(np.zeros((1, N_BINS)), temperature=0.0)


@pytest.mark.parametrize("probs", [np.zeros(N_BINS), np.full(N_BINS, np.nan), -gaussian(6, 1),
                                   gaussian(6, 1)[:10]])
def test_describe_refuses_what_is_no_distribution(probs):
    with pytest.raises(ModelError, match="probs"):
        describe(probs, scale=1.5, limit_pa=1e8, soft_pa=1e3)


@pytest.mark.train
def test_the_training_loss_is_lowest_at_the_truth():
    torch = pytest.importorskip("torch")
    from estimator.training.train import NLL_WEIGHT, distribution_loss

    label = torch.tensor([5.55])
    losses = {}
    for centre in (5.55, 5.85, 7.55):
        logits = torch.from_numpy(np.log(gaussian(centre, 0.15) + 1e-12)[None]).float()
        losses[centre] = float(distribution_loss(logits, label))
    assert losses[5.55] < losses[5.85] < losses[7.55]
    # Far from the truth the CRPS grows like the absolute error (2 decades here); the log score
    # adds at most NLL_WEIGHT times the 28 nats of a near-zero bin.
    assert 1.9 <= losses[7.55] - losses[5.55] <= 2.1 + NLL_WEIGHT * 28


def test_force_bands_split_at_their_edges():
    assert force_band(np.array([0.0, 9.99, 10.0, 19.9, 20.0, 300.0]), (10.0, 20.0)).tolist() == [0, 0, 1, 1, 2, 2]
    assert force_band(5.0, ()) == 0


def test_a_floor_keeps_a_leak_of_the_mass_below_it_and_cuts_its_bin():
    probs = gaussian(5.0, 0.5)[None]
    floored = probabilities(np.log(np.maximum(probs, 1e-300)), log_weights=floor_log_weights(np.array([5.0]), leak=0.01))
    below = cdf_at(floored, 5.0)[0]
    # Half the mass lay below 5.0: it keeps 1 % of its weight against the half above.
    assert below == pytest.approx(0.005 / 0.505, rel=1e-3)
    mid_bin = floor_log_weights(np.array([EDGES_LOG10[20] + BIN_DECADES / 4]), leak=0.0 + 1e-12)[0]
    assert math.exp(mid_bin[20]) == pytest.approx(0.75) and math.exp(mid_bin[19]) < 1e-11 and mid_bin[21] == 0.0
    untouched = floor_log_weights(np.array([-np.inf]), leak=0.01)
    assert np.all(untouched == 0.0)
    with pytest.raises(ModelError, match="leak"):
        floor_log_weights(np.array([5.0]), leak=0.0)


def test_the_floor_is_the_highest_lower_bound_of_the_reliable_methods():
    from estimator.estimate import Estimate
    from estimator.inference.inputs import analytical_floor

    estimates = (Estimate.at_least("no_tactile", 2e5, "stiff"), Estimate.at_least("series", 3e6, "stiffer"),
                 Estimate.at_least("elastic", 1e9, "not trusted"), Estimate.at_most("hertz", 1e4, "soft"))
    assert analytical_floor(estimates) == (pytest.approx(math.log10(3e6)), "series")
    assert analytical_floor(estimates, scale=2.0)[0] == pytest.approx(math.log10(6e6))
    assert analytical_floor(estimates, methods=("no_tactile",)) == (pytest.approx(math.log10(2e5)), "no_tactile")
    assert analytical_floor(estimates[2:]) == (-math.inf, None)
    # An ok answer's interval is no bound: its low end floors nothing.
    assert analytical_floor((Estimate.ok("series", 1e6, 5e5, 2e6),)) == (-math.inf, None)


def _expected_loss(probs: np.ndarray, points: np.ndarray, *, soft: float, limit: float) -> np.ndarray:
    """Brute force: the hedging loss at each point, the distribution drawn uniformly within its bins."""
    rng = np.random.default_rng(0)
    draws = rng.choice(CENTRES, size=200_000, p=probs) + rng.uniform(-BIN_DECADES / 2, BIN_DECADES / 2, 200_000)
    d = np.abs(np.clip(points, soft, limit)[:, None] - np.clip(draws, soft, limit)[None, :])
    return (d + HEDGE_WEIGHT * np.maximum(0.0, d - HEDGE_FROM_DECADES)).mean(axis=1)


@pytest.mark.parametrize(("probs", "where"), [
    (gaussian(5.9, 0.2), "about the median"),
    (0.45 * gaussian(5.9, 0.05) + 0.55 * gaussian(8.0, 0.05), "between the modes"),
])
@pytest.mark.slow
def test_the_value_of_an_ok_answer_minimises_the_hedging_loss(probs, where):
    soft, limit = math.log10(SOFT_PA), math.log10(LIMIT_PA)
    said = describe(probs, scale=1.645, limit_pa=LIMIT_PA, soft_pa=SOFT_PA, p_rigid=0.9)
    assert said.state == "ok" and said.low_pa <= said.e_pa <= said.high_pa
    value = math.log10(said.e_pa)
    assert value == pytest.approx(hedged_point(probs, low=math.log10(said.low_pa), high=math.log10(said.high_pa),
                                               soft=soft, limit=limit))
    grid = np.linspace(math.log10(said.low_pa), min(math.log10(said.high_pa), limit), 400)
    loss = _expected_loss(probs, grid, soft=soft, limit=limit)
    assert _expected_loss(probs, np.array([value]), soft=soft, limit=limit)[0] <= loss.min() + 2e-3
    median = float(quantile(probs, 0.5)[0])
    if where == "about the median":
        assert value == pytest.approx(median, abs=0.01)
    else:  # the median lies in the rigid mode; the value between the modes, well short of the rigid end
        assert median > limit and 6.2 < value < limit - 0.3


def test_no_value_is_hedged_outside_the_display_range():
    probs = gaussian(5.9, 0.2)
    assert hedged_point(probs, low=7.0, high=8.0, soft=3.7, limit=6.83) is None
    assert hedged_point(probs, low=5.0, high=6.5, soft=3.7, limit=6.83) == pytest.approx(5.9, abs=0.01)


def test_widening_moves_the_interval_and_not_the_value():
    probs = 0.45 * gaussian(5.9, 0.05) + 0.55 * gaussian(8.0, 0.05)
    said = {w: describe(probs, scale=1.5, limit_pa=LIMIT_PA, soft_pa=SOFT_PA, p_rigid=0.9, widen=w) for w in (1.0, 3.0)}
    assert said[1.0].state == said[3.0].state == "ok"
    assert said[1.0].e_pa == said[3.0].e_pa and said[3.0].low_pa < said[1.0].low_pa
    with pytest.raises(ModelError, match="widen"):
        describe(probs, scale=0.5, limit_pa=LIMIT_PA, soft_pa=SOFT_PA, widen=0.5)
