"""The renderer, step by step on a simulated display, time driven by the test."""

from __future__ import annotations

import math
from dataclasses import replace

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from haptics.devices.sim import DisplayFirmware, SimulatedDisplay
from haptics.errors import MappingError, ProtocolError
from haptics.mapping import ESTIMATE_STATES, EstimateUpdate, map_estimate, stiffness_fraction
from haptics.protocol import DisplayInfo, decode_output_report
from haptics.renderer import HapticRenderer
from haptics.settings import DisplaySettings, display_settings
from teleop.settings import load_settings

SETTINGS = DisplaySettings(
    e_soft_pa=5e3, e_rigid_pa=1e9, smoothing_s=0.1, fade_s=0.3, stale_after_s=1.0, keepalive_s=0.2
)
LEVEL_MAX = 4095


def estimate(e_pa=1e6, *, grasp="g1", t_s=0.0, state="ok", interval=(None, None), provisional=False):
    return EstimateUpdate(e_pa, interval, state, "", provisional, grasp, t_s)


def written(display: SimulatedDisplay) -> list:
    """Commands the display received, in order."""
    return [decode_output_report(data).command for kind, data in display.log if kind == "output"]


def make(settings=SETTINGS):
    display = SimulatedDisplay()
    return display, HapticRenderer(display, settings)


def run_ticks(renderer, start_s, stop_s, step_s=0.01):
    """Tick from start to stop inclusive; returns the commands as of each tick."""
    n = round((stop_s - start_s) / step_s)
    return [renderer.tick(start_s + i * step_s) for i in range(n + 1)]


def target_level(e_pa):
    return round(stiffness_fraction(e_pa, e_soft_pa=5e3, e_rigid_pa=1e9) * LEVEL_MAX)


def test_first_tick_connects_and_writes_free():
    display, renderer = make()
    command = renderer.tick(0.0)
    assert display.connected and renderer.stats.connects == 1
    assert command.level == 0 and command.flags == 0
    assert written(display) == [command]
    assert renderer.phase == "idle"


def test_level_follows_the_estimate_with_the_smoothing_time_constant():
    _, renderer = make()
    renderer.tick(0.0)
    renderer.on_estimate(estimate(1e6), 0.0)
    assert renderer.phase == "active"
    target = target_level(1e6)
    levels = [c.level for c in run_ticks(renderer, 0.01, 0.6)]
    assert levels == sorted(levels)  # approaches without overshoot
    # After one time constant (0.1 s): 1 - 1/e of the way; after five: within 1 %.
    assert levels[9] == pytest.approx((1 - math.exp(-1)) * target, abs=1)
    assert levels[49] == pytest.approx(target, rel=0.01)


def test_without_smoothing_the_estimate_is_written_at_once_and_latency_measured():
    display, renderer = make(replace(SETTINGS, smoothing_s=0.0))
    renderer.tick(10.0)
    renderer.on_estimate(estimate(1e6, t_s=9.97), 10.0)
    assert written(display)[-1].level == target_level(1e6)
    assert renderer.stats.last_latency_s == pytest.approx(0.03)
    assert renderer.stats.reports_sent == 2


def test_latency_is_measured_at_the_first_write_after_the_estimate():
    display, renderer = make()
    renderer.tick(10.0)
    renderer.on_estimate(estimate(1e6, t_s=9.98), 10.0)
    renderer.tick(10.01)
    assert renderer.stats.last_latency_s == pytest.approx(0.03)


def test_unchanged_commands_are_written_only_as_keep_alive():
    display, renderer = make(replace(SETTINGS, keepalive_s=0.25))
    run_ticks(renderer, 0.0, 1.0, 1 / 64)  # idle, free: unchanged the whole second
    outputs = [data for kind, data in display.log if kind == "output"]
    assert len(outputs) == 5  # t = 0, 0.25, 0.5, 0.75, 1.0 (exact binary times)
    assert renderer.stats.reports_sent == 5


