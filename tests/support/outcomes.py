"""A demo grasp's outcome built from the fields a test gives (:class:`teleop.system.outcome.GraspOutcome`), and
``teleop bench-latency`` run on given outcomes."""

from __future__ import annotations

import contextlib

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


def fake_bench_latency(monkeypatch, tmp_path, outcomes) -> None:
    """``teleop bench-latency`` with the live system, the calibration and the frame baseline (5 and 6 ms
    before and after the run: 5.5 ms) replaced: ``outcomes`` are the grasps it measured."""
    import estimator.perception.calibration
    import teleop.system.latency as latency

    monkeypatch.setattr(latency, "prepare_run", lambda args, **kwargs: (tmp_path / "run", tmp_path / "cal.npz"))
    monkeypatch.setattr(estimator.perception.calibration, "load_calibration", lambda path: None)
    monkeypatch.setattr(latency, "frame_baseline_ms", lambda *args, **kwargs: [5.0, 6.0])
    monkeypatch.setattr(latency, "LiveSystem", lambda *args, **kwargs: contextlib.nullcontext())
    monkeypatch.setattr(latency, "LiveView", lambda *args: None)
    monkeypatch.setattr(latency, "run_grasps", lambda *args, **kwargs: iter(outcomes))
