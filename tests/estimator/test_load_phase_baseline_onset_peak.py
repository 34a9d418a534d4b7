"""What :func:`estimator.load_phase.find_load_phase` finds before and at the loading: the baseline (the tare
well before contact, robust to a knock, from three quiet samples on), the force noise (from the rest, not
the load), the onset (where the force leaves a floor of its baseline, and how fast the fingers closed up to
it), the peak (within the noise of the maximum), and the flags and notes it leaves on records that start
in contact, widths that start late, a loading of one sample, a hold that is quiet but not saturated."""

from __future__ import annotations

import math
import re

import numpy as np
import pytest

from estimator.load_phase import find_load_phase


def phase_of(t, force, *, tw=None, width=None, contact_force_n=0.75, stopped_s=None):
    """The load phase of ``force`` at ``t``, with widths closing 1 mm/s at ``t`` unless given."""
    if tw is None:
        tw, width = t, 0.05 - 0.001 * t
    return find_load_phase(t, force, tw, width, contact_force_n=contact_force_n, stopped_s=stopped_s)


def ramp(t, *, start_s=1.0, rate_n_s=10.0, peak_n=15.0):
    """A force still at 0 until ``start_s``, then rising at ``rate_n_s`` to ``peak_n`` and holding."""
    return np.clip((t - start_s) * rate_n_s, 0.0, peak_n)


# --------------------------------------------------------------------------- baseline and noise


def test_the_baseline_ignores_the_rise_in_the_last_moments_before_contact():
    # 40 ms of rest at a 0.3 N tare, then 45 ms of rise to contact (at 1000 Hz): more rise than rest before
    # contact, but the rise within BASELINE_GUARD_S of contact does not count.
    t = np.arange(0.96, 3.5, 1e-3)
    phase = phase_of(t, ramp(t) + 0.3)
    assert phase, phase.reason
    assert phase.force_baseline_n == pytest.approx(0.3, abs=1e-9)


@pytest.mark.parametrize(("rest_samples", "baseline_n"), [(9, 0.3), (8, 0.0)])
def test_three_quiet_samples_give_a_baseline_and_two_do_not(rest_samples, baseline_n):
    # At 128 Hz, BASELINE_GUARD_S (50 ms) before contact leaves three samples of a rest nine long, two of
    # one eight long.
    t = np.arange(0, 256) / 128
    force = np.where(np.arange(t.size) < rest_samples, 0.3, 1.1 + 0.1 * (np.arange(t.size) - rest_samples))
    phase = phase_of(t, np.minimum(force, 15.0))
    assert phase, phase.reason
    assert phase.force_baseline_n == pytest.approx(baseline_n, abs=1e-12)


def test_a_knock_on_the_load_cell_at_rest_leaves_the_baseline_at_the_tare():
    t = np.arange(0.0, 3.5, 0.01)
    force = ramp(t) + 0.3
    force[40] += 0.4  # a knock, still below contact
    phase = phase_of(t, force)
    assert phase, phase.reason
    assert phase.force_baseline_n == pytest.approx(0.3, abs=1e-12)


def test_the_force_noise_is_the_rests_not_that_of_a_load_cell_noisier_under_load():
    rng = np.random.default_rng(5)
    t = np.arange(0.0, 5.0, 0.01)
    noise = np.where(t < 1.0, 0.01, 0.1)  # 1 s of rest read at 10 mN, 4 s under load at 0.1 N
    phase = phase_of(t, ramp(t) + rng.normal(0.0, 1.0, t.size) * noise, stopped_s=2.5)
    assert phase, phase.reason
    assert 0.007 < phase.segment_fields["force_noise_n"] < 0.013


# --------------------------------------------------------------------------- onset