def test_stale_after_stale_after_s_holds_the_last_level_and_recovers():
    display, renderer = make()
    renderer.tick(0.0)
    renderer.on_estimate(estimate(1e6, provisional=True), 0.0)
    run_ticks(renderer, 0.01, 0.99)
    held = renderer.tick(0.99)
    assert not held.stale and renderer.phase == "active"
    stale = renderer.tick(1.0)
    assert stale.stale and renderer.phase == "stale"
    assert stale.level == held.level
    later = run_ticks(renderer, 1.01, 3.0)
    assert all(c.stale and c.level == held.level for c in later)
    assert written(display)[-1].stale
    # Updates resume with a different estimate: the flag clears at once and the level moves.
    renderer.on_estimate(estimate(1e8, t_s=3.0, provisional=True), 3.0)
    assert renderer.phase == "active"
    assert not written(display)[-1].stale
    moved = run_ticks(renderer, 3.01, 3.6)
    assert not any(c.stale for c in moved)
    assert moved[-1].level == pytest.approx(target_level(1e8), rel=0.01)


def test_stale_holds_the_value_reached_when_it_went_stale():
    _, renderer = make(replace(SETTINGS, smoothing_s=1.0, stale_after_s=0.5))
    renderer.tick(0.0)
    renderer.on_estimate(estimate(1e9, provisional=True), 0.0)
    # One long tick across the stale time: smoothing stops at 0.5 s, not at 5 s.
    command = renderer.tick(5.0)
    assert command.stale
    assert command.level == pytest.approx((1 - math.exp(-0.5)) * LEVEL_MAX, abs=1)


def test_a_final_estimate_never_goes_stale_and_settles_on_its_value():
    # A discrete grasp holds and opens for seconds after its final: no estimate is due then.
    display, renderer = make(replace(SETTINGS, smoothing_s=1.0, stale_after_s=0.5))
    renderer.tick(0.0)
    renderer.on_estimate(estimate(1e6, provisional=True), 0.0)
    renderer.on_estimate(estimate(1e9), 0.2)
    command = renderer.tick(10.0)
    assert not command.stale and renderer.phase == "active"
    assert command.level == LEVEL_MAX and not any(c.stale for c in written(display))


def test_grasp_end_fades_to_free_and_ignores_late_estimates():
    display, renderer = make(replace(SETTINGS, smoothing_s=0.0))
    renderer.tick(0.0)
    renderer.on_estimate(estimate(1e7), 0.0)
    start = renderer.tick(0.1).level
    renderer.on_grasp_end("g1", 0.1)
    assert renderer.phase == "fading" and written(display)[-1].fading
    half = renderer.tick(0.25)
    assert half.fading and half.level == pytest.approx(start / 2, abs=1)
    end = renderer.tick(0.4)
    assert end.level == 0 and end.flags == 0 and renderer.phase == "idle"
    assert written(display)[-1] == end
    renderer.on_estimate(estimate(1e8), 0.45)  # late estimate of the ended grasp
    assert renderer.stats.estimates_ignored == 1
    assert renderer.tick(0.5).level == 0


def test_release_fades_a_stale_value_to_free_but_lets_its_grasp_engage_again():
    display, renderer = make(replace(SETTINGS, smoothing_s=0.0))
    renderer.tick(0.0)
    renderer.on_estimate(estimate(1e8, provisional=True), 0.0)
    assert renderer.tick(1.5).stale  # no estimate for stale_after_s: held, flagged
    renderer.release(1.5)
    assert renderer.phase == "fading" and written(display)[-1].fading and not written(display)[-1].stale
    assert renderer.tick(1.9).level == 0 and renderer.phase == "idle"
    renderer.on_estimate(estimate(1e8, provisional=True), 2.0)  # the same grasp, its estimator back
    assert renderer.phase == "active" and renderer.grasp_id == "g1" and renderer.stats.estimates_ignored == 0
    assert renderer.tick(2.0).level == target_level(1e8)


