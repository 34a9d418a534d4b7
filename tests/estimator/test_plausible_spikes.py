"""One-sample force spikes: dropped and named before the loading phase is found; steps and noise kept."""

from __future__ import annotations

import numpy as np

from estimator.load_phase import find_load_phase
from estimator.plausible import implausible_forces

DT_S = 0.0125  # an HX711 at 80 Hz
T = np.arange(0.0, 3.0, DT_S)
T_CONTACT_S, T_PEAK_S = 0.8, 1.4
HOLD_N = 10.0


def grasp_force(rng: np.random.Generator, noise_n: float = 0.02) -> np.ndarray:
    """A 10 N grasp: rest, loading from 0.8 s to 1.4 s, then a hold, with reading noise."""
    ramp = np.clip((T - T_CONTACT_S) / (T_PEAK_S - T_CONTACT_S), 0.0, 1.0)
    return HOLD_N * ramp + rng.normal(0.0, noise_n, T.size)


def widths() -> tuple[np.ndarray, np.ndarray]:
    tw = np.arange(0.0, 3.0, 1 / 30)
    return tw, np.where(tw < T_PEAK_S, 0.05 - 0.01 * np.clip(tw - T_CONTACT_S, 0.0, None), 0.044)


def test_a_one_sample_spike_in_the_hold_is_dropped_and_named():
    force = grasp_force(np.random.default_rng(1))
    glitch = int(np.searchsorted(T, T_PEAK_S + 0.8))
    force[glitch] = 20.0
    dropped, note, refused = implausible_forces(force, max_force_n=30.0)
    assert not refused
    assert np.flatnonzero(dropped).tolist() == [glitch]
    assert "dropped 1 force samples" in note and "20 N" in note

    phase = find_load_phase(T, force, *widths(), contact_force_n=0.75, max_force_n=30.0)
    assert phase and "implausible_force" in phase.flags
    assert any("20 N" in n for n in phase.notes)
    # The loading ends at the real peak, not at the glitch 0.8 s into the hold.
    assert phase.force_n.max() < 11.0
    assert phase.force_t_s[phase.peak] < T_PEAK_S + 0.1


def test_a_spike_beside_a_force_beyond_the_limit_is_named_with_it():
    force = grasp_force(np.random.default_rng(2))
    force[200], force[230] = 95.0, 19.0
    dropped, note, refused = implausible_forces(force, max_force_n=30.0)
    assert not refused and np.flatnonzero(dropped).tolist() == [200, 230]
    assert "beyond 60 N" in note and "19 N" in note


def test_a_step_that_stays_up_and_a_noisy_hold_are_kept():
    rng = np.random.default_rng(3)
    # A rigid object loaded between two reads: the force jumps to 10 N and holds there.
    step = np.where(T < T_CONTACT_S, 0.0, HOLD_N) + rng.normal(0.0, 0.02, T.size)
    noisy = grasp_force(rng, noise_n=0.2)
    ripple = grasp_force(rng) + 0.3 * np.sin(2 * np.pi * 15.0 * T)  # a hold's ripple of a few noises
    for force in (step, noisy, ripple):
        dropped, note, _ = implausible_forces(force, max_force_n=30.0)
        assert not dropped.any() and note == ""
    # A step down, a release within one read, is kept too.
    release = np.where(T < 2.0, HOLD_N, 0.0) + rng.normal(0.0, 0.02, T.size)
    assert not implausible_forces(release, max_force_n=30.0)[0].any()