def test_a_load_cell_drifting_a_hair_at_rest_keeps_the_onset_at_the_touch():
    # 5 mN of slow drift over the rest (a third of the onset floor, 2 % of contact_force_n), noise-free:
    # the samples above the baseline's median are not yet in contact.
    t = np.arange(0.0, 3.5, 0.01)
    force = np.where(t < 1.0, 0.005 * t, 0.005 + ramp(t))
    phase = phase_of(t, force)
    assert phase, phase.reason
    assert 1.0 <= phase.segment_fields["t_onset_s"] < 1.01


def test_the_onset_width_deviation_takes_the_closing_speed_up_to_the_onset():
    # The fingers close at 1 mm/s, at 2 mm/s over the last width read up to the onset (one read exactly at
    # it), and at 4 mm/s after it; contact comes 0.37 s after the onset, past three more reads.
    t = np.arange(0.0, 4.0, 0.01)
    force = ramp(t, rate_n_s=2.0, peak_n=3.0)
    t_onset = phase_of(t, force).segment_fields["t_onset_s"]
    k = np.arange(-10, 26)
    tw = t_onset + 0.1 * k
    width = 0.05 - np.cumsum(np.where(k < 0, 1e-4, np.where(k == 0, 2e-4, 4e-4)))
    phase = phase_of(t, force, tw=tw, width=width)
    assert phase, phase.reason
    fields = phase.segment_fields
    assert fields["t_onset_s"] == t_onset and fields["t_contact_s"] > t_onset + 0.3
    assert fields["onset_width_sigma_m"] == pytest.approx(2e-3 * 0.01 / math.sqrt(12.0), rel=1e-6)


def test_a_record_that_starts_in_contact_is_misaligned_with_the_onset_at_its_first_sample():
    t = np.arange(0.0, 3.0, 0.01)
    phase = phase_of(t, 2.0 + ramp(t, start_s=0.0))
    assert phase, phase.reason
    assert phase.segment_fields["t_onset_s"] == t[0]
    assert "misaligned" in phase.flags
    assert any("starts in contact" in note for note in phase.notes)


def test_widths_starting_after_the_onset_are_misaligned_and_said_so():
    # Onset at 1.0 s, contact at 1.075 s: the first width read at 1.03 s covers the loading, not the onset.
    t = np.arange(0.0, 3.5, 0.01)
    tw = np.arange(1.03, 3.5, 0.02)
    phase = phase_of(t, ramp(t), tw=tw, width=0.05 - 0.001 * tw)
    assert phase, phase.reason
    assert math.isnan(phase.segment_fields["onset_width_m"])
    assert "misaligned" in phase.flags
    assert [note for note in phase.notes if "no width sample around the contact onset" in note]
    assert phase.segment_fields["load_force_n"].size == phase.peak - phase.contact + 1  # the loading is covered


# --------------------------------------------------------------------------- peak and loading


def test_the_peak_is_the_first_sample_within_three_noise_deviations_of_the_maximum():
    # Rest read with 0.05 N of noise; a clean rise to 5 N at 1.5 s, then a creep of 0.12 N over 3 s
    # (beyond 1 % of the peak, within three deviations): the creep is hold, not loading.
    rng = np.random.default_rng(7)
    t = np.arange(0.0, 4.5, 0.01)
    force = np.interp(t, [0, 1, 1.5, 4.5], [0, 0, 5, 5.12]) + np.where(t < 1.0, rng.normal(0.0, 0.05, t.size), 0.0)
    phase = phase_of(t, force, stopped_s=1.5)
    assert phase, phase.reason
    assert 1.45 < phase.segment_fields["t_peak_s"] < 1.51


def test_a_loading_of_one_force_sample_is_flagged():
    t = np.arange(0.0, 2.0, 0.01)
    phase = phase_of(t, np.where(t >= 1.0, 20.0, 0.0), stopped_s=1.0)
    assert phase, phase.reason
    assert phase.contact == phase.peak
    assert "too_few_samples" in phase.flags
    assert any("single force sample" in note for note in phase.notes)


