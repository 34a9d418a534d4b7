"""What the analytical estimators' intervals and bounds rest on: each noise term's share, frames left
out of a fit, bounds from truncated frames, and refusals, checked against the closed forms."""

from __future__ import annotations

import importlib.util
import math
from pathlib import Path

import numpy as np
import pytest
from scipy import special

from estimator.analytical import elastic, hertz, no_tactile, series
from estimator.errors import FitError
from estimator.linefit import MeasurementNoise

_spec = importlib.util.spec_from_file_location("_analytical_series", Path(__file__).with_name("test_analytical.py"))
_series = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(_series)
uniaxial_series, hertz_series = _series.uniaxial_series, _series.hertz_series
K_GEL, NU, W0, PAD_AREA, NOISY = _series.K_GEL, _series.NU, _series.W0, _series.PAD_AREA, _series.NOISY
Z = float(special.ndtri(0.975))  # the two-sided 95 % normal quantile


def resolution_half_width(stress_pa, width_sigma_m):
    """C's half-width from width noise alone: z * sigma_strain / sqrt(Sxx), sigma_strain = width / w0."""
    return Z * (width_sigma_m / W0) / math.sqrt(float(((stress_pa - stress_pa.mean()) ** 2).sum()))


# --------------------------------------------------------------------------- Hooke: each noise term


def test_no_tactile_width_noise_gives_the_documented_interval():
    noise = MeasurementNoise(width_m=2e-5)
    force, approach, _ = uniaxial_series(2e6, n=6)
    est = no_tactile(force, approach, initial_width_m=W0, pad_area_m2=PAD_AREA, noise=noise)
    c, half = 1 / 2e6, resolution_half_width(force / PAD_AREA, noise.width_m)
    assert est.state == "ok"
    assert est.interval_pa[0] == pytest.approx(1 / (c + half), rel=1e-6)
    assert est.interval_pa[1] == pytest.approx(1 / (c - half), rel=1e-6)


def test_no_tactile_force_noise_widens_the_interval():
    force, approach, _ = uniaxial_series(2e6, n=6)
    quiet = no_tactile(force, approach, initial_width_m=W0, pad_area_m2=PAD_AREA,
                       noise=MeasurementNoise(width_m=2e-5))
    noisy = no_tactile(force, approach, initial_width_m=W0, pad_area_m2=PAD_AREA,
                       noise=MeasurementNoise(width_m=2e-5, force_n=0.5))
    assert quiet.state == noisy.state == "ok"
    assert noisy.interval_pa[1] - noisy.interval_pa[0] > 1.05 * (quiet.interval_pa[1] - quiet.interval_pa[0])


def test_single_frame_carries_the_onset_uncertainty():
    # One frame is fitted through the onset: C = strain / stress, half-width z * (onset_width / w0) / stress.
    noise = MeasurementNoise(onset_width_m=1e-4)
    force, approach = np.array([10.0]), np.array([10.0 / (PAD_AREA * 2e6) * W0 / 2])
    est = no_tactile(force, approach, initial_width_m=W0, pad_area_m2=PAD_AREA, noise=noise)
    stress, c = 10.0 / PAD_AREA, 1 / 2e6
    half = Z * (noise.onset_width_m / W0) / stress
    assert est.state == "ok"
    assert est.interval_pa[0] == pytest.approx(1 / (c + half), rel=1e-6)
    assert est.interval_pa[1] == pytest.approx(1 / (c - half), rel=1e-6)


def test_two_frames_are_fitted_through_the_onset():
    stress = np.array([1e4, 2e4])
    strain = np.array([0.01, 0.0201])  # through the onset C = 1.004e-6; the chord (an intercept fit) 1.01e-6
    est = no_tactile(stress * PAD_AREA, strain * W0 / 2, initial_width_m=W0, pad_area_m2=PAD_AREA,
                     noise=MeasurementNoise(width_m=1e-7))
    assert est.state == "ok"
    assert est.e_pa == pytest.approx(1 / float(stress @ strain / (stress @ stress)), rel=1e-9)


