"""The result of every estimator: a modulus with its interval, or an explicit bound or refusal.

An :class:`Estimate` can never carry a NaN, negative or infinite modulus: the
invariants below are checked on construction, so code that consumes estimates
(the bus, the haptic display, the evaluation) never has to guard against them.

States
------
``"ok"``
    ``e_pa`` is the estimate; ``interval_pa = (low, high)``, both finite,
    ``low <= e_pa <= high``.
``"lower_bound"``
    The object is at least this stiff and the data cannot say how much more
    (e.g. steel: the gel takes all the deformation, within the sensor's depth
    resolution). ``interval_pa = (low, None)`` and ``e_pa == low``.
``"upper_bound"``
    The object is at most this stiff (e.g. the gel barely moves against a very
    soft foam). ``interval_pa = (None, high)`` and ``e_pa == high``.
``"insufficient_data"``
    A refusal: ``e_pa is None``, ``interval_pa == (None, None)`` and ``reason``
    says why. The estimate is falsy.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any

from estimator.errors import FitError
from teleop.states import ESTIMATE_STATES as STATES

if TYPE_CHECKING:
    from estimator.segment import Segment

__all__ = ["STATES", "Estimate", "StreamEstimate", "choose_estimate"]


def _valid_modulus(value: float | None) -> bool:
    return value is not None and math.isfinite(value) and value > 0


@dataclass(frozen=True)
class Estimate:
    """Young's modulus of the grasped object from one method.

    Parameters
    ----------
    method : str
        Which estimator produced it (``"series"``, ``"hertz"``, ...).
    e_pa : float or None
        The modulus in Pa (the bound's value for a bound; None for a refusal).
    interval_pa : (float or None, float or None)
        Uncertainty interval in Pa; None marks an open side.
    state : {"ok", "lower_bound", "upper_bound", "insufficient_data"}
    reason : str
        What the estimate rests on, or why there is none.
    latency_s : float
        Seconds from the data being available to the estimate (>= 0).

    Raises
    ------
    FitError
        The fields break the invariants of ``state`` (a NaN, infinite or
        non-positive modulus or bound, a value outside its interval, ...).
    """

    method: str
    e_pa: float | None
    interval_pa: tuple[float | None, float | None]
    state: str
    reason: str = ""
    latency_s: float = 0.0

    def __post_init__(self) -> None:
        if len(self.interval_pa) != 2:
            raise FitError(f"Estimate.interval_pa must be (low, high), got {self.interval_pa!r}")
        low, high = (None if b is None else float(b) for b in self.interval_pa)
        e_pa = None if self.e_pa is None else float(self.e_pa)
        object.__setattr__(self, "interval_pa", (low, high))
        object.__setattr__(self, "e_pa", e_pa)
        where = f"Estimate({self.method!r}, state={self.state!r})"
        if self.state not in STATES:
            raise FitError(f"{where}: state must be one of {', '.join(STATES)}")
        if not (math.isfinite(self.latency_s) and self.latency_s >= 0):
            raise FitError(f"{where}: latency_s must be finite and >= 0, got {self.latency_s}")
        expected_open = {
            "ok": (False, False),
            "lower_bound": (False, True),
            "upper_bound": (True, False),
            "insufficient_data": (True, True),
        }[self.state]
        if (low is None, high is None) != expected_open:
            raise FitError(f"{where}: interval_pa {self.interval_pa!r} has the wrong open sides")
        for name, bound in (("e_pa", e_pa), ("interval low", low), ("interval high", high)):
            if bound is not None and not _valid_modulus(bound):
                raise FitError(f"{where}: {name} must be finite and > 0, got {bound}")
        if self.state == "insufficient_data":
            if e_pa is not None:
                raise FitError(f"{where}: a refusal carries no modulus, got e_pa={e_pa}")
            if not self.reason:
                raise FitError(f"{where}: a refusal must say why (reason is empty)")
            return
        if e_pa is None:
            raise FitError(f"{where}: e_pa is required")
        if (low is not None and e_pa < low) or (high is not None and e_pa > high):
            raise FitError(f"{where}: e_pa={e_pa} lies outside interval_pa {self.interval_pa!r}")
        if self.state == "lower_bound" and e_pa != low:
            raise FitError(f"{where}: e_pa must equal the bound {low}")
        if self.state == "upper_bound" and e_pa != high:
            raise FitError(f"{where}: e_pa must equal the bound {high}")

    def __bool__(self) -> bool:
        return self.state != "insufficient_data"

    # ------------------------------------------------------------------ constructors

    @classmethod
    def ok(cls, method: str, e_pa: float, low_pa: float, high_pa: float, reason: str = "") -> Estimate:
        """A modulus with a two-sided interval."""
        return cls(method, e_pa, (low_pa, high_pa), "ok", reason)

    @classmethod
    def at_least(cls, method: str, bound_pa: float, reason: str) -> Estimate:
        """The object is at least ``bound_pa`` stiff."""
        return cls(method, bound_pa, (bound_pa, None), "lower_bound", reason)

    @classmethod
    def at_most(cls, method: str, bound_pa: float, reason: str) -> Estimate:
        """The object is at most ``bound_pa`` stiff."""
        return cls(method, bound_pa, (None, bound_pa), "upper_bound", reason)

    @classmethod
    def refuse(cls, method: str, reason: str) -> Estimate:
        """No estimate; ``reason`` says why."""
        return cls(method, None, (None, None), "insufficient_data", reason)

    def with_latency(self, latency_s: float) -> Estimate:
        """The same estimate stamped with ``latency_s``."""
        return replace(self, latency_s=float(latency_s))

    def with_note(self, note: str) -> Estimate:
        """The same estimate with ``note`` appended to its reason."""
        if not note:
            return self
        return replace(self, reason=f"{self.reason}; {note}" if self.reason else note)

    # ------------------------------------------------------------------ export

    def to_json(self) -> dict[str, Any]:
        """JSON-ready mapping: method, E_pa, interval_pa ([low, high], null for an open side),
        state, reason, latency_ms."""
        low, high = self.interval_pa
        return {
            "method": self.method,
            "E_pa": self.e_pa,
            "interval_pa": [low, high],
            "state": self.state,
            "reason": self.reason,
            "latency_ms": self.latency_s * 1e3,
        }


def choose_estimate(estimates: Sequence[Estimate]) -> Estimate:
    """The first estimate that is not a refusal; if all refuse, one refusal naming every reason."""
    if not estimates:
        raise FitError("choose_estimate needs at least one estimate")
    for estimate in estimates:
        if estimate:
            return estimate
    reasons = "; ".join(f"{e.method}: {e.reason}" for e in estimates)
    return Estimate.refuse(estimates[0].method, f"every method refuses ({reasons})")


@dataclass(frozen=True)
class StreamEstimate:
    """One estimate of a grasp in progress.

    Attributes
    ----------
    estimate : Estimate
        The published one (:func:`~estimator.estimate.choose_estimate`), stamped with the compute time.
    estimates : tuple of Estimate
        Every method asked for, in order.
    segment : Segment
        The segmentation it rests on.
    t_data_s : float
        Capture time (s, stream clock) of the newest loading frame the fits used; without
        loading frames, of the newest frame received.
    loading_frames : int
        Loading frames the fits used.
    """

    estimate: Estimate
    estimates: tuple[Estimate, ...]
    segment: Segment
    t_data_s: float
    loading_frames: int

