"""A live session's final estimates are what ``estimator estimate`` says of its exported records.

The live estimator service and ``estimator estimate`` measure a grasp with one implementation
(:class:`~estimator.stream.GraspStream`, on the rig the grasp was captured with) and estimate it
with one model path (:meth:`~estimator.inference.hybrid.HybridEstimator.estimate_stream`). The
quick scene is grasped by the simulated operator (leader-follower grasps: each final estimate comes
at the grasp's end, so the exported record holds exactly the data it was computed on), the session
log is exported to records, and each record's ``estimator estimate --method auto`` must be its
live final: the same floats, state, reason, method and model.

(A scripted grasp's final comes at its loading end, before the hold and the release arrive; its
record holds them too, so a measurement of the whole record differs from it: :mod:`estimator.stream`.)
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

import estimator.cli
import teleop.cli
from estimator.inference.infer import default_model_dir, model_id
from teleop.bus.wire import MAX_STR_CHARS
from teleop.record import read_record
from teleop.session.logfile import LogReader


def _last_json(capsys) -> dict:
    return json.loads(capsys.readouterr().out.strip().splitlines()[-1])


def _as_sent(reason: str) -> str:
    """A reason as an estimate message carries it (cut to the wire's limit, an ellipsis marking the cut)."""
    return reason if len(reason) <= MAX_STR_CHARS else reason[: MAX_STR_CHARS - 1] + "…"


@pytest.mark.slow
def test_estimator_estimate_on_the_exported_records_gives_each_live_final_exactly(quick_demo_sim, tmp_path, capsys):
    model = default_model_dir()  # what the demo serves by default
    assert quick_demo_sim.code == 0, quick_demo_sim.err
    run = quick_demo_sim.result
    assert {g["style"] for g in run["grasps"]} == {"operator"}
    log = Path(run["session_log"])
    finals = {m.message.body["grasp_id"]: m.message.body for m in LogReader(log).messages(("estimate",))
              if not m.message.body["provisional"]}
    assert teleop.cli.main(["export", str(log), "--out", str(tmp_path / "records"), "--json"]) == 0
    capsys.readouterr()
    records = sorted((tmp_path / "records").glob("*.grasp"))
    assert len(records) == len(finals) == 3
    for path in records:
        grasp_id = read_record(path).provenance.extra["grasp_id"]
        assert estimator.cli.main(["estimate", str(path), "--method", "auto", "--model", str(model), "--json"]) == 0
        offline, live = _last_json(capsys), finals[grasp_id]
        assert offline["model"] == live["model"] == model_id(model), grasp_id
        assert (offline["method"], offline["state"], _as_sent(offline["reason"])) == (
            live["method"], live["state"], live["reason"]), grasp_id
        # Exactly the same floats (JSON and the bus both carry a float64 whole).
        assert offline["E_pa"] == live["E_pa"] and offline["interval_pa"] == list(live["interval_pa"]), grasp_id
