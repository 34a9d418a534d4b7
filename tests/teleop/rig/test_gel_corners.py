"""The gel's corners on the real GelSight Wedge no-contact frame of the reference data, and on
synthetic frames whose sides a lens bows.

The reference frame (``../shared/seed/wedge_init_frame_raw_640x480.png``) is a brightly lit gel
on a dark housing; ``wedge_corners_no_markers.csv`` holds its published corners (``Name,x,y``: raw
pixels of the warped image's corners; they warp this frame onto the published warped frame, see
``tests/estimator/perception/test_warp.py``). Those were clicked by hand, inside a lit rim about
20 px wide along the top, right and bottom (as bright as the gel, without the LEDs' colour);
:func:`find_gel_corners` frames the lit region, rim and all (module notes), so it lies that far
outside them there, and on them along the left side, which has no rim.
"""

from __future__ import annotations

import csv

import cv2
import numpy as np
import pytest

from teleop.rig.gel_corners import CornerFit, find_gel_corners

WARPED_SIZE = (400, 300)


def published_corners(path) -> np.ndarray:
    with path.open() as fh:
        rows = {row["Name"]: (float(row["x"]), float(row["y"])) for row in csv.DictReader(fh)}
    return np.array([rows[name] for name in ("topleft", "topright", "bottomleft", "bottomright")])


@pytest.fixture(scope="module")
def wedge(shared_dir):
    seed = shared_dir / "seed"
    raw = cv2.imread(str(seed / "wedge_init_frame_raw_640x480.png"), cv2.IMREAD_COLOR)
    return raw, published_corners(seed / "wedge_corners_no_markers.csv")


def test_the_real_wedge_frame_is_found_around_its_published_corners(wedge):
    raw, published = wedge
    fit = find_gel_corners(raw, warped_size_px=WARPED_SIZE)
    assert fit, fit.reason
    # The lit gel against the housing: measured 109 levels (9, and refused, when sampled across the rim).
    assert fit.contrast > 60.0
    assert fit.edge_rms_px < 0.6  # measured 0.36
    assert 8.0 < fit.bow_px < 16.0  # the lens bows the left side outward: measured 11.9 px over 382
    # Measured 22.3, 26.1, 21.6, 21.9 px from the hand-clicked corners (TL, TR, BL, BR): the rim.
    off = np.hypot(*(fit.corners_px - published).T)
    assert np.all(off < 28.0), off
    # Along the left side, which has no rim, they agree: measured 1.1 and 0.3 px in x.
    np.testing.assert_allclose(fit.corners_px[[0, 2], 0], published[[0, 2], 0], atol=2.0)
    # The rim is outside the published quadrilateral: its corners lie within the found one (the
    # left ones on its border).
    outline = fit.outline_px[[0, 1, 3, 2]].astype(np.float32)
    inside = [cv2.pointPolygonTest(outline, (float(x), float(y)), True) for x, y in published]
    assert min(inside) > -1.5, inside


def test_the_real_frame_dimmed_noisy_or_compressed_gives_the_same_corners_and_dark_is_refused(wedge):
    raw, _ = wedge
    clean = find_gel_corners(raw, warped_size_px=WARPED_SIZE).corners_px
    noisy = np.clip(raw + np.random.default_rng(0).normal(0.0, 4.0, raw.shape), 0, 255).astype(np.uint8)
    jpeg = cv2.imdecode(cv2.imencode(".jpg", noisy, [cv2.IMWRITE_JPEG_QUALITY, 75])[1], cv2.IMREAD_COLOR)
    for frame in (raw // 4, jpeg):  # measured 0.7 and 0.6 px off
        fit = find_gel_corners(frame, warped_size_px=WARPED_SIZE)
        assert fit, fit.reason
        np.testing.assert_allclose(fit.corners_px, clean, atol=1.5)
    dark = find_gel_corners(raw // 10, warped_size_px=WARPED_SIZE)  # the gel 14 levels, the housing 3
    assert not dark and "levels brighter than the housing" in dark.reason


def test_a_side_bowed_like_a_lens_is_followed_to_its_corners():
    corners = np.array([[80.0, 100.0], [560.0, 100.0], [80.0, 400.0], [560.0, 400.0]])
    x = np.linspace(80.0, 560.0, 50)
    bow = 12.0  # 2.5 % of the side, less than the real Wedge's 3 %
    top = np.column_stack([x, 100.0 - bow * (1.0 - ((x - 320.0) / 240.0) ** 2)])
    frame = np.full((480, 640, 3), 12, np.uint8)
    cv2.fillPoly(frame, [np.vstack([top, corners[[3, 2]]]).astype(np.int32)], (150, 140, 130))
    fit = find_gel_corners(frame, warped_size_px=WARPED_SIZE)
    assert fit, fit.reason
    assert fit.bow_px == pytest.approx(bow, abs=1.0)
    # The lit pixels span -0.5 ... +0.5 around the polygon's integer corners; a line through the
    # bowed side would put the top corners about 10 px too high.
    np.testing.assert_allclose(fit.outline_px, corners + [[-0.5, -0.5], [0.5, -0.5], [-0.5, 0.5], [0.5, 0.5]],
                               atol=1.0)


def _lit_rectangle() -> np.ndarray:
    """A gel lit evenly inside (80, 100) .. (560, 400), its top side drawn through many vertices."""
    frame = np.full((480, 640, 3), 12, np.uint8)
    x = np.arange(80.0, 561.0, 4.0)
    top = np.column_stack([x, np.full_like(x, 100.0)])
    cv2.fillPoly(frame, [np.vstack([top, [[560.0, 400.0], [80.0, 400.0]]]).round().astype(np.int32)], (150, 140, 130))
    return frame


def test_edge_points_scattering_more_than_the_limit_are_refused():
    clean = find_gel_corners(_lit_rectangle(), warped_size_px=WARPED_SIZE)
    assert clean and clean.edge_rms_px < 1.0
    fit = find_gel_corners(_lit_rectangle(), warped_size_px=WARPED_SIZE, max_edge_rms_px=clean.edge_rms_px / 2)
    assert not fit and fit.reason.startswith("the gel's sides are not straight: edge points scatter")


def test_the_corners_written_to_the_settings_keep_a_tenth_of_a_pixel():
    fit = CornerFit(corners_px=np.array([[80.26, 100.04], [559.76, 99.96], [80.5, 399.44], [560.0, 400.56]]))
    assert fit.as_settings() == [[80.3, 100.0], [559.8, 100.0], [80.5, 399.4], [560.0, 400.6]]


def test_the_corners_are_the_outline_shifted_by_half_a_warped_pixel():
    # The outline spans warped -0.5 .. W - 0.5; warp_corners_px are warped (0, 0) .. (W, H).
    fit = find_gel_corners(_lit_rectangle(), warped_size_px=WARPED_SIZE)
    outline, corners = fit.outline_px, fit.corners_px
    half = 0.5 * np.array([(outline[1, 0] - outline[0, 0]) / WARPED_SIZE[0], (outline[2, 1] - outline[0, 1]) / WARPED_SIZE[1]])
    np.testing.assert_allclose(corners[0], outline[0] + half, atol=0.02)  # inward at the top-left
    np.testing.assert_allclose(corners[3], outline[3] + half, atol=0.02)  # outward at the bottom-right
