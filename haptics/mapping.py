"""From a Young's modulus estimate to what the softness display renders.

Pure functions, no clocks: every time is passed in (seconds, on the caller's
clock). The chain is

    EstimateUpdate -map_estimate-> Percept -smooth/fade-> Percept -to_command-> StiffnessCommand

A :class:`Percept` is display-independent: ``stiffness`` is the fraction of
the display's range (0 = free, 1 = the stiff end) and ``uncertainty_decades``
the width of the estimate's interval in decades of E. :func:`to_command`
quantises it onto one display's ``level_max``.

The scale is logarithmic in E between ``e_soft_pa`` (fraction 0) and
``e_rigid_pa`` (fraction 1), clamped: equal ratios of E give equal steps,
which is how perceived softness scales (Weber-Fechner), and the range of
real objects spans eight orders of magnitude.
"""

from __future__ import annotations

import math
from collections.abc import Hashable, Mapping
from dataclasses import dataclass, replace
from typing import Any

from haptics.errors import MappingError
from haptics.protocol import UNCERTAINTY_COUNTS_PER_DECADE, StiffnessCommand

__all__ = [
    "ESTIMATE_STATES",
    "FREE",
    "EstimateUpdate",
    "Percept",
    "fade",
    "fade_gain",
    "interval_decades",
    "is_stale",
    "map_estimate",
    "smooth",
    "smoothing_weight",
    "stiffness_fraction",
    "to_command",
]

ESTIMATE_STATES = ("ok", "lower_bound", "upper_bound", "insufficient_data")


