"""The one modulus formatter (:func:`teleop.units.format_pa`)."""

from __future__ import annotations

import math

import pytest

from teleop.units import format_pa


@pytest.mark.parametrize(("value_pa", "shown"), [
    (3.6e6, "3.6 MPa"), (9e3, "9 kPa"), (2e11, "200 GPa"), (12.0, "12 Pa"), (1.23456e6, "1.23 MPa"),
    (999.4, "999 Pa"), (30316.129536967757, "30.3 kPa"),
])
def test_a_modulus_reads_to_three_figures_with_its_prefix(value_pa, shown):
    assert format_pa(value_pa) == shown


@pytest.mark.parametrize(("value_pa", "shown"), [
    (999.7, "1 kPa"), (999_600.0, "1 MPa"), (9.9996e8, "1 GPa"),
    (1e12, "1 TPa"),  # the model distribution's cap, an interval's high end for steel
])
def test_a_value_that_rounds_up_to_the_next_prefix_takes_it(value_pa, shown):
    # rounded before the prefix is chosen: never "1e+03 kPa"
    assert format_pa(value_pa) == shown


def test_no_modulus_reads_as_a_dash():
    assert format_pa(None) == "-" and format_pa(math.nan) == "-" and format_pa(math.inf) == "-"
