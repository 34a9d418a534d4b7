"""Audit of :mod:`teleop.rig.gel_corners` on synthetic frames: which bright region is the gel, which
are refused and why, the corners' order and the overlay."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from teleop.errors import TeleopError
from teleop.rig.gel_corners import CornerFit, draw_corners, find_gel_corners

SIZE = (400, 300)
GEL = np.array([[80, 100], [560, 100], [560, 400], [80, 400]])  # TL, TR, BR, BL


def _frame(*polygons, background=12):
    """A dark frame with each (points, colour) filled in."""
    frame = np.full((480, 640, 3), background, np.uint8)
    for points, colour in polygons:
        cv2.fillPoly(frame, [np.asarray(points, np.int32)], colour)
    return frame


def _corner_order(fit: CornerFit) -> np.ndarray:
    return np.rint(fit.outline_px).astype(int)


def test_the_corners_come_top_left_top_right_bottom_left_bottom_right():
    fit = find_gel_corners(_frame((GEL, (150, 140, 130))), warped_size_px=SIZE)
    assert fit, fit.reason
    np.testing.assert_allclose(fit.outline_px, [[79.5, 99.5], [560.5, 99.5], [79.5, 400.5], [560.5, 400.5]], atol=0.6)
    tl, tr, bl, br = fit.corners_px
    assert tl[0] < tr[0] and bl[0] < br[0] and tl[1] < bl[1] and tr[1] < br[1]
    assert fit.edge_rms_px < 0.5 and abs(fit.bow_px) < 0.5


def test_a_gel_seen_tilted_keeps_its_corners_in_order():
    tilted = np.array([[100, 60], [560, 120], [520, 420], [60, 380]])  # TL, TR, BR, BL
    fit = find_gel_corners(_frame((tilted, (150, 140, 130))), warped_size_px=SIZE)
    assert fit, fit.reason
    np.testing.assert_allclose(fit.outline_px, tilted[[0, 1, 3, 2]], atol=1.5)


def test_the_brighter_of_two_large_regions_is_the_gel_even_when_smaller():
    # The Wedge's second mirror view beside the gel is dimmer: here it is also the larger.
    dim = np.array([[330, 60], [630, 60], [630, 420], [330, 420]])
    gel = np.array([[20, 120], [280, 120], [280, 360], [20, 360]])
    fit = find_gel_corners(_frame((dim, (130, 130, 130)), (gel, (220, 210, 200))), warped_size_px=SIZE)
    assert fit, fit.reason
    np.testing.assert_allclose(fit.outline_px[0], [19.5, 119.5], atol=1.0)


def test_a_bright_region_smaller_than_the_least_area_is_no_gel():
    fit = find_gel_corners(_frame(([[300, 200], [340, 200], [340, 240], [300, 240]], (200, 200, 200))),
                           warped_size_px=SIZE)
    assert not fit and fit.reason.startswith("no bright region of at least 5% of the frame")


@pytest.mark.parametrize("shift", [(100, 0), (0, 100)])
def test_a_gel_running_off_the_right_or_bottom_edge_is_refused(shift):
    fit = find_gel_corners(_frame((GEL + shift, (150, 140, 130))), warped_size_px=SIZE)
    assert not fit and "runs off the frame's edge" in fit.reason


def test_a_faint_gel_is_refused_with_its_contrast():
    fit = find_gel_corners(_frame((GEL, (27, 27, 27)), background=12), warped_size_px=SIZE)
    assert not fit and fit.reason.startswith("the gel is only 1") and "at least 20 needed" in fit.reason
    assert 10.0 < fit.contrast < 20.0


def test_the_contrast_limit_is_the_one_given():
    frame = _frame((GEL, (150, 140, 130)))
    contrast = find_gel_corners(frame, warped_size_px=SIZE).contrast
    assert not find_gel_corners(frame, warped_size_px=SIZE, min_contrast=contrast + 1.0)


def test_a_bright_outline_with_a_fifth_corner_is_refused_naming_its_corners():
    house = np.array([[80, 180], [320, 40], [560, 180], [560, 420], [80, 420]])
    fit = find_gel_corners(_frame((house, (150, 140, 130))), warped_size_px=SIZE)
    assert not fit and fit.reason.startswith("the bright gel's outline has 5 corners, not 4")


def test_a_side_with_a_notch_out_of_it_is_refused_as_not_straight():
    # A dark bite 150 px wide out of the bottom side: a third of its profiles find no edge on its curve.
    frame = _frame((GEL, (150, 140, 130)))
    frame[370:401, 250:400] = 12
    fit = find_gel_corners(frame, warped_size_px=SIZE)
    assert not fit and "bottom side is not straight" in fit.reason


@pytest.mark.parametrize("bow", [-30.0, 30.0])
def test_a_side_bent_in_or_out_past_the_limit_is_refused(bow):
    x = np.linspace(80.0, 560.0, 60)
    top = np.column_stack([x, 100.0 - bow * (1.0 - ((x - 320.0) / 240.0) ** 2)])
    frame = _frame((np.vstack([top, [[560.0, 400.0], [80.0, 400.0]]]), (150, 140, 130)))
    fit = find_gel_corners(frame, warped_size_px=SIZE, max_bow=0.03)
    assert not fit and fit.reason.startswith("the gel's top side is not straight: it bows"), fit.reason
    assert fit.bow_px == pytest.approx(bow, abs=3.0)


@pytest.mark.parametrize("frame", [np.zeros((480, 640, 3), np.float32), np.zeros((480, 640), np.uint8),
                                   np.zeros((480, 640, 4), np.uint8), [[0]]])
def test_a_frame_that_is_not_uint8_bgr_is_refused_naming_it(frame):
    with pytest.raises(TeleopError, match=r"raw_bgr: expected a uint8 \(H, W, 3\) BGR frame, got"):
        find_gel_corners(frame, warped_size_px=SIZE)


def test_the_overlay_draws_on_a_copy_and_writes_a_refusal_across_the_frame():
    frame = _frame((GEL, (150, 140, 130)))
    before = frame.copy()
    fit = find_gel_corners(frame, warped_size_px=SIZE)
    drawn = draw_corners(frame, fit)
    assert np.array_equal(frame, before) and not np.array_equal(drawn, frame)
    refused = draw_corners(frame, CornerFit(reason="no gel"))
    assert np.array_equal(frame, before) and (refused[8:30, 8:60] != frame[8:30, 8:60]).any()


def test_a_short_dent_in_a_side_barely_pulls_its_curve():
    # A dark bite 40 px wide and 4 px deep into the top side: its edge points are outliers to the side's
    # curve, weighted down; fitted with them in full, the parabola would bow and lift the top corners 1.6 px.
    frame = _frame((GEL, (150, 140, 130)))
    frame[95:104, 300:340] = 12
    fit = find_gel_corners(frame, warped_size_px=SIZE)
    assert fit, fit.reason
    np.testing.assert_allclose(fit.outline_px[:2, 1], [99.5, 99.5], atol=0.7)
