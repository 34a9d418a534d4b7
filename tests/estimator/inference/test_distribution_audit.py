"""Audit of the predictive distribution's edges: what the quantiles, the bins, the conformal scale and the
temperature promise, and which options and boundaries :func:`describe` holds to (fast, no model)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.stats import norm

from estimator.errors import ModelError
from estimator.inference.distribution import (
    CENSOR_PA,
    EDGES_LOG10,
    HEDGE_FROM_DECADES,
    HEDGE_WEIGHT,
    N_BINS,
    bin_index,
    cdf_at,
    conformal_scale,
    describe,
    describe_on_gel,
    fit_temperature,
    floor_log_weights,
    hedged_point,
    interval_score,
    probabilities,
    quantile,
    spread,
)

LIMIT_PA = 1e7  # log10 7.0: a bin edge exactly
SOFT_PA = 1e3


def gaussian(mean: float, sd: float) -> np.ndarray:
    """Bin probabilities of a normal distribution of log10 E."""
    mass = np.diff(norm.cdf(EDGES_LOG10, mean, sd))
    return mass / mass.sum()


def two_bins() -> np.ndarray:
    """Half the mass in the bin from 4.0, half in the bin from 8.0; nothing between."""
    probs = np.zeros(N_BINS)
    probs[10] = probs[50] = 0.5
    return probs


# --------------------------------------------------------------------------- quantiles and bins


def test_a_quantile_across_empty_bins_is_the_lowest_value_reaching_it():
    # inf{x: F(x) >= q}: the median of two separate halves is the top of the lower one, not the bottom
    # of the upper one (nor anywhere between).
    assert quantile(two_bins(), 0.5) == pytest.approx([4.1], abs=1e-9)
    assert quantile(two_bins(), 0.5 + 1e-6) == pytest.approx([8.0], abs=1e-4)


def test_an_unnormalised_distribution_says_what_its_normalised_one_does():
    probs = gaussian(5.3, 0.3)
    assert quantile(4.0 * probs, 0.5) == pytest.approx(quantile(probs, 0.5), abs=1e-9)
    assert describe(4.0 * probs, scale=1.5, limit_pa=LIMIT_PA, soft_pa=SOFT_PA) == describe(
        probs, scale=1.5, limit_pa=LIMIT_PA, soft_pa=SOFT_PA)


@pytest.mark.parametrize(("log10_e", "index"), [(-5.0, 0), (3.0, 0), (3.06, 0), (3.1 + 1e-9, 1), (11.95, N_BINS - 1),
                                                (100.0, N_BINS - 1)])
def test_bin_index_floors_within_the_scale_and_clips_outside_it(log10_e, index):
    assert bin_index(np.array([log10_e])).tolist() == [index]


def test_the_score_of_a_truth_below_the_median_is_positive():
    probs = gaussian(6.0, 0.5)[None]
    assert interval_score(probs, np.array([5.0])) == pytest.approx([2.0], rel=0.05)


# --------------------------------------------------------------------------- conformal scale and temperature


def test_the_conformal_scale_does_not_depend_on_the_order_of_the_scores():
    scores = np.random.default_rng(1).permutation(np.linspace(0.1, 0.9, 9))
    assert conformal_scale(scores, 0.9) == pytest.approx(0.9)
    assert conformal_scale(scores, 0.5) == pytest.approx(0.5)


def test_the_temperature_is_fitted_to_the_weighted_distribution_it_calibrates():
    rng = np.random.default_rng(2)
    means = rng.uniform(4.5, 6.5, 200)
    truth = means + rng.normal(0.0, 0.3, means.size)
    centres = (EDGES_LOG10[:-1] + EDGES_LOG10[1:]) / 2
    logits = np.stack([-((centres - m) ** 2) / (2 * 0.3**2) for m in means])
    weights = floor_log_weights(means + 0.2, leak=0.05)  # floors that cut off much of the truths' mass
    fitted = fit_temperature(logits, truth, log_weights=weights)

    def nll(t: float) -> float:
        probs = probabilities(logits, temperature=t, log_weights=weights)
        return float(-np.log(probs[np.arange(truth.size), bin_index(truth)]).mean())

    grid = np.exp(np.linspace(math.log(0.25), math.log(8.0), 400))
    best = grid[np.argmin([nll(t) for t in grid])]
    assert fitted == pytest.approx(best, rel=0.03)
    assert abs(fitted - fit_temperature(logits, truth)) > 0.05 * fitted  # the weights matter here


@pytest.mark.parametrize(("claimed_sd", "temperature"), [(0.01, 8.0), (5.0, 0.25)])
def test_the_temperature_stays_within_its_range(claimed_sd, temperature):
    rng = np.random.default_rng(3)
    means = rng.uniform(4.5, 6.5, 100)
    truth = means + rng.normal(0.0, 0.5 if claimed_sd < 1 else 0.0, means.size)
    centres = (EDGES_LOG10[:-1] + EDGES_LOG10[1:]) / 2
    logits = np.stack([-((centres - m) ** 2) / (2 * claimed_sd**2) for m in means])
    assert fit_temperature(logits, truth) == pytest.approx(temperature, rel=1e-3)


@pytest.mark.parametrize("temperature", [math.inf, math.nan, -1.0])
def test_probabilities_refuse_a_temperature_that_is_not_finite_and_positive(temperature):
    with pytest.raises(ModelError, match="temperature"):
        probabilities(np.zeros((1, N_BINS)), temperature=temperature)


def test_a_leak_of_one_weighs_nothing():
    assert np.all(floor_log_weights(np.array([6.0]), leak=1.0) == 0.0)


# --------------------------------------------------------------------------- the value within [soft, limit]


@pytest.mark.parametrize(("mean", "low", "high", "expected"), [
    (3.2, 2.0, 5.0, 3.7),  # all the mass below soft: rendered at soft, not below it
    (9.0, 6.0, 10.0, 6.83),  # all the mass above the limit: rendered at the limit, not above it
    (9.0, 6.83, 10.0, 6.83),  # an interval meeting [soft, limit] in the limit alone
    (5.0, 2.0, 3.7, 3.7),  # ... or in soft alone
    (6.0, 4.0, 5.0, 5.0),  # the minimum beyond the interval's high end, short of the limit: that end
])
def test_the_value_stays_within_soft_and_limit_and_the_interval(mean, low, high, expected):
    assert hedged_point(gaussian(mean, 0.1), low=low, high=high, soft=3.7, limit=6.83) == pytest.approx(expected,
                                                                                                        abs=1e-9)


# --------------------------------------------------------------------------- describe's options and boundaries


@pytest.mark.parametrize("options", [
    {"scale": math.inf},  # conformal_scale's answer when too few validation grasps: no interval to state
    {"widen": math.inf},
    {"p_rigid": 0.0},
    {"soft_pa": 0.0},
    {"soft_pa": LIMIT_PA},
])
def test_describe_refuses_options_that_say_nothing(options):
    kwargs = {"scale": 1.5, "limit_pa": LIMIT_PA, "soft_pa": SOFT_PA, "p_rigid": 0.5, "widen": 1.0} | options
    with pytest.raises(ModelError, match="describe: expected"):
        describe(gaussian(5.0, 0.3), **kwargs)


def test_describe_refuses_a_negative_probability_even_with_a_positive_sum():
    probs = gaussian(5.0, 0.3)
    probs[20] = -0.01
    with pytest.raises(ModelError, match="probs"):
        describe(probs, scale=1.5, limit_pa=LIMIT_PA, soft_pa=SOFT_PA)


@pytest.mark.parametrize("shape", [(1, N_BINS), (N_BINS + 1,)])
def test_describe_refuses_probabilities_of_another_shape(shape):
    with pytest.raises(ModelError, match="probs"):
        describe(np.full(shape, 1.0 / N_BINS), scale=1.5, limit_pa=LIMIT_PA, soft_pa=SOFT_PA)


def test_a_probability_above_the_limit_reaching_p_rigid_exactly_is_a_lower_bound():
    said = describe(two_bins(), scale=1.0, limit_pa=LIMIT_PA, soft_pa=SOFT_PA, p_rigid=0.5)
    assert said.p_above_limit == 0.5
    assert (said.state, said.e_pa, said.low_pa, said.high_pa) == ("lower_bound", LIMIT_PA, LIMIT_PA, None)


def test_a_median_exactly_at_soft_is_an_upper_bound():
    probs = gaussian(4.5, 0.2)
    median = float(quantile(probs, 0.5)[0])
    soft_pa = 10.0**median
    assert math.log10(soft_pa) == median  # the boundary itself, exactly
    said = describe(probs, scale=1.0, limit_pa=LIMIT_PA, soft_pa=soft_pa)
    assert (said.state, said.e_pa, said.low_pa, said.high_pa) == ("upper_bound", soft_pa, None, soft_pa)


@pytest.mark.parametrize(("probs", "state"), [
    (0.7 * gaussian(3.5, 0.2) + 0.3 * gaussian(8.5, 0.2), "upper_bound"),
    (0.15 * gaussian(5.0, 0.2) + 0.85 * gaussian(8.5, 0.2), "lower_bound"),
    (gaussian(6.9, 0.3), "ok"),
])
def test_every_answer_states_its_probability_above_the_limit(probs, state):
    said = describe(probs, scale=1.5, limit_pa=LIMIT_PA, soft_pa=1e4, p_rigid=0.8)
    assert said.state == state
    assert said.p_above_limit == pytest.approx(1.0 - cdf_at(probs, 7.0)[0], abs=1e-12)
    assert 0.0 < said.p_above_limit < 1.0


def test_a_very_wide_interval_keeps_a_positive_finite_low_end():
    said = describe(gaussian(5.0, 0.2), scale=1e5, limit_pa=LIMIT_PA, soft_pa=SOFT_PA)
    assert said.state == "ok" and said.low_pa == pytest.approx(100.0) and said.high_pa == pytest.approx(1e12)
    assert said.low_pa <= said.e_pa <= said.high_pa


def test_an_interval_reaching_just_past_the_censored_value_is_open_to_the_top_of_the_scale():
    probs = gaussian(7.0, 0.1)
    median, half = float(quantile(probs, 0.5)[0]), float(spread(probs)[0])
    scale = (math.log10(CENSOR_PA) + 0.1 - median) / half  # the calibrated high end at 10**8.1 Pa
    said = describe(probs, scale=scale, limit_pa=LIMIT_PA, soft_pa=SOFT_PA, p_rigid=0.9)
    assert said.state == "ok" and said.high_pa == pytest.approx(1e12)


def test_a_limit_taken_past_the_censored_value_on_the_reference_gel_stops_there():
    # A stiffer measuring gel (gel_scale 2): its limit of 1e8 Pa is 2e8 Pa on the reference gel, past what the
    # model tells apart; the bound is stated at the censored value, in the measuring gel's moduli.
    said = describe_on_gel(gaussian(9.0, 0.2), scale=1.5, limit_pa=CENSOR_PA, soft_pa=SOFT_PA, p_rigid=0.8,
                           gel_scale=2.0)
    assert (said.state, said.e_pa, said.low_pa, said.high_pa) == ("lower_bound", CENSOR_PA / 2, CENSOR_PA / 2, None)


def test_a_minimum_in_the_intervals_last_grid_step_is_interpolated_not_snapped_to_its_end():
    # Only at the limit does the value snap to the grid's end; elsewhere it moves continuously.
    probs = gaussian(5.0, 0.2)
    free = hedged_point(probs, low=4.0, high=6.0, soft=3.7, limit=6.83)
    high = free + 0.5 * (free - 4.0) / 1023  # the minimum half a grid step short of the interval's end
    assert hedged_point(probs, low=4.0, high=high, soft=3.7, limit=6.83) == pytest.approx(free, abs=1e-4)


def test_an_interval_starting_exactly_at_the_limit_is_not_wholly_above_it():
    probs = gaussian(7.5, 0.2)  # P(E >= 1e7 Pa) about 0.994, under p_rigid below
    median, half = float(quantile(probs, 0.5)[0]), float(spread(probs)[0])
    scale = (median - 7.0) / half
    for _ in range(64):  # the scale whose calibrated interval starts at log10 E = 7.0 exactly
        if median - scale * half == 7.0:
            break
        scale = np.nextafter(scale, math.inf if median - scale * half > 7.0 else -math.inf)
    assert median - scale * half == 7.0
    said = describe(probs, scale=float(scale), limit_pa=LIMIT_PA, soft_pa=SOFT_PA, p_rigid=0.999)
    assert (said.state, said.e_pa, said.low_pa) == ("ok", LIMIT_PA, LIMIT_PA)


def _first_non_negative_slope(probs: np.ndarray, *, low: float, high: float, soft: float, limit: float) -> float:
    """Brute force: where the hedging loss's slope (:func:`hedged_point`) first turns non-negative, on a fine grid."""
    cdf = np.concatenate([[0.0], np.cumsum(probs) / probs.sum()])

    def clipped(x: np.ndarray) -> np.ndarray:
        return np.where(x >= limit, 1.0, np.where(x < soft, 0.0, np.interp(x, EDGES_LOG10, cdf)))

    v = np.linspace(max(low, soft), min(high, limit), 20001)
    slope = 2.0 * clipped(v) - 1.0 + HEDGE_WEIGHT * (clipped(v - HEDGE_FROM_DECADES) + clipped(v + HEDGE_FROM_DECADES) - 1.0)
    rising = np.flatnonzero(slope >= 0.0)
    return float(v[rising[0]]) if rising.size else min(high, limit)


