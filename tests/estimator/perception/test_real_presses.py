"""Calibrate on half of taxim's real presses, reconstruct the other half: spheres of the ball's radius.

GelSight (48 presses) and GelSight Mini (24 presses), both 480x640 at 0.0295 mm/px
(taxim's params.json for each) with a 2.0 mm ball; the Mini set states no ball
radius of its own, the same 2.0 mm ball is assumed (its largest recorded contact
radius, 57 px = 1.68 mm, fits it).
"""

from __future__ import annotations

import numpy as np
import pytest

from estimator.perception import (
    fit_calibration,
    fit_sphere,
    load_calibration,
    press_rings,
    reconstruct_depth,
    split_presses,
)

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
    # Measured: median radius 1.993 mm, median error 2.2%, worst 13%, median centre error 2.0 px
    # (before the calibration's flat-gel weight: 1.994 mm, 2.2%).
    assert np.median(relative) < 0.05
    assert abs(np.median(radii) - BALL_RADIUS_M) < 0.05 * BALL_RADIUS_M
    assert relative.max() < 0.2
    assert np.median(centre_errors) < 5.0
    assert centre_errors.max() < 8.0


def test_mini_held_out_presses_are_spheres_of_the_ball(mini_presses, mini_calibration):
    held_out, fits, radii, centre_errors = held_out_fits(mini_presses, mini_calibration)
    relative = np.abs(radii - BALL_RADIUS_M) / BALL_RADIUS_M
    # Measured: median radius 2.05 mm, median error 2.7%, worst 7.2% (before the calibration's
    # flat-gel weight: 2.04 mm, 2.9%, 6.9%). Before the contact
    # radius was re-measured from the colour-change ring (press_rings) it was 5.8%, with
    # shallow presses too small and deep ones too large.
    assert np.median(relative) < 0.05
    assert abs(np.median(radii) - BALL_RADIUS_M) < 0.05 * BALL_RADIUS_M
    assert relative.max() < 0.1
    # The Mini's recorded centres scatter by up to ~25 px around the press (two press sites,
    # presses 0-12 and 13-23, whose images move by under 2 px and 7 px), so they bound the
    # centre error from below: median 6.8 px. The 5 px target cannot be met against them.
    assert np.median(centre_errors) < 10.0
    first_site = np.array([f.center_px for f, i in zip(fits, held_out, strict=True) if i <= 12])
    spread = np.hypot(*(first_site - np.median(first_site, axis=0)).T)
    assert spread.max() < 3.0


def test_press_rings_find_the_contact_edge_not_the_annotation(gelsight_presses, mini_presses):
    # GelSight: the colour change peaks at the drawn contact circle (drawn a few px wide).
    for i in (0, 10, 20):
        rings = press_rings(gelsight_presses.images[i], gelsight_presses.reference,
                            gelsight_presses.centers_px[i], max_radius_px=60.0)
        assert 0.85 * gelsight_presses.radii_px[i] < rings.contact_px <= gelsight_presses.radii_px[i]
        assert rings.flat_px > rings.contact_px
    # Mini: the drawn circles (34-57 px) span the whole sunk-in dimple; the contact is 14-20 px
    # and grows with depth (press 1 shallow, press 7 deep, same site).
    centre = (339.8, 217.8)
    shallow, deep = (press_rings(mini_presses.images[i], mini_presses.reference, centre,
                                 max_radius_px=60.0) for i in (1, 7))
    assert 12 < shallow.contact_px < deep.contact_px < 22
    assert deep.flat_px > 2 * deep.contact_px


@pytest.fixture(scope="module")
def smoothed_gelsight_calibration(gelsight_presses):
    train = split_presses(len(gelsight_presses), 0.5)
    return fit_calibration(gelsight_presses.reference, gelsight_presses.images[train],
                           gelsight_presses.centers_px[train], gelsight_presses.radii_px[train],
                           ball_radius_m=BALL_RADIUS_M, pixel_pitch_m=0.0295e-3, smoothing_px=2.0,
                           provenance={"train_indices": train.tolist()})


def test_a_smoothed_table_reads_real_presses_and_a_noisy_unpressed_frame_flat(
        gelsight_presses, gelsight_calibration, smoothed_gelsight_calibration, tmp_path):
    smoothed = load_calibration(smoothed_gelsight_calibration.save(tmp_path / "cal.npz"))
    assert smoothed.smoothing_px == 2.0
    _, _, radii, _ = held_out_fits(gelsight_presses, smoothed)
    # Measured: median radius error 0.0 % (unsmoothed: -0.4 %).
    assert abs(np.median(radii) - BALL_RADIUS_M) < 0.02 * BALL_RADIUS_M
    reference = gelsight_presses.reference
    noisy = np.clip(reference + np.random.default_rng(7).normal(0.0, 2.0, reference.shape), 0, 255).astype(np.uint8)
    peak = {name: float(np.abs(reconstruct_depth(noisy, reference, cal)).max())
            for name, cal in (("unsmoothed", gelsight_calibration), ("smoothed", smoothed))}
    # Measured: 17 um unsmoothed, 0.5 um smoothed by 2 px.
    assert peak["smoothed"] < 2e-6 < 10e-6 < peak["unsmoothed"], peak
