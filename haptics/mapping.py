"""From a Young's modulus estimate to what the softness display renders.

Pure functions, no clocks: every time is passed in (seconds, on the caller's
clock). The chain is

    EstimateUpdate -map_estimate-> Percept -smooth/fade-> Percept -to_command-> StiffnessCommand

A :class:`Percept` is display-independent: ``stiffness`` is the fraction of
the display's range (0 = free, 1 = the stiff end) and ``uncertainty_decades``
the width of the estimate's interval in decades of E. :func:`to_command`
quantises it onto one display's ``level_max``.

The scale
---------
The display's range runs from ``e_soft_pa`` (fraction 0, free) to
``e_rigid_pa`` (fraction 1, the stiff end), clamped at both ends. In a full
:class:`~teleop.settings.Settings` the rigid end is, unless the TOML sets it,
the estimating sensor's resolution limit (``Settings.resolution_limit_pa``,
about 6.75 MPa for the shipped gel): stiffer objects cannot be told apart by
the mechanics, so the estimator reports them as ``lower_bound`` at that limit.
A lower bound, or an ``ok`` estimate, at or above the rigid end is rendered
*rigid* (fraction 1, the rigid flag); "at" allows a relative
:data:`RIGID_TOLERANCE` (1e-9), so a bound rounded on its way here still counts.

Between the ends the scale is logarithmic in E, after two laws of softness
perception:

- Discrimination (Weber). The Weber fraction for discriminating compliance, or
  Young's modulus, by squeezing is about 15 % (:data:`~teleop.physics.WEBER_FRACTION`;
  Bergmann Tiest and Kappers, IEEE Transactions on Haptics 2009; it more than
  triples without the cue of the surface's deformation). A just-noticeable
  difference is a fixed *ratio* of E, so equal ratios of E are equally
  discriminable, and the scale that gives every just-noticeable step the same
  share of the range is linear in log E. The range holds
  ``ln(e_rigid / e_soft) / ln(1.15)`` just-noticeable steps
  (:func:`just_noticeable_steps`): about 52 for 5 kPa .. 6.75 MPa.
- Magnitude (Stevens). Perceived hardness is a power law of the stimulus,
  ``psi ~ S ** beta`` with ``beta`` about 0.8 for squeezing rubber (Harper and
  Stevens 1964). A display whose stiffness ``K`` is a power law of E,
  ``K = K_soft * (E / e_soft) ** gamma``, is felt as ``psi ~ E ** (gamma * beta)``:
  still a power law of E, so equal ratios of E still feel like equal ratios
  of hardness. ``log K = log K_soft + gamma * log(E / e_soft)`` is exactly a
  scale linear in log E: the firmware ideally renders the levels geometrically from
  ``min_stiffness_n_per_m`` to ``max_stiffness_n_per_m`` (PROTOCOL.md), which
  sets ``gamma = ln(K_max / K_min) / ln(e_rigid / e_soft)``.

The uncertainty
---------------
``Percept.uncertainty_decades`` carries the width of the estimate's interval in
decades of E, clipped to the display's range ``[e_soft_pa, e_rigid_pa]``: an
open side reaches the end of the range, so a lower bound at the rigid end has
width 0 and ``insufficient_data`` spans the whole range (what the display
cannot show is no uncertainty to the operator). The protocol quantises it at
:data:`~haptics.protocol.UNCERTAINTY_COUNTS_PER_DECADE` (20) counts per
decade, saturating at 255; one just-noticeable step (``log10(1.15)``, 0.061
decade) is 1.2 counts.
"""

from __future__ import annotations

import math
from collections.abc import Hashable
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any

from haptics.errors import MappingError
from haptics.protocol import UNCERTAINTY_COUNTS_PER_DECADE, StiffnessCommand
from teleop.physics import WEBER_FRACTION
from teleop.states import ESTIMATE_STATES

if TYPE_CHECKING:
    from teleop.bus.messages import EstimateBody

__all__ = [
    "ESTIMATE_STATES",
    "FREE",
    "RIGID_TOLERANCE",
    "EstimateUpdate",
    "Percept",
    "fade",
    "fade_gain",
    "interval_decades",
    "is_stale",
    "just_noticeable_steps",
    "map_estimate",
    "modulus_from_fraction",
    "rendered_value_pa",
    "smooth",
    "smoothing_weight",
    "stiffness_fraction",
    "to_command",
]

