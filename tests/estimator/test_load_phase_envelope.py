"""What the load phase finds in a grasp: the loading envelope's description (``Segment.loading``) of an
operator's grasp, where a pause is the force standing still for a real time and a back-off a sustained
fall beyond the noise; which samples the envelope keeps; the baseline, the onset, saturation and a stop
time; widths that open instead of closing."""

from __future__ import annotations

import re

import numpy as np

from estimator.load_phase import find_load_phase

RATE_HZ = 80.0
NOISE_N = 0.012


def describe(knots_t_s, knots_n, *, noise_n=NOISE_N, hold_noise_n=None, seed=0, spike=None):
    """The envelope description of a grasp whose force follows the piecewise-linear ``knots`` with
    white noise (``hold_noise_n`` from 1.5 s: a load cell that reads noisier under load), widths
    closing with the force, and ``spike`` (time, newtons) added to the one sample nearest it."""
    rng = np.random.default_rng(seed)
    t = np.arange(knots_t_s[0], knots_t_s[-1], 1 / RATE_HZ)
    noise = np.where(t > 1.5, hold_noise_n or noise_n, noise_n)
    force = np.interp(t, knots_t_s, knots_n) + rng.normal(0.0, 1.0, t.size) * noise
    if spike:
        force[np.argmin(np.abs(t - spike[0]))] += spike[1]
    tw = np.arange(knots_t_s[0], knots_t_s[-1], 0.1)
    width = 0.05 - np.interp(tw, knots_t_s, knots_n) / 15 * 0.005
    phase = find_load_phase(t, force, tw, width, contact_force_n=0.75, max_width_m=0.08, max_force_n=30.0)
    assert phase, phase.reason
    return phase.segment_fields["loading"]


def paused_s(loading: str) -> float:
    found = re.search(r"paused (\d+\.\d+) s", loading)
    return float(found.group(1)) if found else 0.0


def test_a_slow_steady_close_is_not_called_paused():
    loading = describe([0, 1, 31, 32], [0, 0, 15, 15])  # 30 s at 0.5 N/s, never still
    assert "paused" not in loading and "back-off" not in loading


def test_a_long_still_hold_is_one_pause_not_hundreds_of_back_offs():
    # 1 s to 6.7 N, 60 s still (the load cell three times noisier under load), 1 s to 15 N.
    loading = describe([0, 1, 2, 62, 63, 64], [0, 0, 6.7, 6.7, 15, 15], hold_noise_n=3 * NOISE_N)
    assert "back-off" not in loading
    assert 59.5 < paused_s(loading) < 61.0


def test_an_object_relaxing_while_the_fingers_hold_still_is_paused_not_backed_off():
    # The force relaxes by 4 % over a 60 s still hold: far slower than the fingers ever moved.
    loading = describe([0, 1, 2, 62, 63, 64], [0, 0, 6.7, 6.43, 15, 15])
    assert "back-off" not in loading
    assert 59.5 < paused_s(loading) < 61.0


def test_a_single_noise_sample_in_a_pause_is_not_a_back_off():
    loading = describe([0, 1, 2, 3, 4, 5], [0, 0, 6.0, 6.0, 12.0, 12.0], spike=(2.5, -0.4))
    assert "back-off" not in loading
    assert 0.9 < paused_s(loading) < 1.2


def test_a_stiffening_close_is_not_called_paused():
    # A foam closed steadily: the force rises slowly, then steeply as it compacts.
    t = np.linspace(1.0, 3.0, 41)
    loading = describe(np.concatenate([[0.0], t]), np.concatenate([[0.0], 0.8 + 29 * ((t - 1) / 2) ** 6]))
    assert "paused" not in loading and "back-off" not in loading


