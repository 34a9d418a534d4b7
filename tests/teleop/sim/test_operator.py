"""The simulated operator: seeded, person-like, closed loop on the force it feels."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from teleop.operator import FOLLOW_RATE_HZ, FOLLOW_SPEED_M_S
from teleop.sim.operator import (
    GIVE_UP_S,
    MIN_PEAK_FORCE_N,
    OPEN_TOLERANCE_M,
    SQUEEZE_SPEED_M_S,
    STALL_GAP_M,
    OperatorCommand,
    OperatorStyle,
    SimulatedOperator,
    draw_style,
)

MAX_WIDTH_M = 0.08
MAX_FORCE_N = 30.0
STEP_S = 1.0 / FOLLOW_RATE_HZ


def style_of(seed: int, max_force_n: float = MAX_FORCE_N) -> OperatorStyle:
    return draw_style(np.random.default_rng(seed), max_force_n=max_force_n)


def first_seed(where) -> int:
    """The first seed whose operator style satisfies ``where(style)``."""
    return next(s for s in range(500) if where(style_of(s)))


def drive(seed: int, *, stiffness_n_per_m: float, extent_m: float = 0.04, cap_n: float = MAX_FORCE_N,
          open_to_m: float = MAX_WIDTH_M, max_s: float = 40.0, dt: float = 1e-3) -> tuple[SimulatedOperator, dict]:
    """One grasp of a spring-like object: force k (extent - width), capped at ``cap_n`` (the
    gripper's force limit, where the fingers stall); the fingers follow the enabled target at
    FOLLOW_SPEED_M_S, open after the release, and never open wider than ``open_to_m``. "steps"
    holds (t, phase after the step, command, width, force) per operator step."""
    op = SimulatedOperator(np.random.default_rng(seed), max_width_m=MAX_WIDTH_M, max_force_n=MAX_FORCE_N)
    every = round(1.0 / FOLLOW_RATE_HZ / dt)
    width, target, released = open_to_m, open_to_m, False
    out = {"t": [], "force": [], "width": [], "commands": [], "steps": [], "releases": 0}
    for i in range(round(max_s / dt)):
        t = i * dt
        force = min(stiffness_n_per_m * max(extent_m - width, 0.0), cap_n)
        if i % every == 0:
            command = op.step(t, force_n=force, width_m=width)
            out["commands"].append(command)
            out["steps"].append((t, op.phase, command, width, force))
            out["releases"] += command.release
            released |= command.release
            if command.enable:
                target = command.target_width_m
        if released:
            target = MAX_WIDTH_M
        width = width + float(np.clip(target - width, -FOLLOW_SPEED_M_S * dt, FOLLOW_SPEED_M_S * dt))
        # The force limit stalls them; they open no wider than open_to_m.
        width = min(max(width, extent_m - cap_n / stiffness_n_per_m, 0.0), open_to_m)
        out["t"].append(t)
        out["force"].append(force)
        out["width"].append(width)
        if op.done:
            break
    return op, out


def test_same_seed_same_operator_and_commands():
    a, run_a = drive(3, stiffness_n_per_m=3000.0)
    b, run_b = drive(3, stiffness_n_per_m=3000.0)
    assert a.style == b.style
    assert run_a["commands"] == run_b["commands"]
    c, _ = drive(4, stiffness_n_per_m=3000.0)
    assert c.style != a.style


def test_styles_occur_across_seeds():
    styles = [draw_style(np.random.default_rng(seed), max_force_n=MAX_FORCE_N) for seed in range(200)]
    traits = {name: sum(name in s.traits for s in styles) for name in ("pauses", "re-squeezes", "never still", "holds")}
    assert all(count >= 20 for count in traits.values()), traits
    speeds = np.array([s.squeeze_speed_m_s for s in styles])
    assert speeds.min() < 0.01 and speeds.max() > 0.06  # slower and faster than the paper's 3.75 cm/s
    peaks = [p for s in styles for p in s.peaks_n]
    assert min(peaks) >= MIN_PEAK_FORCE_N and max(peaks) <= MAX_FORCE_N  # max force respected as a goal
    re_squeezes = [s.peaks_n for s in styles if len(s.peaks_n) > 1]
    assert any(p[1] > p[0] for p in re_squeezes) and any(p[1] < p[0] for p in re_squeezes)
    assert all(isinstance(s.describe(), str) and "N" in s.describe() for s in styles)
    assert "never holds still" in next(s for s in styles if s.hold_s == 0).describe()


@pytest.mark.parametrize("stiffness", [500.0, 5000.0, 2e5])
@pytest.mark.parametrize("seed", range(8))
def test_releases_once_and_finishes(seed, stiffness):
    op, run = drive(seed, stiffness_n_per_m=stiffness)
    assert op.done
    assert run["releases"] == 1
    commands: list[OperatorCommand] = run["commands"]
    assert all(0.0 <= c.target_width_m <= MAX_WIDTH_M for c in commands)
    release = next(i for i, c in enumerate(commands) if c.release)
    assert all(c.enable for c in commands[:release]) and not any(c.enable for c in commands[release:])
    assert max(run["force"]) > 0.3  # it touched


def test_squeezes_to_its_goal_on_a_soft_object():
    for seed in range(10):
        op, run = drive(seed, stiffness_n_per_m=800.0, extent_m=0.06)
        goal = max(op.style.peaks_n)
        # A soft spring: it reaches its goal and overshoots it only by what it closes while it
        # has not felt it yet.
        overshoot = 800.0 * 0.09 * op.style.reaction_delay_s
        assert 0.8 * goal <= max(run["force"]) <= goal + overshoot + 0.5, op.style.describe()


def test_its_hand_never_closes_faster_than_0_09_m_s():
    # A margin under the fingers' follow speed (FOLLOW_SPEED_M_S): seed 4 draws a squeeze whose speed
    # variation would pass it uncapped.
    for seed in range(12):
        op, run = drive(seed, stiffness_n_per_m=300.0)
        commands = run["commands"]
        closing_m_s = [(a.target_width_m - b.target_width_m) * FOLLOW_RATE_HZ
                       for a, b in zip(commands[:-1], commands[1:], strict=True) if a.enable and b.enable]
        assert max(closing_m_s) <= 0.09 + 1e-9, op.style.describe()


def test_backs_off_and_re_squeezes():
    seed = next(s for s in range(100) if len(draw_style(np.random.default_rng(s), max_force_n=MAX_FORCE_N)
                                            .backoff_to) == 1)
    op, run = drive(seed, stiffness_n_per_m=1000.0, extent_m=0.06)
    release = next(i for i, c in enumerate(run["commands"]) if c.release)
    force = np.array(run["force"])[: round(release / FOLLOW_RATE_HZ / 1e-3)]  # until the release
    first = op.style.peaks_n[0]
    crossed = np.flatnonzero(force >= 0.9 * first)[0]
    dip = crossed + int(np.argmin(force[crossed:]))
    assert force[crossed:dip].max() - force[dip] > 0.2 * first  # it let the force fall
    assert np.any(force[dip:] > force[dip] + 0.2 * first)  # and squeezed again


def test_reaction_delay_makes_it_overshoot_a_stiff_object():
    op, run = drive(0, stiffness_n_per_m=2e5)
    assert max(run["force"]) == pytest.approx(MAX_FORCE_N)  # the fingers' force limit holds them
    assert op.done


def test_rejects_bad_limits():
    for max_width_m in (0.0, -0.01, float("inf"), float("nan")):
        with pytest.raises(ValueError, match="max_width_m"):
            SimulatedOperator(np.random.default_rng(0), max_width_m=max_width_m, max_force_n=MAX_FORCE_N)
    for max_force_n in (0.0, -5.0, float("inf"), float("nan")):
        with pytest.raises(ValueError, match="max_force_n"):
            SimulatedOperator(np.random.default_rng(0), max_width_m=MAX_WIDTH_M, max_force_n=max_force_n)


def test_style_is_frozen():
    style = draw_style(np.random.default_rng(1), max_force_n=MAX_FORCE_N)
    assert isinstance(style, OperatorStyle)
    with pytest.raises(dataclasses.FrozenInstanceError):
        style.hold_s = 3.0  # type: ignore[misc]


def _approach(op: SimulatedOperator, fingers, max_s: float = 30.0) -> list[tuple[float, OperatorCommand]]:
    """Step ``op`` at the follow rate with no force felt, the fingers at ``fingers(t, target)``,
    until it is done; (time, command) per step."""
    steps, dt, target = [], 1.0 / FOLLOW_RATE_HZ, MAX_WIDTH_M
    for i in range(round(max_s / dt)):
        t = i * dt
        command = op.step(t, force_n=0.0, width_m=fingers(t, target))
        target = command.target_width_m
        steps.append((t, command))
        if op.done:
            break
    return steps


def _one_release(steps: list[tuple[float, OperatorCommand]]) -> float:
    """When the operator released, checking it released once and let go of the enable for good."""
    (at,) = [i for i, (_, c) in enumerate(steps) if c.release]
    assert all(c.enable for _, c in steps[:at]) and not any(c.enable for _, c in steps[at:])
    return steps[at][0]


def test_it_gives_up_an_approach_the_fingers_stop_following():
    # The robot's watchdog ended the grasp (the console was paused): the fingers stopped short of
    # the object. It must let go of the enable (the console waits for that), and be done
    # although nothing opens the fingers again.
    op = SimulatedOperator(np.random.default_rng(0), max_width_m=MAX_WIDTH_M, max_force_n=MAX_FORCE_N)
    stopped_s, stopped_at = 0.4 + op.style.start_delay_s, []

    def fingers(t: float, target: float) -> float:
        if t >= stopped_s and not stopped_at:
            stopped_at.append(target)
        return stopped_at[0] if stopped_at else target

    steps = _approach(op, fingers)
    released_s = _one_release(steps)
    assert stopped_s + GIVE_UP_S <= released_s <= stopped_s + GIVE_UP_S + 1.0
    assert op.done and stopped_at[0] < MAX_WIDTH_M - 0.005 and steps[-1][0] >= released_s + GIVE_UP_S
    assert steps[-1][1].target_width_m == MAX_WIDTH_M  # its hand opened


def test_it_gives_up_when_its_grip_closes_on_nothing():
    op = SimulatedOperator(np.random.default_rng(1), max_width_m=MAX_WIDTH_M, max_force_n=MAX_FORCE_N)
    steps = _approach(op, lambda t, target: target)  # the fingers follow, and open with its hand
    released_s = _one_release(steps)
    closed_s = op.style.start_delay_s + MAX_WIDTH_M / op.style.approach_speed_m_s
    assert op.done and closed_s + GIVE_UP_S <= released_s <= closed_s + GIVE_UP_S + 0.1


def test_a_slow_start_of_the_robot_does_not_make_it_give_up():
    # The fingers stay open for a second (the robot prepares its grasp), then follow.
    late = SimulatedOperator(np.random.default_rng(2), max_width_m=MAX_WIDTH_M, max_force_n=MAX_FORCE_N)
    steps = _approach(late, lambda t, target: MAX_WIDTH_M if t < 0.5 * GIVE_UP_S else target, max_s=0.9 * GIVE_UP_S)
    assert late.phase == "approach" and all(c.enable and not c.release for _, c in steps)


def test_it_gives_up_a_back_off_the_fingers_no_longer_follow():
    # The demo stalled: the robot's watchdog stopped the fingers at the first peak, and the hand,
    # backing off, waited for a force that could no longer fall; the demo's next grasp never came.
    seed = next(s for s in range(100) if len(draw_style(np.random.default_rng(s), max_force_n=MAX_FORCE_N)
                                            .backoff_to) == 1)
    op = SimulatedOperator(np.random.default_rng(seed), max_width_m=MAX_WIDTH_M, max_force_n=MAX_FORCE_N)
    dt, steps, backoff_s, width, force = 1.0 / FOLLOW_RATE_HZ, [], None, MAX_WIDTH_M, 0.0
    for i in range(round(60.0 / dt)):
        t = i * dt
        if backoff_s is None and op.phase == "backoff":
            backoff_s = t  # the fingers stop here, and the force with them, however the hand opens
        steps.append((t, command := op.step(t, force_n=force, width_m=width)))
        if backoff_s is None:  # the fingers follow onto a spring 4 cm wide
            width = command.target_width_m
            force = min(1000.0 * max(0.04 - width, 0.0), MAX_FORCE_N)
        if op.done:
            break
    released_s = _one_release(steps)
    assert backoff_s is not None and op.done
    assert backoff_s + GIVE_UP_S <= released_s <= backoff_s + GIVE_UP_S + MAX_WIDTH_M / op.style.squeeze_speed_m_s
    # The fingers never open after the release either: it waits as long again before it is done.
    assert steps[-1][0] >= released_s + GIVE_UP_S - 1e-9


def test_it_feels_a_touch_only_its_reaction_delay_late():
    op = SimulatedOperator(np.random.default_rng(0), max_width_m=MAX_WIDTH_M, max_force_n=MAX_FORCE_N)
    touch_s = op.style.start_delay_s + 0.2
    target, felt_s = MAX_WIDTH_M, None
    for i in range(round(2.0 / STEP_S)):
        t = i * STEP_S
        target = op.step(t, force_n=2.0 if t >= touch_s else 0.0, width_m=target).target_width_m
        if op.phase not in ("wait", "approach"):
            felt_s = t
            break
    delay = op.style.reaction_delay_s
    assert felt_s is not None and touch_s + delay - 1e-9 <= felt_s < touch_s + delay + 2 * STEP_S


def test_its_approach_is_faster_than_its_squeeze_but_never_over_8_cm_s():
    for seed in range(600):
        style = style_of(seed)
        assert style.squeeze_speed_m_s <= style.approach_speed_m_s <= SQUEEZE_SPEED_M_S[1] + 1e-12, seed


def test_a_weak_gripper_is_never_aimed_past_its_maximum_force():
    # A gripper weaker than MIN_PEAK_FORCE_N: every peak is within its maximum force.
    for seed in range(200):
        style = style_of(seed, max_force_n=2.0)
        assert all(0.0 < p <= 2.0 for p in style.peaks_n), style.peaks_n


def test_squeeze_speeds_are_log_uniform_around_the_papers_speed():
    # Half the operators squeeze slower than the geometric middle of SQUEEZE_SPEED_M_S (2 cm/s),
    # not than its arithmetic one (4.25 cm/s).
    speeds = np.array([style_of(seed).squeeze_speed_m_s for seed in range(400)])
    middle = math.sqrt(SQUEEZE_SPEED_M_S[0] * SQUEEZE_SPEED_M_S[1])
    assert 0.4 <= np.mean(speeds < middle) <= 0.6


def test_two_pauses_are_taken_in_order_with_a_squeeze_between():
    # Pauses are taken by rising share of the goal: out of order, the second would come right
    # after the first, at the same force.
    seeds = [s for s in range(300) if len(style_of(s).pauses) == 2 and not style_of(s).backoff_to
             and abs(style_of(s).pauses[1][0] - style_of(s).pauses[0][0]) > 0.25]
    assert seeds
    for seed in seeds:
        op, run = drive(seed, stiffness_n_per_m=800.0, extent_m=0.06)
        steps = run["steps"]
        assert list(op.style.pauses) == sorted(op.style.pauses)
        starts = [steps[i][4] for i in range(1, len(steps)) if steps[i][1] == "pause" and steps[i - 1][1] != "pause"]
        assert len(starts) == 2 and starts[1] > starts[0] + 0.05 * op.style.peaks_n[0], (seed, starts)


def test_it_holds_its_grip_still_for_its_drawn_hold_time():
    seed = first_seed(lambda s: s.hold_s > 0.5 and not s.backoff_to and not s.pauses)
    op, run = drive(seed, stiffness_n_per_m=800.0, extent_m=0.06)
    held_s = next(t for t, phase, *_ in run["steps"] if phase == "hold")
    released_s = next(t for t, _, command, *_ in run["steps"] if command.release)
    assert op.style.hold_s - 1e-9 <= released_s - held_s <= op.style.hold_s + 2 * STEP_S


def _stall(**style_traits) -> tuple[list[tuple], float]:
    """The steps of a quick squeeze without pauses (and with ``style_traits``, each a value or a
    test of one) that stalls on a force limit of 40 % of its first peak, and that limit (N)."""
    seed = first_seed(lambda s: s.squeeze_speed_m_s >= 0.03 and not s.pauses and all(
        test(getattr(s, k)) if callable(test) else getattr(s, k) == test for k, test in style_traits.items()))
    cap = 0.4 * style_of(seed).peaks_n[0]
    _, run = drive(seed, stiffness_n_per_m=1000.0, extent_m=0.06, cap_n=cap)
    return run["steps"], cap


def test_on_a_stalled_grip_its_hand_leads_the_fingers_by_at_most_the_stall_gap():
    steps, _ = _stall(backoff_to=())
    in_contact = [(c.target_width_m, w) for _, phase, c, w, f in steps if c.enable and phase == "squeeze" and f > 1.0]
    assert in_contact and all(target >= width - STALL_GAP_M - 1e-9 for target, width in in_contact)


def test_it_stops_squeezing_soon_after_the_grip_stalls_on_the_force_limit():
    steps, cap = _stall(backoff_to=())
    stalled_s = next(t for t, _, _, _, force in steps if force >= cap - 1e-9)
    squeezed_s = next(t for t, phase, *_ in steps if phase == "squeeze")
    stopped_s = next(t for t, phase, *_ in steps if t > squeezed_s and phase != "squeeze")
    assert stopped_s - stalled_s < 0.6  # well under GIVE_UP_S


def test_a_back_off_on_a_stalled_grip_opens_the_fingers_at_once():
    # Its hand stops with the grip: were it still the stall gap ahead, the fingers would not move
    # until the hand had opened that far.
    steps, _ = _stall(backoff_to=lambda b: len(b) >= 1)
    _, _, command, width, _ = next(step for step in steps if step[1] == "backoff")
    assert command.target_width_m >= width - 1e-12


def test_done_once_the_fingers_are_open_within_the_tolerance():
    # A gripper that opens to 0.5 mm short of its nominal width: no GIVE_UP_S wait for the rest.
    seed = first_seed(lambda s: not s.backoff_to and not s.pauses)
    op, run = drive(seed, stiffness_n_per_m=800.0, extent_m=0.06, open_to_m=MAX_WIDTH_M - 0.0005)
    assert op.done
    opened_s = next(t for t, _, c, width, _ in run["steps"]
                    if not c.enable and width >= MAX_WIDTH_M - OPEN_TOLERANCE_M)
    assert run["steps"][-1][0] - opened_s <= 2 * STEP_S
