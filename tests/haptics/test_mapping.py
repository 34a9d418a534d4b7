"""Mapping from E to the display: scale, states, uncertainty, smoothing, fade, staleness."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from hypothesis import assume, example, given
from hypothesis import strategies as st

from haptics.errors import MappingError
from haptics.mapping import (
    ESTIMATE_STATES,
    FREE,
    RIGID_TOLERANCE,
    EstimateUpdate,
    Percept,
    fade,
    fade_gain,
    interval_decades,
    is_stale,
    just_noticeable_steps,
    map_estimate,
    modulus_from_fraction,
    smooth,
    smoothing_weight,
    stiffness_fraction,
    to_command,
)
from haptics.settings import display_settings
from teleop.bus.messages import EstimateBody
from teleop.settings import load_settings

SOFT, RIGID = 5e3, 1e9
RANGE = {"e_soft_pa": SOFT, "e_rigid_pa": RIGID}
FULL_DECADES = math.log10(RIGID / SOFT)

moduli = st.floats(min_value=1e-300, max_value=1e300, allow_nan=False, allow_infinity=False)


def ok(e_pa, interval=(None, None), **kw):
    return EstimateUpdate(e_pa=e_pa, interval_pa=interval, state="ok", **kw)


# --------------------------------------------------------------------------- scale


def test_scale_is_logarithmic_between_the_ends():
    assert stiffness_fraction(SOFT, **RANGE) == 0.0
    assert stiffness_fraction(RIGID, **RANGE) == 1.0
    assert stiffness_fraction(math.sqrt(SOFT * RIGID), **RANGE) == pytest.approx(0.5)
    # Equal ratios of E give equal steps.
    step_low = stiffness_fraction(1e5, **RANGE) - stiffness_fraction(1e4, **RANGE)
    step_high = stiffness_fraction(1e8, **RANGE) - stiffness_fraction(1e7, **RANGE)
    assert step_low == pytest.approx(step_high)
    assert step_low == pytest.approx(1 / FULL_DECADES)


def test_scale_is_clamped():
    assert stiffness_fraction(1.0, **RANGE) == 0.0
    assert stiffness_fraction(250e9, **RANGE) == 1.0


@given(moduli, moduli)
def test_scale_is_monotone_and_within_range(e1, e2):
    lo, hi = sorted((e1, e2))
    f_lo, f_hi = stiffness_fraction(lo, **RANGE), stiffness_fraction(hi, **RANGE)
    assert 0.0 <= f_lo <= f_hi <= 1.0


@pytest.mark.parametrize("bad", [0.0, -1e5, math.nan, math.inf, None, "1e5", True])
def test_scale_refuses_a_bad_modulus(bad):
    with pytest.raises(MappingError, match="e_pa"):
        stiffness_fraction(bad, **RANGE)


def test_scale_refuses_an_inverted_range():
    with pytest.raises(MappingError, match="e_rigid_pa"):
        stiffness_fraction(1e5, e_soft_pa=1e9, e_rigid_pa=1e3)


@given(st.floats(min_value=SOFT, max_value=RIGID), st.floats(min_value=0.0, max_value=1.0))
def test_modulus_from_fraction_inverts_the_scale(e_pa, fraction):
    assert modulus_from_fraction(stiffness_fraction(e_pa, **RANGE), **RANGE) == pytest.approx(e_pa, rel=1e-9)
    assert stiffness_fraction(modulus_from_fraction(fraction, **RANGE), **RANGE) == pytest.approx(fraction, abs=1e-12)
    assert modulus_from_fraction(0.0, **RANGE) == SOFT and modulus_from_fraction(1.0, **RANGE) == RIGID
    assert modulus_from_fraction(0.5, **RANGE) == pytest.approx(math.sqrt(SOFT * RIGID))
    # Beyond the range the scale is clamped, so the round trip lands on the nearer end.
    assert modulus_from_fraction(stiffness_fraction(250e9, **RANGE), **RANGE) == RIGID
    for bad in (-0.1, 1.1, math.nan, None, True):
        with pytest.raises(MappingError, match="fraction"):
            modulus_from_fraction(bad, **RANGE)


# --------------------------------------------------------------------------- states


def test_ok_estimate_maps_to_its_level_and_interval():
    percept = map_estimate(ok(1e6, (1e5, 1e7)), **RANGE)
    assert percept.stiffness == pytest.approx(math.log10(1e6 / SOFT) / FULL_DECADES)
    assert percept.uncertainty_decades == pytest.approx(2.0)
    assert not (percept.rigid or percept.unknown)


def test_rigid_when_e_or_its_lower_bound_reaches_the_stiff_end():
    assert map_estimate(ok(RIGID), **RANGE).rigid
    assert map_estimate(ok(200e9), **RANGE).rigid
    bound = map_estimate(EstimateUpdate(3e9, (3e9, None), "lower_bound"), **RANGE)
    assert bound.rigid and bound.stiffness == 1.0
    assert bound.uncertainty_decades == 0.0  # above the range: nothing left to doubt on the display


def test_an_upper_bound_at_the_stiff_end_is_never_shown_rigid():
    at_most = map_estimate(EstimateUpdate(10 * RIGID, (1e5, 10 * RIGID), "upper_bound"), **RANGE)
    assert not at_most.unknown and not at_most.rigid  # "at most X" is no "rigid"


def test_a_lower_bound_below_the_stiff_end_is_not_rigid_and_open_above():
    bound = map_estimate(EstimateUpdate(1e6, (None, None), "lower_bound"), **RANGE)
    assert not bound.rigid
    assert bound.stiffness == pytest.approx(stiffness_fraction(1e6, **RANGE))
    assert bound.uncertainty_decades == pytest.approx(3.0)  # 1e6 .. 1e9


def test_an_upper_bound_is_never_rigid_and_open_below():
    bound = map_estimate(EstimateUpdate(5e9, (None, 5e9), "upper_bound"), **RANGE)
    assert not bound.rigid
    assert bound.uncertainty_decades == pytest.approx(FULL_DECADES)
    soft_bound = map_estimate(EstimateUpdate(5e4, (None, None), "upper_bound"), **RANGE)
    assert soft_bound.uncertainty_decades == pytest.approx(1.0)  # 5e3 .. 5e4


def test_insufficient_data_is_unknown_and_free():
    update = EstimateUpdate(None, state="insufficient_data", reason="no contact")
    percept = map_estimate(update, **RANGE)
    assert percept.unknown and not percept.rigid
    assert percept.stiffness == 0.0
    assert percept.uncertainty_decades == pytest.approx(FULL_DECADES)


def test_an_interval_over_the_whole_range_is_unknown_as_a_refusal():
    # The middle of a distribution over every modulus is often rigid: rendering it would say what
    # the estimate does not.
    lo, hi = RANGE["e_soft_pa"], RANGE["e_rigid_pa"]
    for update in (ok(hi, (lo / 50, hi * 1e5)), ok(3e4, (lo, hi)),
                   EstimateUpdate(lo, (None, None), "lower_bound"), EstimateUpdate(hi, (None, hi), "upper_bound")):
        percept = map_estimate(update, **RANGE)
        assert percept.unknown and not percept.rigid and percept.stiffness == 0.0
        assert percept.uncertainty_decades == pytest.approx(FULL_DECADES)
    # Anything narrower is placed: a side inside the range, or an ok estimate's side left open.
    for update in (ok(3e4, (lo * 1.01, hi * 10)), ok(3e4, (lo / 10, hi * 0.99)), ok(3e4, (None, None)),
                   EstimateUpdate(lo * 2, (None, None), "lower_bound"),
                   EstimateUpdate(hi / 2, (None, hi / 2), "upper_bound")):
        assert not map_estimate(update, **RANGE).unknown


@pytest.mark.parametrize("rounding", [1 - RIGID_TOLERANCE / 10, 1.0, 1 + RIGID_TOLERANCE / 10])
def test_a_bound_at_an_end_after_rounding_reaches_that_end(rounding):
    # The tolerance of the rigid flag holds for "spans the whole range" too: a bound a rounding
    # away from an end renders as one at the end, not as the opposite extreme.
    upper = map_estimate(EstimateUpdate(RIGID * rounding, state="upper_bound"), **RANGE)
    assert upper.unknown and upper.stiffness == 0.0 and not upper.rigid
    lower = map_estimate(EstimateUpdate(SOFT * rounding, state="lower_bound"), **RANGE)
    assert lower.unknown and lower.stiffness == 0.0
    spanning = map_estimate(ok(3e4, (SOFT * rounding, RIGID * rounding)), **RANGE)
    assert spanning.unknown
    # a real distance from an end is still placed
    assert not map_estimate(EstimateUpdate(RIGID * 0.999, state="upper_bound"), **RANGE).unknown
    assert not map_estimate(EstimateUpdate(SOFT * 1.001, state="lower_bound"), **RANGE).unknown


def test_rigid_unknown_and_stiffest_ok_are_distinct_commands():
    commands = {
        state: to_command(map_estimate(update, **RANGE), level_max=4095)
        for state, update in {
            "rigid": EstimateUpdate(2e9, (2e9, None), "lower_bound"),
            "unknown": EstimateUpdate(None, state="insufficient_data"),
            "just_below": ok(0.99 * RIGID, (0.9 * RIGID, 0.99 * RIGID)),
            "soft": ok(SOFT, (SOFT, SOFT)),
        }.items()
    }
    assert len(set(commands.values())) == 4
    assert commands["rigid"].rigid and not commands["just_below"].rigid
    assert commands["unknown"].unknown and commands["unknown"].level == 0
    assert commands["soft"].level == 0 and not commands["soft"].unknown


def test_a_missing_interval_is_the_whole_range():
    assert map_estimate(ok(1e5), **RANGE).uncertainty_decades == pytest.approx(FULL_DECADES)


def test_interval_decades_clips_to_the_display_range():
    assert interval_decades(1e4, 1e6, **RANGE) == pytest.approx(2.0)
    assert interval_decades(1.0, 1e4, **RANGE) == pytest.approx(math.log10(1e4 / SOFT))
    assert interval_decades(2e9, 3e9, **RANGE) == 0.0
    assert interval_decades(None, None, **RANGE) == pytest.approx(FULL_DECADES)


def test_provisional_is_carried_through():
    assert map_estimate(ok(1e5, provisional=True), **RANGE).provisional
    assert to_command(map_estimate(ok(1e5, provisional=True), **RANGE), level_max=10).provisional


# --------------------------------------------------------------------------- estimate validation


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"e_pa": math.nan}, "E_pa .* = nan"),
        ({"e_pa": -1.0}, "E_pa .* = -1.0"),
        ({"e_pa": math.inf}, "E_pa .* = inf"),
        ({"e_pa": None}, "E_pa .* = None"),
        ({"e_pa": 1e5, "state": "great"}, "state = 'great'"),
        ({"e_pa": 1e5, "interval_pa": (1e6, 1e4)}, "low above high"),
        ({"e_pa": 1e5, "interval_pa": (math.nan, None)}, r"interval_pa\[0\] = nan"),
        ({"e_pa": 1e5, "interval_pa": (None, -3.0)}, r"interval_pa\[1\] = -3.0"),
        ({"e_pa": 1e5, "interval_pa": (1e6, None)}, "outside its interval"),
        ({"e_pa": 1e5, "interval_pa": (1e3,)}, "expected \\(low or None, high or None\\)"),
        ({"e_pa": 1e5, "t_s": math.nan}, "t_s = nan"),
        ({"e_pa": 1e5, "t_s": True}, "t_s = True: expected a finite time"),
        ({"e_pa": 1e5, "provisional": 1}, "provisional = 1: expected True or False"),
        ({"e_pa": 1e5, "provisional": "no"}, "provisional = 'no'"),
    ],
)
def test_bad_estimates_are_refused_naming_the_field(kwargs, message):
    with pytest.raises(MappingError, match=message):
        EstimateUpdate(**kwargs)


def test_insufficient_data_needs_no_modulus():
    assert EstimateUpdate(None, state="insufficient_data").value_pa is None
    assert EstimateUpdate(1e5, state="insufficient_data").value_pa is None


def test_a_bound_may_come_from_the_interval_alone():
    lower = EstimateUpdate(None, (2e9, None), "lower_bound")
    assert lower.value_pa == 2e9 and map_estimate(lower, **RANGE).rigid
    upper = EstimateUpdate(None, (None, 5e4), "upper_bound")
    explicit = EstimateUpdate(5e4, (None, 5e4), "upper_bound")
    assert map_estimate(upper, **RANGE) == map_estimate(explicit, **RANGE)
    with pytest.raises(MappingError, match="a bound may come from interval_pa"):
        EstimateUpdate(None, (None, 5e4), "lower_bound")


def test_from_estimate_reads_the_bus_estimate_and_its_capture_time():
    estimate = EstimateBody(E_pa=2e5, interval_pa=[1e5, 4e5], state="ok", reason="", provisional=True,
                            grasp_id="g-7", latency_s=0.02, method="hybrid", model=None)
    update = EstimateUpdate.from_estimate(estimate, 12.5)
    assert update == EstimateUpdate(2e5, (1e5, 4e5), "ok", "", True, "g-7", 12.5)
    with pytest.raises(MappingError, match="lies outside its interval_pa"):
        EstimateUpdate.from_estimate(dataclasses.replace(estimate, E_pa=9e5), 12.5)
    # numpy's bool passes the bus's flag check; the update holds Python's
    numpy_flag = EstimateUpdate.from_estimate(dataclasses.replace(estimate, provisional=np.bool_(False)), 1.0)
    assert numpy_flag.provisional is False


# --------------------------------------------------------------------------- smoothing, fade, stale


def test_smoothing_weight_is_a_first_order_lag():
    assert smoothing_weight(0.0, smoothing_s=0.1) == 0.0
    assert smoothing_weight(0.1, smoothing_s=0.1) == pytest.approx(1 - math.exp(-1))
    assert smoothing_weight(0.0, smoothing_s=0.0) == 1.0
    with pytest.raises(MappingError, match="dt_s = -0.1"):
        smoothing_weight(-0.1, smoothing_s=0.1)


percepts = st.builds(
    Percept,
    stiffness=st.floats(0, 1),
    uncertainty_decades=st.floats(0, 20),
    rigid=st.booleans(),
    provisional=st.booleans(),
)
durations = st.floats(0, 1e6, allow_nan=False)


@given(percepts, percepts, durations, st.floats(0, 10))
def test_smoothing_stays_between_previous_and_target(previous, target, dt_s, smoothing_s):
    out = smooth(previous, target, dt_s=dt_s, smoothing_s=smoothing_s)
    for name in ("stiffness", "uncertainty_decades"):
        lo, hi = sorted((getattr(previous, name), getattr(target, name)))
        value = getattr(out, name)
        assert not math.isnan(value)
        assert lo - 1e-12 <= value <= hi + 1e-12
    flags = ("rigid", "unknown", "provisional")
    assert [getattr(out, f) for f in flags] == [getattr(target, f) for f in flags]


@given(percepts, percepts, st.floats(0, 1), st.floats(0, 1), st.floats(0.01, 10))
def test_smoothing_in_two_steps_equals_one_step(previous, target, dt1, dt2, smoothing_s):
    two = smooth(smooth(previous, target, dt_s=dt1, smoothing_s=smoothing_s), target,
                 dt_s=dt2, smoothing_s=smoothing_s)
    one = smooth(previous, target, dt_s=dt1 + dt2, smoothing_s=smoothing_s)
    assert two.stiffness == pytest.approx(one.stiffness, abs=1e-9)


def test_fade_is_linear_to_free():
    assert fade_gain(0.0, fade_s=0.3) == 1.0
    assert fade_gain(0.15, fade_s=0.3) == pytest.approx(0.5)
    assert fade_gain(0.3, fade_s=0.3) == 0.0
    assert fade_gain(5.0, fade_s=0.3) == 0.0
    assert fade_gain(0.0, fade_s=0.0) == 0.0
    held = Percept(stiffness=0.8, uncertainty_decades=1.0, rigid=True)
    half = fade(held, gain=0.5)
    assert half.stiffness == pytest.approx(0.4) and not half.rigid
    with pytest.raises(MappingError, match="gain"):
        fade(held, gain=1.5)


@given(durations, durations, st.floats(0, 10))
def test_fade_gain_never_grows(t1, t2, fade_s):
    early, late = sorted((t1, t2))
    assert 0.0 <= fade_gain(late, fade_s=fade_s) <= fade_gain(early, fade_s=fade_s) <= 1.0


def test_staleness_starts_at_stale_after_s():
    assert not is_stale(10.0, 10.99, stale_after_s=1.0)
    assert is_stale(10.0, 11.0, stale_after_s=1.0)
    with pytest.raises(MappingError, match="before the last update"):
        is_stale(10.0, 9.0, stale_after_s=1.0)
    assert is_stale(-math.inf, 11.0, stale_after_s=1.0)  # never updated


@pytest.mark.parametrize(("last", "now", "after", "match"), [
    (math.nan, 1e9, 0.5, "last_update_s = nan"),
    (math.inf, 1e9, 0.5, "last_update_s = inf"),
    (0.0, math.nan, 0.5, "now_s = nan"),
    (0.0, math.inf, 0.5, "now_s = inf"),
    (0.0, 1e9, math.nan, "stale_after_s = nan"),
    (0.0, 1e9, -1.0, "stale_after_s = -1.0"),
    (0.0, 1e9, "1", "stale_after_s = '1'"),
    (True, 1e9, 0.5, "last_update_s = True"),
])
def test_staleness_refuses_bad_arguments_by_name(last, now, after, match):
    with pytest.raises(MappingError, match=match):
        is_stale(last, now, stale_after_s=after)


@pytest.mark.parametrize("e_pa", [1e-320, 5e-324, 2.2e-308])
def test_a_denormal_modulus_is_at_the_soft_end(e_pa):
    assert stiffness_fraction(e_pa, e_soft_pa=5e3, e_rigid_pa=6.75e6) == 0.0
    percept = map_estimate(EstimateUpdate(e_pa=e_pa), e_soft_pa=5e3, e_rigid_pa=6.75e6)
    assert percept.stiffness == 0.0 and not percept.rigid
    assert to_command(percept, level_max=4095).level == 0


def test_a_range_spanning_the_whole_float_range_maps_without_error():
    soft, rigid = 5e-324, 1.7e308
    assert stiffness_fraction(1.0, e_soft_pa=soft, e_rigid_pa=rigid) == pytest.approx(
        (math.log(1.0) - math.log(soft)) / (math.log(rigid) - math.log(soft)))
    assert math.isfinite(interval_decades(None, None, e_soft_pa=soft, e_rigid_pa=rigid))
    assert math.isfinite(just_noticeable_steps(soft, rigid))


# --------------------------------------------------------------------------- quantisation


def test_to_command_quantises_level_and_uncertainty():
    command = to_command(Percept(stiffness=0.5, uncertainty_decades=2.0), level_max=4095,
                         stale=True, fading=True)
    assert command.level == 2048 and command.uncertainty == 40
    assert command.stale and command.fading
    assert to_command(Percept(uncertainty_decades=50.0), level_max=1).uncertainty == 255
    assert to_command(FREE, level_max=4095).level == 0


@pytest.mark.parametrize("level_max", [0, 65536, 2.5, True])
def test_to_command_refuses_a_bad_level_max(level_max):
    with pytest.raises(MappingError, match="level_max"):
        to_command(FREE, level_max=level_max)


def test_to_command_refuses_a_nan_percept():
    with pytest.raises(MappingError, match="stiffness = nan"):
        to_command(Percept(stiffness=math.nan), level_max=10)


updates = st.one_of(
    st.builds(EstimateUpdate, e_pa=st.none(), state=st.just("insufficient_data")),
    st.builds(lambda e, state: EstimateUpdate(e, (None, None), state), moduli,
              st.sampled_from(ESTIMATE_STATES[:3])),
    st.builds(lambda a, b, c: EstimateUpdate(sorted((a, b, c))[1], (min(a, b, c), max(a, b, c))),
              moduli, moduli, moduli),
)


@given(updates, st.integers(1, 0xFFFF), st.floats(1e-3, 1e6), st.floats(1.001, 1e9))
@example(EstimateUpdate(1.0, (0.0010000000000000002, 1.0)), 1, 0.001, 2.0)  # a low end one ulp above soft
def test_any_estimate_gives_a_valid_command(update, level_max, e_soft_pa, ratio):
    assume(math.isfinite(e_soft_pa * ratio))
    percept = map_estimate(update, e_soft_pa=e_soft_pa, e_rigid_pa=e_soft_pa * ratio)
    assert 0.0 <= percept.stiffness <= 1.0
    assert 0.0 <= percept.uncertainty_decades <= math.log10(ratio) + 1e-9
    command = to_command(percept, level_max=level_max)
    assert 0 <= command.level <= level_max
    assert not (command.rigid and command.unknown)
    # Unknown: a refusal, or an interval over the whole range (a bound's open side reaching past its end).
    low, high = update.interval_pa
    low = update.value_pa if update.state == "lower_bound" and low is None else low
    high = update.value_pa if update.state == "upper_bound" and high is None else high
    tol = RIGID_TOLERANCE  # a bound within it of an end reaches that end (haptics.mapping)
    spans = ((update.state == "upper_bound" if low is None else low <= e_soft_pa * (1 + tol))
             and (update.state == "lower_bound" if high is None else high >= e_soft_pa * ratio * (1 - tol)))
    assert command.unknown == (update.state == "insufficient_data" or spans)


# --------------------------------------------------------------------------- the shipped range


def shipped_range() -> dict[str, float]:
    display = display_settings(load_settings())
    return {"e_soft_pa": display.e_soft_pa, "e_rigid_pa": display.e_rigid_pa}


def test_a_lower_bound_at_the_sensors_resolution_limit_renders_rigid():
    limit = load_settings().resolution_limit_pa
    for bound in (limit, float(f"{limit:.6g}"), limit * (1 - RIGID_TOLERANCE / 2), limit * 10):
        percept = map_estimate(EstimateUpdate(bound, (bound, None), "lower_bound"), **shipped_range())
        assert percept.rigid and percept.stiffness == 1.0 and percept.uncertainty_decades == pytest.approx(0, abs=1e-9)
        command = to_command(percept, level_max=4095)
        assert command.rigid and command.level == 4095
    # An ok estimate at the limit is rigid too; an upper bound never is.
    assert map_estimate(ok(limit, (limit / 2, limit * 2)), **shipped_range()).rigid
    assert not map_estimate(EstimateUpdate(limit, (None, limit), "upper_bound"), **shipped_range()).rigid


def test_a_lower_bound_below_the_limit_renders_at_its_bound_and_not_rigid():
    limit = load_settings().resolution_limit_pa
    for bound in (limit / 1.15, limit * (1 - 1e-6)):
        percept = map_estimate(EstimateUpdate(bound, (bound, None), "lower_bound"), **shipped_range())
        assert not percept.rigid
        assert percept.stiffness == pytest.approx(stiffness_fraction(bound, **shipped_range()))
        assert percept.stiffness < 1.0
        command = to_command(percept, level_max=4095)
        assert not command.rigid


def test_just_noticeable_steps_count_weber_fractions_of_e():
    limit = load_settings().resolution_limit_pa
    assert just_noticeable_steps(5e3, limit) == pytest.approx(math.log(limit / 5e3) / math.log(1.15))
    assert 50 < just_noticeable_steps(5e3, limit) < 54  # "about 52" (module notes)
    assert just_noticeable_steps(1e3, 1e3 * 1.15**10) == pytest.approx(10.0)
    assert just_noticeable_steps(1e3, 2e3, weber_fraction=1.0) == pytest.approx(1.0)
    # Equal ratios of E are equally many steps, wherever they lie on the scale.
    assert just_noticeable_steps(1e4, 1e5) == pytest.approx(just_noticeable_steps(1e6, 1e7))
    with pytest.raises(MappingError, match="e_rigid_pa"):
        just_noticeable_steps(1e6, 1e3)
    for bad in (0.0, -0.1, math.nan, True):
        with pytest.raises(MappingError, match="weber_fraction"):
            just_noticeable_steps(1e3, 1e6, weber_fraction=bad)


def test_one_just_noticeable_step_is_about_one_uncertainty_count():
    # An interval one Weber fraction wide, inside the range, quantises to one count (1/20 decade).
    percept = map_estimate(ok(1e5, (1e5, 1.15e5)), **shipped_range())
    assert to_command(percept, level_max=4095).uncertainty == 1


@pytest.mark.parametrize("update", [None, {"e_pa": 1e5}])
def test_map_estimate_requires_an_estimate_update(update):
    with pytest.raises(MappingError, match=r"update: expected an EstimateUpdate, got .*EstimateUpdate\.from_estimate"):
        map_estimate(update, e_soft_pa=1e3, e_rigid_pa=1e6)


def test_map_estimate_refuses_an_estimator_estimate():
    from estimator.estimate import Estimate

    estimate = Estimate(method="series", e_pa=1e5, interval_pa=(5e4, 2e5), state="ok")
    with pytest.raises(MappingError, match="update: expected an EstimateUpdate, got Estimate"):
        map_estimate(estimate, e_soft_pa=1e3, e_rigid_pa=1e6)