def test_fade_levels_fall_monotonically():
    _, renderer = make()
    renderer.tick(0.0)
    renderer.on_estimate(estimate(1e8), 0.0)
    run_ticks(renderer, 0.01, 0.5)
    renderer.on_grasp_end("g1", 0.5)
    levels = [c.level for c in run_ticks(renderer, 0.5, 0.9)]
    assert levels == sorted(levels, reverse=True) and levels[-1] == 0


def test_a_new_grasp_during_the_fade_takes_over():
    _, renderer = make()
    renderer.tick(0.0)
    renderer.on_estimate(estimate(1e8, grasp="a"), 0.0)
    run_ticks(renderer, 0.01, 0.5)
    renderer.on_grasp_end("a", 0.5)
    renderer.tick(0.6)
    renderer.on_estimate(estimate(1e5, grasp="b"), 0.6)
    assert renderer.phase == "active" and renderer.grasp_id == "b"
    assert not renderer.tick(0.61).fading
    assert run_ticks(renderer, 0.61, 1.2)[-1].level == pytest.approx(target_level(1e5), rel=0.01)


def test_a_new_grasp_id_ends_the_previous_grasp():
    _, renderer = make()
    renderer.on_estimate(estimate(1e6, grasp="a"), 0.0)
    renderer.on_estimate(estimate(1e6, grasp="b"), 0.1)
    renderer.on_estimate(estimate(1e6, grasp="a"), 0.2)  # a straggler of grasp a
    assert renderer.grasp_id == "b" and renderer.stats.estimates_ignored == 1


def test_a_late_estimate_of_a_grasp_ended_a_few_grasps_ago_is_still_ignored():
    # The renderer remembers more ended grasps than the last one: a straggler held up on the bus for a
    # few grasps must not re-engage the display.
    _, renderer = make(replace(SETTINGS, smoothing_s=0.0))
    for i, grasp in enumerate(("a", "b", "c")):
        renderer.on_estimate(estimate(1e6, grasp=grasp), 2.0 * i)
        renderer.on_grasp_end(grasp, 2.0 * i + 0.5)
    assert renderer.tick(6.0).level == 0 and renderer.phase == "idle"
    renderer.on_estimate(estimate(1e8, grasp="a", provisional=True), 6.01)
    assert renderer.phase == "idle" and renderer.stats.estimates_ignored == 1
    assert renderer.tick(6.5).level == 0


def test_rigid_and_unknown_states_reach_the_display():
    display, renderer = make(replace(SETTINGS, smoothing_s=0.0))
    renderer.on_estimate(estimate(None, state="insufficient_data", provisional=True), 0.0)
    assert written(display)[-1].unknown and written(display)[-1].level == 0
    renderer.on_estimate(estimate(5e9, state="lower_bound", interval=(5e9, None)), 0.1)
    rigid = written(display)[-1]
    assert rigid.rigid and not rigid.unknown and rigid.level == LEVEL_MAX
    renderer.on_grasp_end("g1", 0.2)
    assert not written(display)[-1].rigid  # a fading display may yield


def test_unplug_then_replug_resends_the_last_command_and_resumes():
    display, renderer = make(replace(SETTINGS, smoothing_s=0.0))
    renderer.on_estimate(estimate(1e6, provisional=True), 0.0)
    display.unplug()
    renderer.on_estimate(estimate(1e7), 0.1)  # this write fails: the display is gone
    assert renderer.stats.write_failures == 1 and not display.connected
    wanted = renderer.command
    assert wanted.level == target_level(1e7)
    run_ticks(renderer, 0.11, 0.5)  # reconnect attempts fail, with backoff
    assert not display.connected and renderer.stats.connects == 1
    display.replug()
    assert display.rendered_command is None  # power-on reset: the display forgot
    before = len(written(display))
    commands = run_ticks(renderer, 0.51, 1.0)
    assert display.connected and renderer.stats.connects == 2
    # The first report after the replug is the command whose write had failed.
    assert written(display)[before] == wanted
    assert display.rendered_command == commands[-1] == wanted