#: Relative tolerance of "at or above the rigid end" (and "at or below the soft end"): a bound
#: equal to the limit after rounding is at it.
RIGID_TOLERANCE = 1e-9


def _positive_finite(name: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not (
        math.isfinite(value) and value > 0
    ):
        raise MappingError(f"{name} = {value!r}: expected a finite number > 0 (Pa)")
    return float(value)


def _finite(name: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise MappingError(f"{name} = {value!r}: expected a finite number (s)")
    return float(value)


def _non_negative(name: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not (
        math.isfinite(value) and value >= 0
    ):
        raise MappingError(f"{name} = {value!r}: expected a finite number >= 0 (s)")
    return float(value)


def rendered_value_pa(state: str, e_pa: float | None, interval_pa: tuple[float | None, float | None]) -> float | None:
    """The modulus an estimate renders at: ``e_pa``, or for a bound state without one the interval's
    bound (low for ``lower_bound``, high for ``upper_bound``); None for ``insufficient_data``."""
    if state == "insufficient_data":
        return None
    if e_pa is not None:
        return e_pa
    low, high = interval_pa
    return {"lower_bound": low, "upper_bound": high}.get(state)


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
        if not isinstance(self.provisional, bool):
            raise MappingError(f"estimate provisional = {self.provisional!r}: expected True or False")
        if isinstance(self.t_s, bool) or not isinstance(self.t_s, int | float) or not math.isfinite(self.t_s):
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
        return rendered_value_pa(self.state, self.e_pa, self.interval_pa)

    @classmethod
    def from_estimate(cls, estimate: EstimateBody, t_s: float) -> EstimateUpdate:
        """Build from a bus ``estimate`` body and ``t_s``, its message's capture time (the bus
        carries it in the message header); the method, latency and model are left out."""
        return cls(
            e_pa=estimate.E_pa,
            interval_pa=tuple(estimate.interval_pa),
            state=estimate.state,
            reason=estimate.reason,
            provisional=bool(estimate.provisional),  # the bus checked it; it may be numpy's bool
            grasp_id=estimate.grasp_id,
            t_s=t_s,
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
    # Differences of logs, not the log of a ratio: a denormal e_pa (1e-320) would make
    # e_pa / soft underflow to 0 and the log fail; its fraction is 0 (clamped) instead.
    fraction = (math.log(e_pa) - math.log(soft)) / (math.log(rigid) - math.log(soft))
    return min(1.0, max(0.0, fraction))


def modulus_from_fraction(fraction: float, *, e_soft_pa: float, e_rigid_pa: float) -> float:
    """The modulus at ``fraction`` of the display's range: the inverse of :func:`stiffness_fraction`.

    The scale is logarithmic, so ``E = e_soft_pa * (e_rigid_pa / e_soft_pa) ** fraction``;
    the ends are returned exactly (0 gives ``e_soft_pa``, 1 gives ``e_rigid_pa``).

    Parameters
    ----------
    fraction : float
        Position on the display's range, in [0, 1] (a :class:`Percept`'s ``stiffness``).
    e_soft_pa, e_rigid_pa : float
        The display's range in Pa.

    Returns
    -------
    float
        Young's modulus in Pa, in ``[e_soft_pa, e_rigid_pa]``.

    Raises
    ------
    MappingError
        ``fraction`` is not a finite number in [0, 1], or the range is invalid.
    """
    soft, rigid = _check_range(e_soft_pa, e_rigid_pa)
    if isinstance(fraction, bool) or not isinstance(fraction, int | float) or not 0.0 <= fraction <= 1.0:
        raise MappingError(f"fraction = {fraction!r}: expected a number in [0, 1]")
    if fraction == 0:
        return soft
    if fraction == 1:
        return rigid
    return min(rigid, max(soft, soft * (rigid / soft) ** fraction))


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
    return math.log10(high) - math.log10(low)


def _unknown(update: EstimateUpdate, soft: float, rigid: float) -> Percept:
    """Nothing placed: free, the whole range as uncertainty."""
    return Percept(stiffness=0.0, uncertainty_decades=math.log10(rigid) - math.log10(soft), unknown=True,
                   provisional=update.provisional)


def map_estimate(update: EstimateUpdate, *, e_soft_pa: float, e_rigid_pa: float) -> Percept:
    """The percept for one estimate.

    - ``insufficient_data``: unknown, free (stiffness 0), uncertainty the whole range.
    - ``ok``: stiffness of E; rigid when E >= ``e_rigid_pa``.
    - ``lower_bound``: E is the bound (E >= bound); rendered at the bound, rigid when
      the bound is >= ``e_rigid_pa`` (the estimator's bound at the sensor's resolution
      limit, when that is the rigid end); the interval is open above unless given.

    - ``upper_bound``: E is the bound (E <= bound); rendered at the bound, never
      rigid; the interval is open below unless given.
    - any of these three whose interval spans the whole range (from its soft end or below to
      its rigid end or above; a bound's open side reaches past the end on its side, an ``ok``
      estimate's open side states nothing): unknown, as ``insufficient_data``. Such an estimate
      places the object nowhere on the scale; rendering its value (often rigid: the middle of a
      distribution over every modulus) would tell the operator what the estimate does not.

    "At or above" ``e_rigid_pa`` (for the rigid flag and for reaching the rigid end) and "at or
    below" ``e_soft_pa`` allow a relative :data:`RIGID_TOLERANCE`.
    """
    if not isinstance(update, EstimateUpdate):
        raise MappingError(
            f"update: expected an EstimateUpdate, got {type(update).__name__}; build one with "
            "EstimateUpdate.from_estimate(body, t_s) from a bus estimate body, or "
            "EstimateUpdate(e_pa=..., interval_pa=..., state=...) from an estimator Estimate's fields"
        )
    soft, rigid = _check_range(e_soft_pa, e_rigid_pa)
    if update.state == "insufficient_data":
        return _unknown(update, soft, rigid)
    e_pa = update.value_pa
    low, high = update.interval_pa
    # A bound within EstimateUpdate's rounding tolerance beyond the other side is at that side.
    if update.state == "lower_bound" and low is None:
        low = e_pa if high is None else min(e_pa, high)
    if update.state == "upper_bound" and high is None:
        high = e_pa if low is None else max(e_pa, low)
    # The same tolerance as the rigid flag's: a bound at an end after rounding reaches it.
    reaches_soft = (low <= soft * (1 + RIGID_TOLERANCE) if low is not None
                    else update.state == "upper_bound")
    reaches_rigid = (high >= rigid * (1 - RIGID_TOLERANCE) if high is not None
                     else update.state == "lower_bound")
    if reaches_soft and reaches_rigid:
        return _unknown(update, soft, rigid)
    is_rigid = update.state in ("ok", "lower_bound") and e_pa >= rigid * (1 - RIGID_TOLERANCE)
    return Percept(
        stiffness=1.0 if is_rigid else stiffness_fraction(e_pa, e_soft_pa=soft, e_rigid_pa=rigid),
        uncertainty_decades=interval_decades(low, high, e_soft_pa=soft, e_rigid_pa=rigid),
        rigid=is_rigid,
        provisional=update.provisional,
    )


def just_noticeable_steps(
    e_soft_pa: float, e_rigid_pa: float, *, weber_fraction: float = WEBER_FRACTION
) -> float:
    """How many just-noticeable differences of E the range [e_soft_pa, e_rigid_pa] spans:
    ``ln(e_rigid / e_soft) / ln(1 + weber_fraction)`` (module notes; about 52 for
    5 kPa .. 6.75 MPa at the 15 % Weber fraction)."""
    soft, rigid = _check_range(e_soft_pa, e_rigid_pa)
    if isinstance(weber_fraction, bool) or not isinstance(weber_fraction, int | float) or not (
        math.isfinite(weber_fraction) and weber_fraction > 0
    ):
        raise MappingError(f"weber_fraction = {weber_fraction!r}: expected a finite number > 0")
    return (math.log(rigid) - math.log(soft)) / math.log1p(weber_fraction)


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
    """True when no update arrived for ``stale_after_s`` seconds or more.

    ``last_update_s`` may be ``-inf``: no update ever (stale).

    Raises
    ------
    MappingError
        ``now_s`` is not a finite number, ``last_update_s`` is neither finite nor ``-inf``,
        ``stale_after_s`` is not a finite number >= 0, or ``now_s`` is before ``last_update_s``.
    """
    if last_update_s != -math.inf:
        last_update_s = _finite("last_update_s", last_update_s)
    now_s = _finite("now_s", now_s)
    stale_after_s = _non_negative("stale_after_s", stale_after_s)
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