def test_a_real_pause_and_a_real_back_off_and_re_squeeze_are_named():
    # Up to 5 N, still for 1 s, up to 8 N, back off to 3 N and squeeze again up to 12 N.
    loading = describe([0, 1, 1.5, 2.5, 2.8, 3.1, 3.7, 4.5, 5], [0, 0, 5, 5, 8, 3, 8, 12, 12])
    assert "1 back-off and re-squeeze skipped" in loading
    assert 0.9 < paused_s(loading) < 1.2


def ramp_grasp(*, noise_n=0.0, tare_n=0.0, seed=0, rate_hz=100.0, width_open_m=0.0, stopped_s=None, start_s=0.0):
    """The load phase of a grasp whose force is still until 1 s, rises at 10 N/s to 15 N at 2.5 s, then
    holds; widths close 2.5 mm over the loading (or open by ``width_open_m`` instead)."""
    rng = np.random.default_rng(seed)
    t = np.arange(start_s, 3.5, 1 / rate_hz)
    force = np.interp(t, [0, 1, 2.5, 3.5], [0, 0, 15, 15]) + tare_n + rng.normal(0, 1, t.size) * noise_n
    tw = np.arange(start_s, 3.5, 0.02)
    if width_open_m:
        width = 0.05 + np.interp(tw, [0, 1, 2.5, 3.5], [0, 0, width_open_m, width_open_m])
    else:
        width = 0.05 - np.interp(tw, [0, 1, 2.5, 3.5], [0, 0, 0.0025, 0.0025])
    return find_load_phase(t, force, tw, width, contact_force_n=0.75, stopped_s=stopped_s,
                           max_width_m=0.08, max_force_n=30.0)


def test_an_operator_grasp_rising_steadily_keeps_every_loading_sample():
    phase = ramp_grasp(noise_n=0.1, seed=2)  # no stop reported: the loading envelope; noise as large as a step
    assert phase, phase.reason
    assert phase.envelope
    assert phase.segment_fields["load_force_n"].size == phase.peak - phase.contact + 1


def test_widths_opening_a_little_beyond_their_noise_refuse_the_grasp():
    phase = ramp_grasp(width_open_m=2e-5)  # 20 um against a 1 um reading noise floor
    assert not phase
    assert "widths open" in phase.reason
    assert "implausible_width" in phase.flags


def test_the_baseline_is_the_tare_before_contact_not_the_rise():
    phase = ramp_grasp(tare_n=0.3, rate_hz=1000.0, start_s=0.95)  # 50 ms of rest before the rise at 1 s
    assert phase, phase.reason
    assert abs(phase.force_baseline_n - 0.3) < 1e-9


def test_a_noisy_baseline_keeps_the_onset_below_half_the_contact_force():
    # Baseline noise 0.2 N: four deviations exceed contact_force_n, so the onset level is capped at
    # half of it and the onset lies well before contact (the rise is 10 N/s: 0.375 N is 37 ms early).
    phase = ramp_grasp(noise_n=0.2, seed=3)
    assert phase, phase.reason
    fields = phase.segment_fields
    assert fields["t_contact_s"] - fields["t_onset_s"] > 0.015


def test_a_stop_time_that_is_not_finite_is_no_stop():
    nan_stop, no_stop = ramp_grasp(noise_n=0.01, seed=4, stopped_s=float("nan")), ramp_grasp(noise_n=0.01, seed=4)
    assert nan_stop and no_stop
    assert nan_stop.stopped_s is None and nan_stop.envelope
    np.testing.assert_array_equal(nan_stop.segment_fields["load_width_m"], no_stop.segment_fields["load_width_m"])


def test_two_identical_top_readings_are_no_saturation():
    t = np.arange(0.0, 3.0, 0.01)
    force = np.interp(t, [0, 1, 2, 3], [0, 0, 15, 10]) + np.random.default_rng(1).normal(0, 0.01, t.size)
    top = int(np.argmax(force))
    force[top + 1] = force[top]
    phase = find_load_phase(t, force, t, 0.05 - 1e-4 * np.minimum(t, 2.0), contact_force_n=0.75)
    assert phase, phase.reason
    assert "clipped" not in phase.flags
