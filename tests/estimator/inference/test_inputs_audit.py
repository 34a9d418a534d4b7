"""Model inputs, audited: the edges of what a variant accepts, the calibration smoothings, the analytical
floor and the analytical encoding's clips."""

from __future__ import annotations

import math

import numpy as np
import pytest

from estimator.errors import ModelError
from estimator.estimate import Estimate
from estimator.inference.inputs import (
    ANALYTICAL_METHODS,
    FEATURES_PER_METHOD,
    Variant,
    analytical_features,
    analytical_floor,
    calibration_smoothings,
    distinct_frames,
    reduce_images,
    smoothings_text,
)


@pytest.mark.parametrize("size_px", [(8, 8), (250, 350), (8, 350), (250, 8)])
def test_the_extreme_image_sizes_are_accepted(size_px):
    assert Variant(size_px=size_px).size_px == size_px


@pytest.mark.parametrize("size_px", [(7, 88), (251, 88), (64, 7), (64, 351)])
def test_an_image_size_just_outside_the_range_is_refused(size_px):
    with pytest.raises(ModelError, match="size_px"):
        Variant(size_px=size_px)


def test_sixty_four_frames_are_accepted_and_sixty_five_refused():
    assert Variant(n_frames=64).n_frames == 64
    with pytest.raises(ModelError, match="n_frames"):
        Variant(n_frames=65)


def test_a_variant_from_json_numbers_and_lists_equals_the_one_from_python_values():
    """Metadata read from JSON gives lists and maybe floats: the variant normalises them."""
    variant = Variant(n_frames=3.0, size_px=[64, 88], window_m=[0.02, 0.03])
    assert variant == Variant(n_frames=3, size_px=(64, 88), window_m=(0.02, 0.03))
    assert type(variant.n_frames) is int and all(type(v) is int for v in variant.input_shapes["force_width"])
    assert hash(variant) == hash(Variant(n_frames=3, window_m=(0.02, 0.03)))


@pytest.mark.parametrize("window_m", [(0.02,), (0.02, 0.03, 0.04), (5e-4, 0.03), (0.02, 0.3), ("a", 0.03)])
def test_a_window_that_is_not_a_pad_sized_pair_is_refused(window_m):
    with pytest.raises(ModelError, match="window_m"):
        Variant(window_m=window_m)


def test_an_unknown_image_kind_is_refused():
    with pytest.raises(ModelError, match="variant image"):
        Variant(image="infrared")


def test_the_input_pitch_is_the_window_over_the_size_per_axis():
    assert Variant(size_px=(50, 100), window_m=(0.02, 0.03)).input_pitch_m == pytest.approx((4e-4, 3e-4))
    assert Variant().input_pitch_m is None


def test_a_part_named_twice_is_refused_and_surrounding_blanks_are_ignored():
    with pytest.raises(ModelError, match=r"\+fw given more than once"):
        Variant.parse("depth+fw+fw")
    assert Variant.parse("  depth+fw \n").name == "depth+fw"


def test_calibration_smoothings_are_sorted_and_default_to_none():
    assert calibration_smoothings({}) == (0.0,)
    assert calibration_smoothings({"calibration_smoothing_px": []}) == (0.0,)
    assert calibration_smoothings({"calibration_smoothing_px": [2, 0]}) == (0.0, 2.0)
    assert smoothings_text((0.0, 2.0)) == "0 and 2 px" and smoothings_text((1.5,)) == "1.5 px"


def test_the_floor_is_the_highest_lower_bound_of_the_floor_methods_on_the_reference_gel():
    estimates = [
        Estimate.at_least("series", 1e6, "bound"),
        Estimate.at_least("no_tactile", 1e8, "bound"),
        Estimate.at_least("hertz", 1e10, "not a floor method"),
        Estimate.ok("series", 2e9, 1e9, 3e9, "an answer, not a bound"),
    ]
    assert analytical_floor(estimates) == (pytest.approx(8.0), "no_tactile")
    assert analytical_floor(estimates, scale=10.0) == (pytest.approx(9.0), "no_tactile")
    assert analytical_floor(estimates[2:]) == (-math.inf, None)


def _rows(estimates):
    f = analytical_features(estimates).reshape(len(ANALYTICAL_METHODS), FEATURES_PER_METHOD)
    return dict(zip(ANALYTICAL_METHODS, f, strict=True))


def test_moduli_far_outside_the_output_range_are_clipped_half_a_range_beyond_it():
    soft, stiff = ANALYTICAL_METHODS[:2]
    rows = _rows([Estimate.at_most(soft, 1e-3, "tiny"), Estimate.at_least(stiff, 1e20, "huge")])
    assert rows[soft][0] == pytest.approx(-0.5) and rows[stiff][0] == pytest.approx(1.5)
    assert rows[soft][1:].tolist() == [1, 0, 0, 1, 0]  # an upper bound: open, its own state
    rows = _rows([Estimate.at_most(soft, 1.0, "just below"), Estimate.at_least(stiff, 1e14, "just above")])
    assert rows[soft][0] == pytest.approx(-1 / 3) and rows[stiff][0] == pytest.approx(11 / 9)


def test_an_interval_wider_than_the_output_range_encodes_as_open():
    method = ANALYTICAL_METHODS[0]
    assert _rows([Estimate.ok(method, 1e6, 1.0, 1e12, "twelve decades")])[method][1] == pytest.approx(1.0)


def test_repeated_sampled_frames_count_once():
    assert distinct_frames(np.array([1.0, 1.0, 2.0])) == 2


def test_a_window_without_the_images_pitch_is_refused():
    with pytest.raises(ModelError, match="pixel pitch"):
        reduce_images(np.zeros((1, 20, 20), np.float32), (10, 10), window_m=(0.01, 0.01))


def test_a_window_smaller_than_the_images_cuts_them_before_reducing():
    stack = np.zeros((1, 20, 20), np.float32)
    stack[0, 5:15, 5:15] = 1.0  # the centre half of each side
    cut = reduce_images(stack, (10, 10), pitch_m=1e-3, window_m=(0.01, 0.01))
    np.testing.assert_array_equal(cut, np.ones((1, 10, 10), np.float32))
