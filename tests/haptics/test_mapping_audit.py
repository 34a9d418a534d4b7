"""Audit of haptics.mapping: the scale's closed forms, the refusals at its edges and what a refusal keeps."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from haptics.errors import MappingError
from haptics.mapping import (
    EstimateUpdate,
    Percept,
    fade,
    interval_decades,
    just_noticeable_steps,
    map_estimate,
    modulus_from_fraction,
    smooth,
    stiffness_fraction,
    to_command,
)
from teleop.bus.messages import EstimateBody

SOFT, RIGID = 5e3, 6.75e6
RANGE = {"e_soft_pa": SOFT, "e_rigid_pa": RIGID}


def test_the_fraction_is_log_e_over_the_range_in_closed_form():
    for e_pa in (7.3e3, 1e5, 2.2e6):
        expected = math.log10(e_pa / SOFT) / math.log10(RIGID / SOFT)
        assert stiffness_fraction(e_pa, **RANGE) == pytest.approx(expected, rel=1e-12)
        assert modulus_from_fraction(expected, **RANGE) == pytest.approx(e_pa, rel=1e-12)


def test_the_ends_of_the_range_come_back_exactly_even_where_the_power_would_round():
    # 15424 * (66074574 / 15424) is one ulp below 66074574 in floats: the stiff end must stay the stiff end.
    assert modulus_from_fraction(1.0, e_soft_pa=15424.0, e_rigid_pa=66074574.0) == 66074574.0
    assert modulus_from_fraction(1.0, e_soft_pa=7e3, e_rigid_pa=1e9) == 1e9
    assert modulus_from_fraction(0.0, e_soft_pa=7e3, e_rigid_pa=1e9) == 7e3


def test_the_modulus_of_a_fraction_stays_inside_a_range_one_rounding_wide():
    # A range a few ulps wide: the power overshoots its stiff end unless clamped.
    soft, rigid = 5484756.246400936, 5484756.246400937
    e_pa = modulus_from_fraction(0.999999999999, e_soft_pa=soft, e_rigid_pa=rigid)
    assert soft <= e_pa <= rigid


def test_an_empty_range_is_refused_as_a_mapping_error():
    with pytest.raises(MappingError, match="e_rigid_pa = 100000.0: expected a value above e_soft_pa"):
        stiffness_fraction(1e5, e_soft_pa=1e5, e_rigid_pa=1e5)
    with pytest.raises(MappingError, match="e_rigid_pa"):
        just_noticeable_steps(1e5, 1e5)


@pytest.mark.parametrize("interval", [(1e5 * (1 + 1e-6), None), (None, 1e5 * (1 - 1e-6))])
def test_an_estimate_a_millionth_outside_its_interval_is_refused(interval):
    # The tolerance is for rounding (1e-9), not for an estimate beside its own interval.
    with pytest.raises(MappingError, match="lies outside its interval_pa"):
        EstimateUpdate(1e5, interval, "ok")


@pytest.mark.parametrize("interval", [(1e5 * (1 + 1e-10), None), (None, 1e5 * (1 - 1e-10))])
def test_an_estimate_a_rounding_outside_its_interval_is_accepted(interval):
    assert EstimateUpdate(1e5, interval, "ok").value_pa == 1e5


def test_an_inverted_interval_inside_the_range_is_refused():
    with pytest.raises(MappingError, match="low above high"):
        interval_decades(1e6, 1e4, **RANGE)


def test_interval_decades_is_the_log_ratio_of_the_clipped_ends():
    assert interval_decades(2e4, 3e5, **RANGE) == pytest.approx(math.log10(3e5 / 2e4), rel=1e-12)
    assert interval_decades(1e3, 3e5, **RANGE) == pytest.approx(math.log10(3e5 / SOFT), rel=1e-12)
    assert interval_decades(2e4, 1e8, **RANGE) == pytest.approx(math.log10(RIGID / 2e4), rel=1e-12)


@pytest.mark.parametrize("interval", [(None, RIGID * 10), (SOFT / 10, None)])
def test_an_ok_estimate_with_one_open_side_is_placed_not_unknown(interval):
    # An ok estimate's open side states nothing: only the closed side can reach its end.
    percept = map_estimate(EstimateUpdate(3e4, interval, "ok"), **RANGE)
    assert not percept.unknown
    assert percept.stiffness == pytest.approx(math.log10(3e4 / SOFT) / math.log10(RIGID / SOFT))


def test_an_unknown_provisional_estimate_stays_provisional():
    for update in (EstimateUpdate(None, state="insufficient_data", provisional=True),
                   EstimateUpdate(3e4, (SOFT, RIGID), "ok", provisional=True)):
        percept = map_estimate(update, **RANGE)
        assert percept.unknown and percept.provisional
        assert to_command(percept, level_max=4095).provisional


def test_a_provisional_numpy_flag_from_the_bus_stays_provisional():
    estimate = EstimateBody(E_pa=2e5, interval_pa=[1e5, 4e5], state="ok", reason="", provisional=np.bool_(True),
                            grasp_id="g-1", latency_s=0.02, method="hybrid", model=None)
    assert EstimateUpdate.from_estimate(estimate, 1.0).provisional is True
    assert EstimateUpdate.from_estimate(dataclasses.replace(estimate, provisional=False), 1.0).provisional is False


def test_smoothing_moves_the_uncertainty_by_the_same_first_order_lag():
    previous = Percept(stiffness=0.2, uncertainty_decades=3.0)
    target = Percept(stiffness=0.6, uncertainty_decades=1.0)
    out = smooth(previous, target, dt_s=0.1, smoothing_s=0.1)
    weight = 1 - math.exp(-1)
    assert out.stiffness == pytest.approx(0.2 + weight * 0.4, rel=1e-12)
    assert out.uncertainty_decades == pytest.approx(3.0 - weight * 2.0, rel=1e-12)


@pytest.mark.parametrize("gain", [-0.1, math.nan, 1.0 + 1e-9])
def test_fade_refuses_a_gain_outside_0_to_1(gain):
    with pytest.raises(MappingError, match="fade gain"):
        fade(Percept(stiffness=0.5), gain=gain)


@pytest.mark.parametrize(("percept", "field"), [
    (Percept(stiffness=-0.01), "stiffness"),
    (Percept(stiffness=1.01), "stiffness"),
    (Percept(uncertainty_decades=-0.5), "uncertainty_decades"),
])
def test_to_command_refuses_a_percept_off_the_display(percept, field):
    with pytest.raises(MappingError, match=f"percept {field} = .*: out of range"):
        to_command(percept, level_max=4095)


def test_to_command_rounds_the_uncertainty_to_the_nearest_count():
    # 0.99 decade is 19.8 counts of 1/20 decade: 20, not 19.
    assert to_command(Percept(uncertainty_decades=0.99), level_max=10).uncertainty == 20
    assert to_command(Percept(uncertainty_decades=0.96), level_max=10).uncertainty == 19


@pytest.mark.parametrize("update", [
    EstimateUpdate(1e5 * (1 + 5e-10), (None, 1e5), "lower_bound"),
    EstimateUpdate(1e5 * (1 - 5e-10), (1e5, None), "upper_bound"),
])
def test_a_bound_a_rounding_beyond_its_interval_side_maps_to_a_point(update):
    # EstimateUpdate accepts a bound within a rounding of its interval's other side; mapping it must
    # not then fail as an inverted interval.
    percept = map_estimate(update, **RANGE)
    assert percept.uncertainty_decades == pytest.approx(0.0, abs=1e-9) and not percept.unknown
    assert percept.stiffness == pytest.approx(stiffness_fraction(1e5, **RANGE), rel=1e-9)
