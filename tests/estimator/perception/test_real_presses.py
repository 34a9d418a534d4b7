"""Calibrate on half of taxim's real presses, reconstruct the other half: spheres of the ball's radius.

GelSight (48 presses) and GelSight Mini (24 presses), both 480x640 at 0.0295 mm/px
(taxim's params.json for each) with a 2.0 mm ball; the Mini set states no ball
radius of its own, the same 2.0 mm ball is assumed (its largest recorded contact
radius, 57 px = 1.68 mm, fits it).
"""

from __future__ import annotations

import numpy as np
import pytest

from estimator.perception import fit_sphere, reconstruct_depth, split_presses

BALL_RADIUS_M = 2.0e-3

pytestmark = pytest.mark.slow


def held_out_fits(presses, calibration):
    held_out = np.setdiff1d(np.arange(len(presses)), split_presses(len(presses), 0.5))
    fits = [fit_sphere(reconstruct_depth(presses.images[i], presses.reference, calibration),
                       pixel_pitch_m=calibration.pixel_pitch_m) for i in held_out]
    assert all(fits), [f.reason for f in fits if not f]
    radii = np.array([f.radius_m for f in fits])
    centre_errors = np.array([np.hypot(*(np.array(f.center_px) - presses.centers_px[i]))
                              for f, i in zip(fits, held_out, strict=True)])
    return held_out, fits, radii, centre_errors


def test_gelsight_held_out_presses_are_spheres_of_the_ball(gelsight_presses, gelsight_calibration):
    assert gelsight_calibration.ball_radius_m == BALL_RADIUS_M
    held_out, fits, radii, centre_errors = held_out_fits(gelsight_presses, gelsight_calibration)
    assert len(held_out) == 24
    relative = np.abs(radii - BALL_RADIUS_M) / BALL_RADIUS_M
    # Measured: median radius 1.994 mm, median error 2.2%, median centre error 2.0 px.
    assert np.median(relative) < 0.05
    assert abs(np.median(radii) - BALL_RADIUS_M) < 0.05 * BALL_RADIUS_M
    assert relative.max() < 0.2
    assert np.median(centre_errors) < 5.0
    assert centre_errors.max() < 8.0


def test_mini_held_out_presses_are_spheres_of_the_ball(mini_presses, mini_calibration):
    held_out, fits, radii, centre_errors = held_out_fits(mini_presses, mini_calibration)
    relative = np.abs(radii - BALL_RADIUS_M) / BALL_RADIUS_M
    # Measured: median radius 2.07 mm (+3.5%) but a median per-press error of 5.8%:
    # shallow presses come out smaller, deep ones larger (1.71..2.21 mm).
    assert abs(np.median(radii) - BALL_RADIUS_M) < 0.05 * BALL_RADIUS_M
    assert np.median(relative) < 0.08
    # The Mini's recorded centres scatter by up to ~25 px around the press (two press sites,
    # presses 0-12 and 13-23), so they bound the centre error from below: median 6.3 px.
    assert np.median(centre_errors) < 10.0
    first_site = np.array([f.center_px for f, i in zip(fits, held_out, strict=True) if i <= 12])
    spread = np.hypot(*(first_site - np.median(first_site, axis=0)).T)
    assert spread.max() < 3.0