def _positive_finite(name: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not (
        math.isfinite(value) and value > 0
    ):
        raise MappingError(f"{name} = {value!r}: expected a finite number > 0 (Pa)")
    return float(value)


def _non_negative(name: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not (
        math.isfinite(value) and value >= 0
    ):
        raise MappingError(f"{name} = {value!r}: expected a finite number >= 0 (s)")
    return float(value)


@dataclass(frozen=True)
class EstimateUpdate:
    """One modulus estimate as the renderer receives it (from the bus, a file or a test).

    Parameters
    ----------
    e_pa : float or None
        Young's modulus in Pa; for the bound states, the bound itself. Required
        (finite, > 0) for ``"ok"``; a bound state without it takes its bound
        from ``interval_pa``; ignored for ``"insufficient_data"``.
    interval_pa : (low or None, high or None)
        Uncertainty interval in Pa; None is an open side.
    state : str
        One of :data:`ESTIMATE_STATES`.
    reason : str
        Why the state is what it is (free text, shown to people only).
    provisional : bool
        Streamed while the squeeze is still loading.
    grasp_id : hashable
        The grasp this estimate belongs to.
    t_s : float
        Capture time of the data the estimate comes from, in seconds.
    """

    e_pa: float | None
    interval_pa: tuple[float | None, float | None] = (None, None)
    state: str = "ok"
    reason: str = ""
    provisional: bool = False
    grasp_id: Hashable = ""
    t_s: float = 0.0

    def __post_init__(self) -> None:
        if self.state not in ESTIMATE_STATES:
            raise MappingError(
                f"estimate state = {self.state!r}: expected one of {', '.join(ESTIMATE_STATES)}"
            )
        if not isinstance(self.t_s, int | float) or not math.isfinite(self.t_s):
            raise MappingError(f"estimate t_s = {self.t_s!r}: expected a finite time in seconds")
        if len(self.interval_pa) != 2:
            raise MappingError(
                f"estimate interval_pa = {self.interval_pa!r}: expected (low or None, high or None)"
            )
        low, high = (
            None if v is None else _positive_finite(f"estimate interval_pa[{i}]", v)
            for i, v in enumerate(self.interval_pa)
        )
        if low is not None and high is not None and low > high:
            raise MappingError(f"estimate interval_pa = {self.interval_pa!r}: low above high")
        if self.state == "insufficient_data":
            return
        e_pa = _positive_finite(
            f"estimate E_pa (state {self.state!r}; a bound may come from interval_pa)",
            self.value_pa,
        )
        # A relative tolerance: the estimator may round the bound and the value differently.
        if (low is not None and e_pa < low * (1 - 1e-9)) or (
            high is not None and e_pa > high * (1 + 1e-9)
        ):
            raise MappingError(
                f"estimate E_pa = {e_pa!r} lies outside its interval_pa {self.interval_pa!r}"
            )

    @property
    def value_pa(self) -> float | None:
        """The modulus to render: ``e_pa``, or for a bound state without one, the
        interval's bound (low for ``lower_bound``, high for ``upper_bound``); None
        for ``insufficient_data``."""
        if self.state == "insufficient_data":
            return None
        if self.e_pa is not None:
            return self.e_pa
        low, high = self.interval_pa
        return {"lower_bound": low, "upper_bound": high}.get(self.state)

    @classmethod
    def from_mapping(cls, message: Mapping[str, Any]) -> EstimateUpdate:
        """Build from a mapping with the bus's keys ``E_pa``, ``interval_pa``, ``state``,
        ``reason``, ``provisional``, ``grasp_id`` and ``t_s`` (the capture time: the bus
        carries it in the message header); other keys are ignored."""
        missing = [key for key in ("E_pa", "state", "grasp_id", "t_s") if key not in message]
        if missing:
            raise MappingError(f"estimate message lacks {', '.join(missing)}")
        interval = message.get("interval_pa") or (None, None)
        return cls(
            e_pa=message["E_pa"],
            interval_pa=tuple(interval),
            state=message["state"],
            reason=str(message.get("reason", "")),
            provisional=bool(message.get("provisional", False)),
            grasp_id=message["grasp_id"],
            t_s=message["t_s"],
        )


@dataclass(frozen=True)
class Percept:
    """What the operator should feel, independent of any display.

    ``stiffness`` is the fraction of the display's range, 0 (free) to 1 (stiff
    end); ``uncertainty_decades`` the interval width in decades of E, >= 0.
    """

    stiffness: float = 0.0
    uncertainty_decades: float = 0.0
    rigid: bool = False
    unknown: bool = False
    provisional: bool = False


#: Nothing rendered: the display is free.
FREE = Percept()


def _check_range(e_soft_pa: float, e_rigid_pa: float) -> tuple[float, float]:
    soft = _positive_finite("e_soft_pa", e_soft_pa)
    rigid = _positive_finite("e_rigid_pa", e_rigid_pa)
    if rigid <= soft:
        raise MappingError(f"e_rigid_pa = {rigid!r}: expected a value above e_soft_pa = {soft!r}")
    return soft, rigid


def stiffness_fraction(e_pa: float, *, e_soft_pa: float, e_rigid_pa: float) -> float:
    """Position of ``e_pa`` on the display's range: log10 scale, clamped to [0, 1].

    ``e_pa`` at or below ``e_soft_pa`` gives 0, at or above ``e_rigid_pa`` gives 1.
    """
    soft, rigid = _check_range(e_soft_pa, e_rigid_pa)
    e_pa = _positive_finite("e_pa", e_pa)
    fraction = math.log(e_pa / soft) / math.log(rigid / soft)
    return min(1.0, max(0.0, fraction))


def interval_decades(
    low_pa: float | None, high_pa: float | None, *, e_soft_pa: float, e_rigid_pa: float
) -> float:
    """Width in decades of the interval [low, high] clipped to [e_soft_pa, e_rigid_pa].

    An open side (None) reaches the end of the display range, so the width is
    always finite: what the display cannot show is no uncertainty to the operator.
    """
    soft, rigid = _check_range(e_soft_pa, e_rigid_pa)
    low = soft if low_pa is None else min(rigid, max(soft, _positive_finite("low_pa", low_pa)))
    high = rigid if high_pa is None else min(rigid, max(soft, _positive_finite("high_pa", high_pa)))
    if low > high:
        raise MappingError(f"interval [{low_pa!r}, {high_pa!r}]: low above high")
    return math.log10(high / low)


def map_estimate(update: EstimateUpdate, *, e_soft_pa: float, e_rigid_pa: float) -> Percept:
    """The percept for one estimate.

    - ``insufficient_data``: unknown, free (stiffness 0), uncertainty the whole range.
    - ``ok``: stiffness of E; rigid when E >= ``e_rigid_pa``.
    - ``lower_bound``: E is the bound (E >= bound); rendered at the bound, rigid when
      the bound is >= ``e_rigid_pa``; the interval is open above unless given.
    - ``upper_bound``: E is the bound (E <= bound); rendered at the bound, never
      rigid; the interval is open below unless given.
    """
    soft, rigid = _check_range(e_soft_pa, e_rigid_pa)
    if update.state == "insufficient_data":
        return Percept(
            stiffness=0.0,
            uncertainty_decades=math.log10(rigid / soft),
            unknown=True,
            provisional=update.provisional,
        )
    e_pa = update.value_pa
    low, high = update.interval_pa
    if update.state == "lower_bound" and low is None:
        low = e_pa
    if update.state == "upper_bound" and high is None:
        high = e_pa
    is_rigid = update.state in ("ok", "lower_bound") and e_pa >= rigid
    return Percept(
        stiffness=1.0 if is_rigid else stiffness_fraction(e_pa, e_soft_pa=soft, e_rigid_pa=rigid),
        uncertainty_decades=interval_decades(low, high, e_soft_pa=soft, e_rigid_pa=rigid),
        rigid=is_rigid,
        provisional=update.provisional,
    )


def smoothing_weight(dt_s: float, *, smoothing_s: float) -> float:
    """Weight of the new target after ``dt_s`` in a first-order lag of time constant
    ``smoothing_s``: ``1 - exp(-dt_s / smoothing_s)``; 1 when ``smoothing_s`` is 0."""
    dt_s = _non_negative("dt_s", dt_s)
    smoothing_s = _non_negative("smoothing_s", smoothing_s)
    if smoothing_s == 0:
        return 1.0
    return -math.expm1(-dt_s / smoothing_s)


def smooth(previous: Percept, target: Percept, *, dt_s: float, smoothing_s: float) -> Percept:
    """Move ``previous`` toward ``target`` for ``dt_s`` seconds (exponential smoothing).

    Stiffness and uncertainty are blended on the display's (logarithmic) scale;
    the flags are the target's, so a state change shows at once.
    """
    weight = smoothing_weight(dt_s, smoothing_s=smoothing_s)
    return replace(
        target,
        stiffness=previous.stiffness + weight * (target.stiffness - previous.stiffness),
        uncertainty_decades=previous.uncertainty_decades
        + weight * (target.uncertainty_decades - previous.uncertainty_decades),
    )


def fade_gain(elapsed_s: float, *, fade_s: float) -> float:
    """Gain of a linear fade to free: 1 at release, 0 after ``fade_s`` (at once when 0)."""
    elapsed_s = _non_negative("elapsed_s", elapsed_s)
    fade_s = _non_negative("fade_s", fade_s)
    if elapsed_s >= fade_s:
        return 0.0
    return 1.0 - elapsed_s / fade_s


def fade(percept: Percept, *, gain: float) -> Percept:
    """``percept`` scaled toward free by ``gain`` in [0, 1]; the rigid flag is dropped,
    since a fading display must be allowed to yield."""
    if not 0.0 <= gain <= 1.0:
        raise MappingError(f"fade gain = {gain!r}: expected a value in [0, 1]")
    return replace(percept, stiffness=percept.stiffness * gain, rigid=False)


def is_stale(last_update_s: float, now_s: float, *, stale_after_s: float) -> bool:
    """True when no update arrived for ``stale_after_s`` seconds or more."""
    if now_s < last_update_s:
        raise MappingError(f"now_s = {now_s!r}: before the last update at {last_update_s!r}")
    return now_s - last_update_s >= stale_after_s


def to_command(
    percept: Percept, *, level_max: int, stale: bool = False, fading: bool = False
) -> StiffnessCommand:
    """Quantise ``percept`` onto a display with full-scale level ``level_max``.

    The level is ``round(stiffness * level_max)``; the uncertainty byte counts
    1/20 decade, saturating at 255.
    """
    if isinstance(level_max, bool) or not isinstance(level_max, int) or not 0 < level_max < 65536:
        raise MappingError(f"level_max = {level_max!r}: expected an integer in [1, 65535]")
    for name in ("stiffness", "uncertainty_decades"):
        value = getattr(percept, name)
        if not math.isfinite(value) or value < 0 or (name == "stiffness" and value > 1):
            raise MappingError(f"percept {name} = {value!r}: out of range")
    counts = round(percept.uncertainty_decades * UNCERTAINTY_COUNTS_PER_DECADE)
    return StiffnessCommand(
        level=round(percept.stiffness * level_max),
        uncertainty=min(255, counts),
        rigid=percept.rigid,
        unknown=percept.unknown,
        stale=stale,
        fading=fading,
        provisional=percept.provisional,
    )
