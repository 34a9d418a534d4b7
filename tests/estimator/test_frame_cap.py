"""A grasp keeps at most ``MAX_GRASP_FRAMES`` frames of each finger (an operator may hold an object for
minutes): once in contact, later ones are counted, not kept (before contact: test_frame_cap_precontact);
the estimates rest on the frames kept and say how many were not; offline, a record's frames past the cap
are treated as live; the service logs it once per grasp."""

from __future__ import annotations

import dataclasses
import json
import logging

import cv2
import numpy as np
import pytest
from support.live import METHODS, feed, in_capture_order, same

from estimator import received, service
from estimator import stream as stream_module
from estimator.errors import PerceptionError
from estimator.stream import GraspStream
from teleop.catalogue import load_catalogue
from teleop.settings import CONFIG_DIR
from teleop.sim.grasp import simulate_grasp


def note(count: int, cap: int) -> str:
    return f"{count} frames of finger 'left' after its first {cap} not kept (a grasp keeps at most {cap})"


@pytest.fixture(scope="module")
def operator_grasp(settings):
    """A simulated operator's leader-follower grasp (no loading-end marker: its final comes at its end)."""
    objects = {o.name: o for o in load_catalogue(CONFIG_DIR / "objects.toml")}
    record = simulate_grasp(objects["rubber_duck"], settings=settings, rng=np.random.default_rng(3), operator="sim")[0]
    return dataclasses.replace(record, events={})


@pytest.fixture
def cap(monkeypatch, operator_grasp):
    """A cap that the grasp's last 20 frames of the estimator's finger come past (the shipped one is far above it)."""
    n = len(operator_grasp.stream("left").t_s)
    assert n < received.MAX_GRASP_FRAMES and len(operator_grasp.stream("right").t_s) > n - 20
    for module in (received, stream_module, service):
        monkeypatch.setattr(module, "MAX_GRASP_FRAMES", n - 20)
    return n - 20


def test_a_long_grasp_keeps_the_first_frames_and_counts_the_rest(settings, calibration):
    sensor = settings.sensor("left")
    image = np.full((sensor.raw_height_px, sensor.raw_width_px, 3), 128, dtype=np.uint8)
    jpeg = cv2.imencode(".jpg", image)[1].tobytes()
    stream = GraspStream(settings=settings, calibration=calibration, methods=METHODS)
    stream.add_force(np.array([0.0, 0.01, 0.02]), np.array([1.0, 2.0, 3.0]))  # in contact from the first frame
    stream.add_width(np.array([0.0, 0.02]), np.array([0.05, 0.049]))
    cap, extra = received.MAX_GRASP_FRAMES, 7
    kept = [stream.add_frame(finger, i / 30.0, jpeg, "jpeg") for i in range(cap + extra) for finger in ("left", "right")]
    assert kept == [True, False] * cap + [False, False] * extra  # only a kept frame of the estimator's finger is news
    assert stream.frame_count == cap and stream.frames_not_kept("left") == stream.frames_not_kept("right") == extra
    assert len(stream._perception.images) == cap  # decoded only while kept
    assert [len(s.t_s) for s in stream.to_record().frames] == [cap, cap]
    with pytest.raises(PerceptionError, match=f"frame {cap + extra} of finger 'left': capture time nan"):
        stream.add_frame("left", float("nan"), jpeg, "jpeg")  # still checked, and counted as a record holds it
    assert stream.frames_not_kept("left") == extra + 1