def test_negative_compliance_gives_a_lower_bound_at_the_resolution():
    noise = MeasurementNoise(width_m=2e-5)
    force, approach, _ = uniaxial_series(2e6, n=6)
    est = no_tactile(force, -approach, initial_width_m=W0, pad_area_m2=PAD_AREA, noise=noise)  # strain falls
    assert est.state == "lower_bound"
    assert est.e_pa == pytest.approx(1 / resolution_half_width(force / PAD_AREA, noise.width_m), rel=1e-6)


def test_no_tactile_without_a_finite_sample_says_so():
    est = no_tactile(np.full(3, np.nan), np.ones(3), initial_width_m=W0, pad_area_m2=PAD_AREA)
    assert est.state == "insufficient_data"
    assert "no loading sample with finite force and width" in est.reason


# --------------------------------------------------------------------------- frames left out, truncated frames


@pytest.mark.parametrize("method", ["elastic", "series"])
def test_depth_falling_beyond_its_noise_is_refused(method):
    noise = MeasurementNoise(width_m=2e-5, depth_m=2e-5)
    n = 8
    approach = np.linspace(0.1e-3, 2e-3, n)
    depth = np.linspace(0.05e-3, 0.5e-3, n)
    depth[-1] = depth[-2] - 10 * noise.depth_m  # falls by 10 noise deviations while the approach grows
    if method == "elastic":
        est = elastic(np.linspace(1, 20, n), approach, depth, np.full(n, 1e-4), initial_width_m=W0, noise=noise)
    else:
        est = series(approach, depth, gel_compliance_per_pa=K_GEL, object_poisson=NU, noise=noise)
    assert est.state == "insufficient_data"
    assert "falls" in est.reason


def elastic_on(force, approach, depth, area, **options):
    return elastic(force, approach, depth, area, initial_width_m=W0,
                   noise=MeasurementNoise(width_m=2e-5, force_n=0.02), **options)


def test_elastic_skips_frames_without_contact_area():
    force, approach, depth = uniaxial_series(1e6, area_m2=1e-4, n=6)
    area = np.full(force.size, 1e-4)
    base = elastic_on(force, approach, depth, area)
    with_gap = elastic_on(np.r_[0.3, force], np.r_[1e-6, approach], np.r_[0.0, depth], np.r_[0.0, area])
    assert base.state == with_gap.state == "ok"
    assert with_gap.e_pa == pytest.approx(base.e_pa, rel=1e-12)
    assert with_gap.interval_pa == pytest.approx(base.interval_pa, rel=1e-12)


def test_elastic_on_truncated_frames_only_is_bounded_by_the_interval_top():
    force, approach, depth = uniaxial_series(1e6, area_m2=1e-4, n=6)
    area = np.full(force.size, 1e-4)
    full = elastic_on(force, approach, depth, area)
    cut = elastic_on(force, approach, depth, area, truncated=np.ones(force.size, bool))
    assert full.state == "ok" and cut.state == "upper_bound"
    assert cut.e_pa == pytest.approx(full.interval_pa[1], rel=1e-12)


def test_hertz_on_truncated_frames_only_is_bounded_by_the_interval_bottom():
    f, ap, d, a = hertz_series(1e5)
    kw = dict(gel_compliance_per_pa=K_GEL, object_poisson=NU, noise=NOISY)
    full = hertz(f, ap, d, a, **kw)
    cut = hertz(f, ap, d, a, truncated=np.ones(f.size, bool), **kw)
    assert full.state == "ok" and cut.state == "lower_bound"
    assert cut.e_pa == pytest.approx(full.interval_pa[0], rel=1e-12)


def test_hertz_skips_frames_without_depth():
    f, ap, d, a = hertz_series(1e5)
    kw = dict(gel_compliance_per_pa=K_GEL, object_poisson=NU, noise=NOISY)
    base = hertz(f, ap, d, a, **kw)
    extra = hertz(np.r_[0.1, f], np.r_[ap[0] / 10, ap], np.r_[0.0, d], np.r_[a[0] / 3, a], **kw)
    assert base.state == extra.state
    assert extra.e_pa == pytest.approx(base.e_pa, rel=1e-12)
    assert extra.interval_pa == pytest.approx(base.interval_pa, rel=1e-12)


# --------------------------------------------------------------------------- series compliance


