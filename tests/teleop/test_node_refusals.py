"""The robot node's refusals of commands whose values a sender makes up: bounded log and notices."""

from __future__ import annotations

import logging
import time

import pytest
from support.node_rig import drain, running_node, step_for

import teleop.follow as follow
from teleop.node import _Grasp
from teleop.node_refusals import NOTICES_PER_KIND


@pytest.fixture
def rig():
    with running_node() as rig:
        yield rig


def _step_until_refused(node, count: int) -> None:
    deadline = time.monotonic() + 30.0
    while node.stats.bad_commands < count:
        assert time.monotonic() < deadline, f"{count} commands were not refused in time"
        node.step(timeout_s=0.002)


@pytest.mark.slow
def test_refusals_with_made_up_values_log_and_notice_a_bounded_number_while_an_operator_still_hears(rig, caplog):
    node, operator, listener, _ = rig
    flood = 1000
    frozen_s = time.monotonic() - 100.0
    clock, node.clock = node.clock, lambda: frozen_s  # the whole flood within one second of the node's clock
    with caplog.at_level(logging.WARNING, logger="teleop.node"):
        for batch in range(0, flood, 100):
            for i in range(batch, batch + 100):
                operator.send("command", t_capture_s=0.0, action="start_grasp", grasp_id=None,
                              params={"object_index": 1e9 + i if i % 2 else -float(i + 1)})
                operator.send("follow", t_capture_s=0.0, grasp_id=f"x{i}", target_width_m=1.0 + i, enable=True)
            _step_until_refused(node, 2 * (batch + 100))
        flooded = [r for r in caplog.records if "not carried out" in r.getMessage()]
        notices = [m.body for m in drain(listener) if m.type == "robot_notice"]
        # An operator's refusal of another kind is said at once, even within the flood's second ...
        operator.send("command", t_capture_s=0.0, action="start_grasp", grasp_id="g-legit-1",
                      params={"object_index": 0.5})
        _step_until_refused(node, 2 * flood + 1)
        # ... and one of a flooded kind once that second is over.
        node.clock = clock
        operator.send("command", t_capture_s=0.0, action="start_grasp", grasp_id="g-legit-2",
                      params={"object_index": 99.0})
        _step_until_refused(node, 2 * flood + 2)
        heard = [m.body for m in drain(listener) if m.type == "robot_notice"]
    assert node.stats.bad_commands == 2 * flood + 2
    # Two kinds (the object index beyond the scene, the width beyond the fingers): the first of each,
    # then the 10th, 100th and 1000th with their count.
    assert len(flooded) <= 2 * 4, [r.getMessage() for r in flooded[:10]]
    assert any("object_index" in r.getMessage() for r in flooded)
    assert any("the fingers open to" in r.getMessage() for r in flooded)
    assert any("(1000 refusals like it so far)" in r.getMessage() for r in flooded)
    assert 2 <= len(notices) <= 2 * NOTICES_PER_KIND  # of each kind in the flood's one second
    assert {n["event"] for n in notices} == {"refused"}
    assert {n["action"] for n in notices} == {"start_grasp", "follow"}
    legit = [(n["grasp_id"], n["action"]) for n in heard if n["event"] == "refused"]
    assert legit == [("g-legit-1", "start_grasp"), ("g-legit-2", "start_grasp")]
    assert "whole number" in heard[0]["reason"] and "object_index 99" in heard[1]["reason"]


def test_the_refusal_bookkeeping_stays_bounded():
    from teleop.node_refusals import MAX_KINDS, MAX_RECENT, Refusals

    refusals = Refusals()
    sent = 0
    for i in range(5 * MAX_RECENT):
        # Made-up kinds too: a reason whose values are not taken out (an unknown parameter's name).
        kind = refusals.kind("start_grasp", ValueError(f"start_grasp params p{chr(97 + i % 26)}{i}: expected only"))
        refusals.refused(kind)
        sent += refusals.may_send("start_grasp", f"g{i}", f"reason {i}", now=i * 1e-4, repeat_s=1.0, kind=kind)
    assert len(refusals._kinds) <= MAX_KINDS + 1
    assert len(refusals._recent) <= MAX_RECENT
    assert sent <= NOTICES_PER_KIND * (MAX_KINDS + 1)
    # A second on, the same refusal goes out again, and the repeats within it do not.
    assert refusals.may_send("stop", "g", "r", now=10.0, repeat_s=1.0)
    assert not refusals.may_send("stop", "g", "r", now=10.5, repeat_s=1.0)
    assert refusals.may_send("stop", "g", "r", now=11.0, repeat_s=1.0)


def test_the_follow_grasps_remembered_as_ended_are_bounded(rig):
    node, *_ = rig
    kept = getattr(follow, "ENDED_KEPT", 1024)
    for i in range(kept + 200):
        node._follower.grasp_ended(_Grasp(f"made-up-{i}", None, follow=True))
    assert len(node._follower.ended) <= kept
    # The grasps that ended last are still not started again.
    assert f"made-up-{kept + 199}" in node._follower.ended
    with pytest.raises(follow.DeviceError, match="has ended"):
        node._follower.follow(f"made-up-{kept + 199}", 0.05, True)


def test_a_consoles_burst_of_refused_grasps_is_each_said(rig):
    """A console clears a grasp it pressed only when the robot's refusal names it: a burst of presses
    while one grasp runs (one kind of refusal, well under a flood) gets every notice."""
    node, operator, listener, _ = rig
    operator.send("command", t_capture_s=0.0, action="start_grasp", grasp_id="op-s-001", params={})
    step_for(node, 0.3)
    for i in range(2, 12):
        operator.send("command", t_capture_s=0.0, action="start_grasp", grasp_id=f"op-s-{i:03d}", params={})
    _step_until_refused(node, 10)
    refused = {m.body["grasp_id"] for m in drain(listener) if m.type == "robot_notice"
               and m.body["event"] == "refused"}
    assert refused == {f"op-s-{i:03d}" for i in range(2, 12)}
