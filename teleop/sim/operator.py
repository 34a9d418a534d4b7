"""A simulated operator: a person-like hand on the leader's grip, for one grasp.

A person squeezes otherwise than the paper's scripted grasp (close at a constant 3.75 cm/s to one
force, hold 0.5 s). :class:`SimulatedOperator` drives the fingers' target width
(:mod:`teleop.operator`: position-position, force-capped) closed loop on the force it feels
through the display, with everything drawn once per grasp from its random stream
(:class:`OperatorStyle`):

approach
    From open fingers, after a start delay, at 1-1.5 times its squeezing speed (up to 8 cm/s)
    until it feels contact (``CONTACT_FORCE_N``). When the fingers do not follow its grip for
    ``GIVE_UP_S`` (the robot no longer drives them: its watchdog ended the grasp) or its grip is
    fully closed that long without contact, it gives up: it releases at once.
squeeze
    Closing at a drawn speed (``SQUEEZE_SPEED_M_S``, log-uniform around the paper's 3.75 cm/s)
    varied smoothly (a slow sinusoid of drawn depth and rate), slowing down as the felt force
    nears its goal; it stops closing when the felt force reaches the goal, when the fingers
    stop following (the gripper stalls at its force limit: the hand feels the grip stop) or when
    its grip is fully closed.
pauses
    Sometimes it stops closing for a while on the way up (at a drawn share of the goal).
back-offs
    Sometimes it reaches a first peak, opens until the felt force falls to a drawn share of it,
    and squeezes again, to a higher or a lower peak. When its hand has been open for
    ``GIVE_UP_S`` and the force has not fallen (the fingers no longer follow: the watchdog ended
    the grasp), it lets go at once.
hold
    At the last peak it holds its grip still for a drawn time, or (sometimes) never holds
    still: it lets go at once.
release
    :attr:`OperatorCommand.release` is True once (send ``release``); from then on the dead-man is
    let go (``enable`` False: the node opens the fingers) and the hand opens.
    :attr:`SimulatedOperator.done` once the fingers are open again, or once its hand has been open
    for ``GIVE_UP_S`` while they are not (nothing opens them: the grasp had ended).

The operator feels the force ``REACTION_DELAY_S`` late (drawn; a person feels through the
display 50-100 ms late and reacts on that), so it overshoots its goal on stiff objects as a
person does; the gripper's force limit (``gripper.target_force_n``) bounds what the fingers do,
and the operator's goals never exceed ``max_force_n``.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np

__all__ = ["OperatorCommand", "OperatorStyle", "SimulatedOperator", "draw_style"]

CONTACT_FORCE_N = 0.3  # felt force that tells the operator it touches
MIN_PEAK_FORCE_N = 3.0
SQUEEZE_SPEED_M_S = (0.005, 0.08)  # log-uniform: slower and faster than the paper's 0.0375
APPROACH_FACTOR = (1.0, 1.5)  # approach speed over squeeze speed (it does not know where the object is)
SPEED_VARIATION = (0.0, 0.5)  # depth of the smooth speed variation (share of the speed)
VARIATION_HZ = (0.3, 1.5)
REACTION_DELAY_S = (0.05, 0.1)
START_DELAY_S = (0.0, 0.3)
PAUSE_PROBABILITY = 0.35
PAUSE_S = (0.15, 0.6)
PAUSE_AT = (0.25, 0.8)  # share of the current goal force where a pause starts
BACKOFF_PROBABILITY = 0.35
SECOND_BACKOFF_PROBABILITY = 0.3  # of those that back off once
BACKOFF_TO = (0.3, 0.75)  # share of the peak the felt force falls to before the re-squeeze
NEVER_STILL_PROBABILITY = 0.25
HOLD_S = (0.2, 1.5)
OPEN_SPEED_M_S = (0.03, 0.1)
SLOWDOWN_SHARE = 0.3  # slows down over the last 30 % of the goal force
MIN_SLOWDOWN = 0.25
STALL_GAP_M = 0.005  # the fingers this far behind the target (in contact): the grip has stopped
STALL_S = 0.15  # stopped this long: as far as it goes
OPEN_TOLERANCE_M = 0.001
MAX_SPEED_M_S = 0.09  # the hand never outruns the fingers' follow speed (0.1 m/s)
GIVE_UP_S = 2.0  # fingers that go nowhere this long: beyond a slow start of the robot's follow grasp


@dataclass(frozen=True)
class OperatorCommand:
    """What the operator asks at one step.

    ``target_width_m``: the fingers' target width (m, >= 0); ``enable``: the dead-man is held
    (the command counts); ``release``: True once, when the operator is done with the grasp (send
    ``release``).
    """

    target_width_m: float
    enable: bool
    release: bool = False


@dataclass(frozen=True)
class OperatorStyle:
    """The drawn parameters of one operator's grasp (SI units; module notes).

    ``peaks_n`` are the goal forces of the successive squeezes (one more than the back-offs);
    ``backoff_to`` the share of each reached peak the felt force falls to before the next
    squeeze; ``pauses`` (share of the first goal, seconds) on the first squeeze; ``hold_s`` 0:
    never holds still.
    """

    squeeze_speed_m_s: float
    approach_speed_m_s: float
    speed_variation: float
    variation_hz: float
    variation_phase: float
    reaction_delay_s: float
    start_delay_s: float
    peaks_n: tuple[float, ...]
    backoff_to: tuple[float, ...]
    pauses: tuple[tuple[float, float], ...]
    hold_s: float
    open_speed_m_s: float

    @property
    def traits(self) -> tuple[str, ...]:
        """Names of what sets this grasp apart: "pauses", "re-squeezes", "never still", "holds"."""
        return tuple(name for name, on in (("pauses", bool(self.pauses)), ("re-squeezes", bool(self.backoff_to)),
                                            ("never still", self.hold_s == 0), ("holds", self.hold_s > 0)) if on)

    def describe(self) -> str:
        """One line: speeds, peaks, back-offs, pauses, hold and reaction delay."""
        parts = [f"squeeze {100 * self.squeeze_speed_m_s:.2g} cm/s +-{100 * self.speed_variation:.0f} %",
                 "peak " + " -> ".join(f"{p:.3g} N" for p in self.peaks_n)]
        if self.backoff_to:
            parts.append(f"{len(self.backoff_to)} back-off(s) to "
                         + ", ".join(f"{100 * b:.0f} %" for b in self.backoff_to))
        if self.pauses:
            parts.append("pause " + ", ".join(f"{s:.2g} s at {100 * a:.0f} %" for a, s in self.pauses))
        parts.append(f"hold {self.hold_s:.2g} s" if self.hold_s > 0 else "never holds still")
        parts.append(f"reacts {1000 * self.reaction_delay_s:.0f} ms late")
        return "; ".join(parts)


def _log_uniform(rng: np.random.Generator, bounds: tuple[float, float]) -> float:
    return float(math.exp(rng.uniform(math.log(bounds[0]), math.log(bounds[1]))))


def draw_style(rng: np.random.Generator, *, max_force_n: float) -> OperatorStyle:
    """Draw one grasp's :class:`OperatorStyle` from ``rng`` (a fixed order of draws)."""
    if not (math.isfinite(max_force_n) and max_force_n > 0):
        raise ValueError(f"max_force_n = {max_force_n!r}: expected a finite number > 0")
    low = min(MIN_PEAK_FORCE_N, max_force_n)
    speed = _log_uniform(rng, SQUEEZE_SPEED_M_S)
    approach = min(speed * float(rng.uniform(*APPROACH_FACTOR)), SQUEEZE_SPEED_M_S[1])
    variation = float(rng.uniform(*SPEED_VARIATION))
    variation_hz = float(rng.uniform(*VARIATION_HZ))
    phase = float(rng.uniform(0.0, 2 * math.pi))
    delay = float(rng.uniform(*REACTION_DELAY_S))
    start = float(rng.uniform(*START_DELAY_S))
    backoffs = 0
    if rng.random() < BACKOFF_PROBABILITY:
        backoffs = 2 if rng.random() < SECOND_BACKOFF_PROBABILITY else 1
    peaks = tuple(float(rng.uniform(low, max_force_n)) for _ in range(backoffs + 1))
    backoff_to = tuple(float(rng.uniform(*BACKOFF_TO)) for _ in range(backoffs))
    pauses: tuple[tuple[float, float], ...] = ()
    if rng.random() < PAUSE_PROBABILITY:
        count = 1 + int(rng.random() < 0.3)
        pauses = tuple(sorted((float(rng.uniform(*PAUSE_AT)), float(rng.uniform(*PAUSE_S))) for _ in range(count)))
    hold = 0.0 if rng.random() < NEVER_STILL_PROBABILITY else float(rng.uniform(*HOLD_S))
    open_speed = float(rng.uniform(*OPEN_SPEED_M_S))
    return OperatorStyle(squeeze_speed_m_s=speed, approach_speed_m_s=approach, speed_variation=variation,
                         variation_hz=variation_hz, variation_phase=phase, reaction_delay_s=delay,
                         start_delay_s=start, peaks_n=peaks, backoff_to=backoff_to, pauses=pauses,
                         hold_s=hold, open_speed_m_s=open_speed)