def test_time_must_not_go_backwards():
    _, renderer = make()
    renderer.tick(5.0)
    with pytest.raises(MappingError, match="before the previous call"):
        renderer.tick(4.0)
    with pytest.raises(MappingError, match="finite"):
        renderer.tick(math.nan)


events = st.lists(
    st.one_of(
        st.tuples(st.just("tick"), st.floats(0, 0.5)),
        st.tuples(st.just("end"), st.floats(0, 0.5)),
        st.tuples(
            st.sampled_from(ESTIMATE_STATES),
            st.floats(0, 0.5),
            st.floats(1.0, 1e12),
            st.sampled_from(["a", "b", "c"]),
        ),
    ),
    max_size=40,
)


@settings(max_examples=60, deadline=None)
@given(events)
def test_any_event_sequence_writes_only_valid_reports(sequence):
    display, renderer = make()
    now, grasp = 0.0, "a"
    for event in sequence:
        now += event[1]
        if event[0] == "tick":
            renderer.tick(now)
        elif event[0] == "end":
            renderer.on_grasp_end(grasp, now)
        else:
            state, _, e_pa, grasp = event
            e_pa = None if state == "insufficient_data" else e_pa
            update = estimate(e_pa, grasp=grasp, state=state)
            renderer.on_estimate(update, now)
        p = renderer.percept
        assert 0.0 <= p.stiffness <= 1.0 and math.isfinite(p.uncertainty_decades)
    for command in written(display):
        assert 0 <= command.level <= LEVEL_MAX
        assert not (command.rigid and command.unknown)
    assert renderer.stats.reports_sent == len(written(display))


def test_stiffer_estimates_settle_on_higher_levels():
    levels = []
    for e_pa in (1e4, 1e5, 1e6, 1e7, 1e8):
        _, renderer = make(replace(SETTINGS, stale_after_s=5.0))
        renderer.on_estimate(estimate(e_pa), 0.0)
        levels.append(run_ticks(renderer, 0.0, 2.0, 0.05)[-1].level)  # 20 time constants
        assert levels[-1] == round(map_estimate(estimate(e_pa), e_soft_pa=5e3,
                                                e_rigid_pa=1e9).stiffness * LEVEL_MAX)
    assert levels == sorted(levels) and len(set(levels)) == 5


def test_an_unresolved_display_range_is_refused_naming_e_rigid_pa():
    # A bare DisplaySettings() leaves the rigid end at 0: "the sensor's resolution limit", unknown here.
    with pytest.raises(MappingError, match=r"e_rigid_pa = 0\.0: unresolved.*display_settings\(load_settings\(\.\.\.\)\)"):
        HapticRenderer(SimulatedDisplay(), DisplaySettings())
    HapticRenderer(SimulatedDisplay(), DisplaySettings(e_rigid_pa=1e9))  # set explicitly: fine


def test_with_the_shipped_settings_a_bound_at_the_resolution_limit_is_rigid():
    settings = load_settings()
    display, renderer = make(replace(display_settings(settings), smoothing_s=0.0))
    limit = settings.resolution_limit_pa
    renderer.on_estimate(estimate(limit, state="lower_bound", interval=(limit, None), provisional=True), 0.0)
    rigid = written(display)[-1]
    assert rigid.rigid and rigid.level == LEVEL_MAX and rigid.uncertainty == 0
    assert renderer.target.rigid and renderer.target.stiffness == 1.0
    below = limit / 2
    renderer.on_estimate(estimate(below, state="lower_bound", interval=(below, None)), 0.1)
    bound = written(display)[-1]
    fraction = stiffness_fraction(below, e_soft_pa=display_settings(settings).e_soft_pa, e_rigid_pa=limit)
    assert not bound.rigid and bound.level == round(fraction * LEVEL_MAX) < LEVEL_MAX