@pytest.mark.slow
def test_past_the_cap_live_and_offline_estimate_the_frames_kept_and_say_so(settings, calibration, operator_grasp, cap):
    live = GraspStream(settings=settings, calibration=calibration, methods=METHODS)
    live.mark_follow()
    for t, kind, body in in_capture_order(operator_grasp):
        feed(live, kind, body, t)
    assert live.frame_count == cap and live.frames_not_kept("left") == 20
    assert live.frames_not_kept("right") == len(operator_grasp.stream("right").t_s) - cap
    final = live.estimate()
    offline = GraspStream.from_record(operator_grasp, settings=settings, calibration=calibration, methods=METHODS)
    assert offline.frame_count == cap and offline.frames_not_kept("left") == 20
    assert all(same(a, b) for a, b in zip(final.estimates, offline.estimate().estimates, strict=True))
    # The record without its frames past the cap gives the same floats, without the note.
    first = dataclasses.replace(operator_grasp, frames=tuple(
        dataclasses.replace(s, t_s=s.t_s[:cap], encoded=s.encoded[:cap]) for s in operator_grasp.frames))
    truncated = GraspStream.from_record(first, settings=settings, calibration=calibration, methods=METHODS).estimate()
    assert any(e.state == "ok" for e in final.estimates)
    for a, b in zip(final.estimates, truncated.estimates, strict=True):
        assert note(20, cap) in a.reason and note(20, cap) not in b.reason
        assert (a.method, a.state, a.e_pa, a.interval_pa) == (b.method, b.state, b.e_pa, b.interval_pa)


def test_a_frame_refused_live_takes_its_place_as_in_its_record(settings, calibration, operator_grasp, cap):
    # Refused live, each is in the record offline measures, among its first frames or past them.
    refusals = {("left", 5): "does not decode", ("right", 2): "encoding", ("left", cap + 3): "time"}
    left = operator_grasp.stream("left")
    garbled = dataclasses.replace(left, encoded=(*left.encoded[:5], b"not a jpeg", *left.encoded[6:]))
    record = dataclasses.replace(operator_grasp, frames=tuple(garbled if s.finger == "left" else s
                                                              for s in operator_grasp.frames))
    live = GraspStream(settings=settings, calibration=calibration, methods=METHODS)
    live.mark_follow()
    refused = []
    for t, kind, body in in_capture_order(record):
        how = refusals.get((body.get("finger"), body.get("index")))
        body = {**body, "encoding": "png"} if how == "encoding" else body
        try:
            feed(live, kind, body, float("nan") if how == "time" else t)
        except PerceptionError as exc:
            refused.append(str(exc))
    assert refused == [f"grasp '' frame {i} of finger {f!r}: {why}" for f, i, why in (
        ("right", 2, "png after jpeg frames"), ("left", 5, "jpeg data does not decode"),
        ("left", cap + 3, "capture time nan is not finite"))]  # named by their index in the record
    offline = GraspStream.from_record(record, settings=settings, calibration=calibration, methods=METHODS)
    for finger in ("left", "right"):
        assert live.frames_not_kept(finger) == offline.frames_not_kept(finger) == len(record.stream(finger).t_s) - cap
    final, measured = live.estimate().estimates, offline.estimate().estimates
    assert any(e.state == "ok" for e in final) and all(note(20, cap) in e.reason for e in final)
    assert all(same(a, b) for a, b in zip(final, measured, strict=True))


def test_the_service_says_once_that_a_grasp_keeps_no_more_frames(rig, settings, calibration, operator_grasp, cap,
                                                               caplog, tmp_path):
    rig.robot.send("robot_state", t_capture_s=0.0, mode="following", grasp_id="g-long", target_width_m=0.08,
                   enable=True)
    with caplog.at_level(logging.WARNING, logger="estimator.service"):
        rig.send_grasp(operator_grasp, "g-long")
        estimates = [m for m in rig.collect("g-long") if m.type == "estimate"]
    said = [r.getMessage() for r in caplog.records if "counted, not kept" in r.getMessage()]
    assert said == [f"grasp 'g-long': frames of finger {f!r} past the {cap} kept are counted, not kept: its "
                    "estimates rest on those" for f in ("left", "right")]  # once per finger, not per frame
    assert [m.body["provisional"] for m in estimates].count(False) == 1 and not estimates[-1].body["provisional"]
    report = json.loads((tmp_path / "estimator.jsonl").read_text().splitlines()[-1])
    assert note(20, cap) in report["final"]["reason"]  # the estimate message's reason is cut to the wire's limit
    live = GraspStream(settings=settings, calibration=calibration, methods=METHODS)
    provisional = 0
    for t, kind, body in in_capture_order(operator_grasp):
        provisional += bool(feed(live, kind, body, t) and live.segment())
    assert len(estimates) == provisional + 1  # no provisional estimate for a frame not kept
    assert estimates[-1].body["E_pa"] == live.estimate().estimate.e_pa