def test_series_gel_within_its_noise_gives_the_documented_upper_bound():
    # Max depth 2 sigma (within 3 sigma): E <= (1 - nu^2) / k_lo, k_lo = (max gap - 2 sigma_gap) k_gel / (3 sigma_d).
    noise = MeasurementNoise(width_m=2e-5, depth_m=2e-5)
    approach = np.linspace(0.1e-3, 2e-3, 8)
    depth = np.linspace(0.0, 2 * noise.depth_m, 8)
    est = series(approach, depth, gel_compliance_per_pa=K_GEL, object_poisson=NU, noise=noise)
    sigma_gap = math.hypot(noise.approach_m, noise.depth_m)
    k_lo = (float(np.max(approach - depth)) - 2 * sigma_gap) / (3 * noise.depth_m / K_GEL)
    assert est.state == "upper_bound"
    assert est.e_pa == pytest.approx((1 - NU**2) / k_lo, rel=1e-9)


def test_series_two_frames_carry_the_onset_uncertainty():
    approach = np.array([1e-3, 2e-3])
    depth = approach * 0.6
    kw = dict(gel_compliance_per_pa=K_GEL, object_poisson=NU)
    sharp = series(approach, depth, noise=MeasurementNoise(width_m=2e-5, depth_m=2e-5), **kw)
    blurred = series(approach, depth, noise=MeasurementNoise(width_m=2e-5, depth_m=2e-5, onset_width_m=2e-4), **kw)
    assert sharp.state == "ok" and blurred.state in ("ok", "lower_bound")
    assert blurred.interval_pa[0] < 0.9 * sharp.interval_pa[0]


def test_series_depth_scale_error_moves_gap_and_lever_together():
    # Exact data, a depth scale error s only: k_object's half-width is z * s * (k_gel + k_object).
    e_pa, s = 2e5, 0.05
    k_obj = (1 - NU**2) / e_pa
    approach = np.linspace(0.1e-3, 2e-3, 8)
    depth = K_GEL / (K_GEL + k_obj) * approach
    est = series(approach, depth, gel_compliance_per_pa=K_GEL, object_poisson=NU,
                 noise=MeasurementNoise(depth_scale=s))
    half = Z * s * (K_GEL + k_obj)
    assert est.state == "ok"
    assert est.interval_pa[0] == pytest.approx((1 - NU**2) / (k_obj + half), rel=1e-6)
    assert est.interval_pa[1] == pytest.approx((1 - NU**2) / (k_obj - half), rel=1e-6)


def test_series_bulk_ignores_negative_forces():
    approach = np.linspace(0.1e-3, 2e-3, 8)
    depth = 0.6 * approach
    force = np.linspace(0.0, 20.0, 8)
    kw = dict(gel_compliance_per_pa=K_GEL, object_poisson=NU, noise=MeasurementNoise(width_m=2e-5, depth_m=2e-5),
              initial_width_m=W0)
    clamped = series(approach, depth, force_n=force, **kw)
    tared_low = series(approach, depth, force_n=np.r_[-0.5, force[1:]], **kw)  # a baseline read below zero
    assert clamped.state == tared_low.state == "ok"
    assert tared_low.e_pa == pytest.approx(clamped.e_pa, rel=1e-12)


@pytest.mark.parametrize(("call", "named"), [
    (lambda: no_tactile(np.ones(3), np.ones(3), initial_width_m=0.0, pad_area_m2=PAD_AREA), "initial_width_m"),
    (lambda: no_tactile(np.ones(3), np.ones(3), initial_width_m=W0, pad_area_m2=0.0), "pad_area_m2"),
    (lambda: hertz(np.ones(3), np.ones(3), np.ones(3), np.ones(3), gel_compliance_per_pa=0.0, object_poisson=NU),
     "gel_compliance_per_pa"),
    (lambda: series(np.ones(3), np.ones(3), gel_compliance_per_pa=0.0, object_poisson=NU), "gel_compliance_per_pa"),
])
def test_a_zero_width_area_or_gel_compliance_is_refused_by_name(call, named):
    with pytest.raises(FitError, match=f"{named} must be a finite real number > 0"):
        call()