def test_an_estimate_that_cannot_become_a_command_leaves_the_renderer_as_it_was():
    with pytest.raises(MappingError, match="provisional = 1: expected True or False"):
        EstimateUpdate(1e5, grasp_id="A", provisional=1)
    display, renderer = make()
    renderer.tick(0.0)
    bad = estimate(1e5, grasp="A")
    object.__setattr__(bad, "provisional", 1)  # past the checks, as a careless caller might
    with pytest.raises(ProtocolError, match="provisional = 1"):
        renderer.on_estimate(bad, 0.1)
    assert renderer.phase == "idle" and renderer.grasp_id is None and renderer.stats.estimates == 0
    assert renderer.tick(0.2).level == 0
    renderer.on_grasp_end("A", 0.3)
    renderer.on_estimate(estimate(1e5, grasp="B"), 0.4)
    assert renderer.grasp_id == "B"


def test_a_provisional_estimate_after_the_final_is_ignored():
    display, renderer = make(replace(SETTINGS, smoothing_s=0.0, stale_after_s=0.5))
    renderer.on_estimate(estimate(1e6, provisional=True), 0.0)
    renderer.on_estimate(estimate(1e7), 0.1)  # the final: the grasp's last
    final = renderer.command
    renderer.on_estimate(estimate(1e5, provisional=True), 0.2)
    renderer.on_estimate(estimate(1e4), 0.3)
    assert renderer.stats.estimates_ignored == 2 and renderer.command == final
    later = renderer.tick(5.0)
    assert later == final and not later.stale and renderer.phase == "active"
    assert not any(c.stale for c in written(display))


def test_an_ignored_estimate_leaves_the_command_current():
    _, renderer = make(replace(SETTINGS, smoothing_s=0.0))
    renderer.on_estimate(estimate(1e7), 0.0)
    renderer.on_grasp_end("g1", 0.1)
    assert renderer.command.fading
    renderer.on_estimate(estimate(1e7), 1.0)  # late: the fade ended at 0.4
    assert renderer.phase == "idle" and renderer.stats.estimates_ignored == 1
    assert renderer.command.level == 0 and renderer.command.flags == 0


def test_a_display_whose_watchdog_is_not_longer_than_the_keep_alive_gets_a_longer_one(caplog):
    display, renderer = make(replace(SETTINGS, keepalive_s=1.0))  # the simulated watchdog: 1000 ms
    with caplog.at_level("WARNING", logger="haptics.renderer"):
        assert renderer.tick(0.0).level == 0  # no refusal: the display is used
        renderer.on_estimate(estimate(1e6), 0.1)
        run_ticks(renderer, 0.1, 3.0, step_s=0.1)
    assert display.info.watchdog_ms == display.firmware.info.watchdog_ms == 2000  # twice the keep-alive
    assert written(display)[-1].level == target_level(1e6) and display.firmware.state == "rendering"
    (record,) = caplog.records  # once, naming the display and both values
    assert record.levelname == "WARNING" and "simulated display" in record.getMessage()
    assert "watchdog_ms = 1000 ms" in record.getMessage() and "keepalive_s = 1 s" in record.getMessage()
    assert "set it to 2000 ms" in record.getMessage()
    display, renderer = make(replace(SETTINGS, keepalive_s=0.999))
    assert renderer.tick(0.0).level == 0 and display.info.watchdog_ms == 1000  # longer already: kept
    off = SimulatedDisplay(firmware=DisplayFirmware(DisplayInfo(4095, watchdog_ms=0)))
    assert HapticRenderer(off, replace(SETTINGS, keepalive_s=60.0)).tick(0.0).level == 0  # no watchdog
    assert off.info.watchdog_ms == 0  # off stays off