@pytest.mark.parametrize(("probs", "low", "high"), [
    (0.45 * gaussian(5.9, 0.05) + 0.55 * gaussian(8.0, 0.05), 5.0, 6.83),
    (0.6 * gaussian(4.5, 0.1) + 0.4 * gaussian(5.6, 0.1), 3.8, 6.3),
    (gaussian(5.3, 0.4), 4.0, 6.6),
])
def test_the_value_is_where_the_losss_slope_turns_non_negative(probs, low, high):
    expected = _first_non_negative_slope(probs, low=low, high=high, soft=3.7, limit=6.83)
    assert hedged_point(probs, low=low, high=high, soft=3.7, limit=6.83) == pytest.approx(expected, abs=1e-3)


def test_widening_does_not_let_the_value_leave_the_calibrated_interval():
    # The loss's minimum lies below the calibrated interval (between the modes): the value stays at its low end.
    probs = 0.45 * gaussian(5.9, 0.05) + 0.55 * gaussian(7.5, 0.05)
    said = {w: describe(probs, scale=0.3, limit_pa=CENSOR_PA, soft_pa=SOFT_PA, p_rigid=0.9, widen=w) for w in (1.0, 3.0)}
    assert said[1.0].state == said[3.0].state == "ok"
    assert said[1.0].e_pa == said[1.0].low_pa == said[3.0].e_pa > said[3.0].low_pa
