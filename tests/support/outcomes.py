"""A demo grasp's outcome built from the fields a test gives (:class:`teleop.system.outcome.GraspOutcome`)."""

from __future__ import annotations

from teleop.bus.messages import EstimateBody
from teleop.catalogue import ObjectSpec
from teleop.system.outcome import GraspOutcome

# What a final estimate says besides the fields a test gives (an estimate left without "model" is
# one from before the field: it reads as None).
FINAL = {"grasp_id": "g", "method": "auto", "interval_pa": [None, None], "reason": "", "provisional": False,
         "latency_s": 0.0}


def outcome(name: str, e_true: float, final: dict | None, first_s: float | None, latency_ms: float | None,
            display_range: tuple[float, float] | None = None, **report) -> GraspOutcome:
    o = GraspOutcome("g", ObjectSpec(name=name, shape="sphere", material="rubber", modulus_pa=e_true),
                     display_range=display_range)
    o.final = None if final is None else EstimateBody(**{**FINAL, **final})
    o.estimator_report = {"time_to_first_estimate_s": first_s, **report}
    o.renderer_report = None if latency_ms is None else {"latency_ms": latency_ms}
    return o
