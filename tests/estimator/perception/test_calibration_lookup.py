"""The colour-to-gradient table lookup: the index of every pixel's relative colour change."""

from __future__ import annotations

import numpy as np
import pytest

from estimator.perception.calibration import lut_index


def all_byte_pairs(rng):
    """Every (reference, value) byte pair once per channel, the channels shuffled independently."""
    ref, val = np.divmod(np.arange(256 * 256), 256)
    order = [rng.permutation(256 * 256) for _ in range(3)]
    frame = np.stack([val[o] for o in order], axis=-1).astype(np.uint8).reshape(256, 256, 3)
    reference = np.stack([ref[o] for o in order], axis=-1).astype(np.uint8).reshape(256, 256, 3)
    return frame, reference


@pytest.mark.parametrize(("bins", "relative_range"), [(9, 0.3), (16, 0.5), (7, 2.0)])
def test_smoothed_lookup_with_a_vanishing_kernel_equals_the_byte_pair_lookup(bins, relative_range):
    # Both paths divide by max(reference, 1) and order the channels B, G, R (B * bins^2 + G * bins + R);
    # a Gaussian of 1e-3 px leaves every pixel as it is.
    frame, reference = all_byte_pairs(np.random.default_rng(0))
    offsets = np.zeros((256, 256), np.int32)
    exact = lut_index(frame, reference, bins=bins, relative_range=relative_range, offsets=offsets,
                      smoothing_px=0.0)
    smoothed = lut_index(frame, reference, bins=bins, relative_range=relative_range, offsets=offsets,
                         smoothing_px=1e-3)
    np.testing.assert_array_equal(smoothed, exact)
    assert exact.min() >= 0 and exact.max() < bins**3


def test_a_sub_pixel_smoothing_is_still_applied():
    # Only 0 means "the 8-bit pairs as they are": a one-pixel bright speck blurred by 0.7 px reaches its neighbours.
    reference = np.full((9, 9, 3), 100, np.uint8)
    frame = reference.copy()
    frame[4, 4] = 255
    offsets = np.zeros((9, 9), np.int32)
    plain = lut_index(frame, reference, bins=9, relative_range=0.3, offsets=offsets, smoothing_px=0.0)
    blurred = lut_index(frame, reference, bins=9, relative_range=0.3, offsets=offsets, smoothing_px=0.7)
    assert plain[4, 3] == plain[0, 0]
    assert blurred[4, 3] != plain[4, 3]
