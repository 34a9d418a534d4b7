"""Where the loading envelope of an operator's grasp (:mod:`estimator.load_phase`) draws the line between a
back-off and noise, a back-off and an object relaxing, a pause and a slow or noisy close: the bounds its
module notes give (five noise deviations for a back-off, a quarter of the loading's mean rate, a pause's
dwell against the bands on either side, bands no finer than the noise), each on a grasp just past it."""

from __future__ import annotations

import re

import numpy as np
import pytest

from estimator.load_phase import find_load_phase

RATE_HZ = 80.0
NOISE_N = 0.012


def describe(knots_t_s, knots_n, *, noise_n=NOISE_N, hold_noise_n=None, seed=0):
    """The envelope description (``Segment.loading``) of a grasp whose force follows the piecewise-linear
    ``knots`` with white noise (``hold_noise_n`` from 1.5 s: a load cell that reads noisier under load),
    and widths closing with the force; no stop is reported."""
    rng = np.random.default_rng(seed)
    t = np.arange(knots_t_s[0], knots_t_s[-1], 1 / RATE_HZ)
    noise = np.where(t > 1.5, hold_noise_n or noise_n, noise_n)
    force = np.interp(t, knots_t_s, knots_n) + rng.normal(0.0, 1.0, t.size) * noise
    tw = np.arange(knots_t_s[0], knots_t_s[-1], 0.1)
    width = 0.05 - np.interp(tw, knots_t_s, knots_n) / 15 * 0.005
    phase = find_load_phase(t, force, tw, width, contact_force_n=0.75, max_width_m=0.08, max_force_n=30.0)
    assert phase and phase.envelope, phase.reason
    return phase.segment_fields["loading"]


def paused_s(loading: str) -> float:
    found = re.search(r"paused (\d+\.\d+) s", loading)
    return float(found.group(1)) if found else 0.0


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_sustained_dip_within_five_noise_deviations_is_no_back_off(seed):
    # A light grasp read noisily (0.05 N): the force sags 0.2 N (4 deviations, 4 % of its peak) for half a
    # second and recovers; beyond the 2 % share, but within five deviations of the noise.
    loading = describe([0, 1, 2, 2.2, 2.5, 2.7, 3.5, 4], [0, 0, 3, 3, 2.8, 3, 4.5, 4.5], noise_n=0.05, seed=seed)
    assert "back-off" not in loading


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_back_off_slower_than_the_mean_loading_rate_is_still_a_back_off(seed):
    # Up to 8 N, eased back to 6 N over a second (2 N/s, slower than the loading's mean 3 N/s but far faster
    # than a quarter of it, which an object relaxing under still fingers stays below), squeezed up to 12 N.
    loading = describe([0, 1, 2, 3, 4, 5, 5.5], [0, 0, 8, 6, 8, 12, 12], seed=seed)
    assert "1 back-off and re-squeeze skipped" in loading
    assert "paused" not in loading  # the time backing off and squeezing back is skipped, not a pause


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_near_still_squeeze_across_a_band_edge_is_one_pause(seed):
    # Up to 6 N in half a second, then creeping 0.15 N over 2 s (1.25 % of the peak: across one band edge of
    # the rise), then up to 12 N: each of the two bands it lingers in is judged against the three bands on
    # either side, not against the other one.
    loading = describe([0, 1, 1.5, 3.5, 4, 4.5], [0, 0, 6, 6.15, 12, 12], seed=seed)
    assert 1.8 < paused_s(loading) < 2.2
    assert "back-off" not in loading


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_slow_close_read_noisily_is_not_paused(seed):
    # 10 s at 0.6 N/s, read with 0.06 N noise: the running maximum advances in noise-sized jumps, and bands
    # of the rise finer than three deviations would catch it waiting between them.
    loading = describe([0, 1, 11, 12], [0, 0, 6, 6], noise_n=0.06, seed=seed)
    assert "paused" not in loading and "back-off" not in loading


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_load_cell_far_noisier_under_load_than_at_rest_holds_still_without_back_offs(seed):
    # At rest it reads 5 mN of noise, under load 0.1 N (twenty times more): over a 60 s still hold the
    # noise of the loading itself, not the rest's, sets what a back-off must exceed.
    loading = describe([0, 1, 2, 62, 63, 64], [0, 0, 6.7, 6.7, 15, 15], noise_n=0.005, hold_noise_n=0.1, seed=seed)
    assert "back-off" not in loading
    assert 59.5 < paused_s(loading) < 61.0


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_light_close_whose_whole_rise_lies_within_the_noise_is_not_paused(seed):
    # 0.6 N/s to 1.2 N, read with 0.1 N of noise: the loading ends within three deviations of the peak, so
    # its whole rise lies in one band, with no bands around it to be judged against: a steady close.
    loading = describe([0, 1, 3, 4], [0, 0, 1.2, 1.2], noise_n=0.1, seed=seed)
    assert "paused" not in loading and "back-off" not in loading
