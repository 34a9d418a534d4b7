"""The shared argparse number types say what they expected, an infinite value included."""

from __future__ import annotations

import argparse

import pytest

from teleop.clikit import non_negative_number, positive_number


@pytest.mark.parametrize("kind, text", [(positive_number, "inf"), (positive_number, "0"),
                                        (non_negative_number, "inf"), (non_negative_number, "-1")])
def test_a_refused_number_is_told_it_must_be_finite_too(kind, text):
    with pytest.raises(argparse.ArgumentTypeError, match=rf"'{text}': expected a number >=? 0, finite"):
        kind(text)


@pytest.mark.parametrize("kind, text, value", [(positive_number, "1e-9", 1e-9), (non_negative_number, "0", 0.0)])
def test_a_finite_number_in_range_is_taken(kind, text, value):
    assert kind(text) == value