class SimulatedOperator:
    """A person-like operator for one grasp, seeded (module notes).

    Parameters
    ----------
    rng : Generator
        Its style is drawn from it at construction; the steps draw nothing.
    max_width_m : float
        The fingers' open width (m): the target at an open grip.
    max_force_n : float
        The largest force it aims for (N; the settings' maximum grasp force).

    :meth:`step` is called at the operator side's rate (``teleop.operator.FOLLOW_RATE_HZ``) with
    the time since the grasp's operator began, the force it feels now and the fingers' width.
    """

    def __init__(self, rng: np.random.Generator, *, max_width_m: float, max_force_n: float):
        if not (math.isfinite(max_width_m) and max_width_m > 0):
            raise ValueError(f"max_width_m = {max_width_m!r}: expected a finite number > 0")
        self.style = draw_style(rng, max_force_n=max_force_n)
        self.max_width_m = float(max_width_m)
        self.max_force_n = float(max_force_n)
        self._phase = "wait"  # wait, approach, squeeze, pause, backoff, hold, open
        self._target = self.max_width_m
        self._last_t: float | None = None
        self._felt: deque[tuple[float, float]] = deque()
        self._squeeze = 0  # which of style.peaks_n is the goal
        self._reached = 0.0  # force felt at the last peak
        self._pauses = list(self.style.pauses)
        self._until = 0.0  # end of a pause or of the hold
        self._stalled_since: float | None = None
        self._released = False
        self._done = False

    @property
    def done(self) -> bool:
        """Released, and the fingers are open again."""
        return self._done

    @property
    def phase(self) -> str:
        """What the hand does now: wait, approach, squeeze, pause, backoff, hold or open."""
        return self._phase

    def _felt_force(self, t_s: float, force_n: float) -> float:
        """The force as the operator perceives it: what the fingers felt ``reaction_delay_s`` ago."""
        self._felt.append((t_s, force_n))
        delay = self.style.reaction_delay_s
        while len(self._felt) > 1 and self._felt[1][0] <= t_s - delay:
            self._felt.popleft()
        return self._felt[0][1] if self._felt[0][0] <= t_s - delay else 0.0

    def _speed(self, t_s: float, felt: float, goal: float) -> float:
        s = self.style
        wave = 1.0 + s.speed_variation * math.sin(2 * math.pi * s.variation_hz * t_s + s.variation_phase)
        slow = min(max((goal - felt) / (SLOWDOWN_SHARE * goal), MIN_SLOWDOWN), 1.0)
        return min(s.squeeze_speed_m_s * wave * slow, MAX_SPEED_M_S)

    def step(self, t_s: float, *, force_n: float, width_m: float) -> OperatorCommand:
        """The operator's command at ``t_s`` (s since it began; 0: fingers open).

        Parameters
        ----------
        t_s : float
            Seconds since this grasp's operator began (non-decreasing over the calls).
        force_n : float
            The grasp force now (N); the operator feels it ``reaction_delay_s`` late.
        width_m : float
            The fingers' width now (m).

        Returns
        -------
        OperatorCommand
        """
        dt = 0.0 if self._last_t is None else max(t_s - self._last_t, 0.0)
        self._last_t = t_s
        felt = self._felt_force(t_s, float(force_n))
        s = self.style
        release = False
        if self._phase == "wait" and t_s >= s.start_delay_s:
            self._phase = "approach"
        if self._phase == "approach":
            self._target -= s.approach_speed_m_s * dt
            if felt >= CONTACT_FORCE_N:
                self._phase, self._stalled_since = "squeeze", None
            elif self._stuck(t_s, self._target <= 0.0 or width_m - self._target >= STALL_GAP_M - 1e-9):
                self._phase, self._until = "hold", t_s  # gives up: lets go at once
        elif self._phase == "squeeze":
            goal = s.peaks_n[self._squeeze]
            if self._pauses and felt >= self._pauses[0][0] * s.peaks_n[0] and self._squeeze == 0:
                self._phase, self._until = "pause", t_s + self._pauses.pop(0)[1]
            elif felt >= goal or self._stalled(t_s, width_m):
                self._reached = felt
                if self._squeeze < len(s.backoff_to):
                    self._phase = "backoff"
                    self._target = max(self._target, min(width_m, self.max_width_m))  # the hand stops with the grip
                else:
                    self._phase, self._until = "hold", t_s + s.hold_s
            else:
                self._target -= self._speed(t_s, felt, goal) * dt
        elif self._phase == "pause":
            if t_s >= self._until:
                self._phase = "squeeze"
        elif self._phase == "backoff":
            if felt <= s.backoff_to[self._squeeze] * self._reached:
                self._squeeze += 1
                self._stalled_since = None
                self._phase = "squeeze"
            elif self._stuck(t_s, self._target >= self.max_width_m):  # its hand open, the force stays: the
                self._phase, self._until = "hold", t_s  # fingers no longer follow (the watchdog ended the grasp)
            else:
                self._target += s.squeeze_speed_m_s * dt
        if self._phase == "hold" and t_s >= self._until:
            self._phase, release, self._released, self._stalled_since = "open", True, True, None
        elif self._phase == "open":
            self._target += s.open_speed_m_s * dt
            if width_m >= self.max_width_m - OPEN_TOLERANCE_M or self._stuck(t_s, self._target >= self.max_width_m):
                self._done = True
        if self._phase in ("squeeze", "pause", "backoff", "hold") and felt >= CONTACT_FORCE_N:
            # The hand cannot lead a stalled grip by more than the gap: it feels the grip stop.
            self._target = max(self._target, width_m - STALL_GAP_M)
        self._target = min(max(self._target, 0.0), self.max_width_m)
        return OperatorCommand(target_width_m=self._target, enable=not self._released, release=release)

    def _held_for(self, t_s: float, condition: bool, after_s: float) -> bool:
        """Whether ``condition`` has held for ``after_s`` (counted afresh whenever it does not)."""
        if not condition:
            self._stalled_since = None
            return False
        if self._stalled_since is None:
            self._stalled_since = t_s
        return t_s - self._stalled_since >= after_s

    def _stuck(self, t_s: float, stuck: bool) -> bool:
        """Whether ``stuck`` has held for ``GIVE_UP_S``."""
        return self._held_for(t_s, stuck, GIVE_UP_S)

    def _stalled(self, t_s: float, width_m: float) -> bool:
        """Whether the fingers have not followed the target for ``STALL_S``: as far as it goes."""
        if self._target <= 0.0:
            return True  # the grip is fully closed
        return self._held_for(t_s, width_m - self._target >= STALL_GAP_M - 1e-9, STALL_S)