def test_a_width_read_only_at_the_onset_itself_leaves_the_loading_unread():
    # Loaded within one force sample; a width is read at the onset instant, the next 0.5 s later: none
    # between the onset and the peak, so the approach over the loading is still interpolated blind.
    t = np.arange(0.0, 2.0, 0.01)
    force = np.where(t >= 1.0, 20.0, 0.0)
    t_onset = phase_of(t, force, stopped_s=1.0).segment_fields["t_onset_s"]
    tw = np.array([0.5, t_onset, 1.5, 2.0])
    phase = phase_of(t, force, tw=tw, width=np.array([0.05, 0.0495, 0.048, 0.048]), stopped_s=1.0)
    assert phase, phase.reason
    assert phase.segment_fields["t_onset_s"] == t_onset
    assert "width_unread" in phase.flags


def test_a_quiet_hold_of_distinct_readings_is_no_saturation():
    # Read with 0.1 mN of noise throughout: the hold's readings stay within a millinewton of the top, but no
    # two are identical.
    rng = np.random.default_rng(3)
    t = np.arange(0.0, 3.5, 0.01)
    phase = phase_of(t, ramp(t) + rng.normal(0.0, 1e-4, t.size))
    assert phase, phase.reason
    assert "clipped" not in phase.flags


def test_a_width_stream_ending_in_the_loading_leaves_force_and_width_at_the_same_times():
    t = np.arange(0.0, 3.5, 0.01)
    tw = np.arange(0.0, 1.8, 0.02)  # the widths stop 0.7 s before the peak
    phase = phase_of(t, ramp(t), tw=tw, width=0.05 - 0.001 * tw)
    assert phase, phase.reason
    fields = phase.segment_fields
    assert "misaligned" in phase.flags
    assert fields["load_t_s"].size == fields["load_force_n"].size == fields["load_width_m"].size > 10
    assert np.all(fields["load_t_s"] <= tw[-1]) and np.all(np.isfinite(fields["load_width_m"]))
    np.testing.assert_array_equal(fields["load_force_n"], np.interp(fields["load_t_s"], t, ramp(t)))


def test_the_envelope_description_times_the_loading_from_the_interpolated_contact():
    # Contact (0.72 N) at 1.072 s, between the samples at 1.07 and 1.08 s.
    t = np.arange(0.0, 3.5, 0.01)
    phase = phase_of(t, ramp(t), contact_force_n=0.72)
    assert phase, phase.reason
    fields = phase.segment_fields
    duration = float(re.search(r"envelope over (\d+\.\d+) s", fields["loading"]).group(1))
    assert f"{duration:.2f}" == f"{fields['t_peak_s'] - fields['t_contact_s']:.2f}"
    assert f"{duration:.2f}" != f"{fields['t_peak_s'] - t[phase.contact]:.2f}"


# --------------------------------------------------------------------------- widths that open


def test_widths_opening_while_the_force_stays_within_its_noise_are_not_refused():
    # The rest and the rise up to 1.7 s are read with 10 mN of noise; from contact to the peak the force rises
    # within the noise of two readings while the widths open by 50 um: not the squeeze the refusal is for.
    rng = np.random.default_rng(11)
    t = np.arange(0.0, 3.0, 0.01)
    force = np.interp(t, [0, 1, 1.9, 3], [0, 0, 0.8, 0.8]) + np.where(t < 1.7, rng.normal(0, 0.01, t.size), 0.0)
    tw = np.arange(0.0, 3.0, 0.005)
    width = 0.05 + np.interp(tw, [0, 1.8, 1.9, 3], [0, 0, 5e-5, 5e-5])
    phase = phase_of(t, force, tw=tw, width=width)
    assert phase, phase.reason
    loading = phase.segment_fields["load_width_m"]
    assert loading[-1] - loading[0] > 3.0 * math.sqrt(2.0) * 1e-6  # they do open beyond their noise
    rose = phase.segment_fields["load_force_n"][-1] - phase.segment_fields["load_force_n"][0]
    assert 0 < rose < 3.0 * math.sqrt(2.0) * phase.segment_fields["force_noise_n"]
