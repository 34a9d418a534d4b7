"""Audit of what the operator's loop knows of grasps (:mod:`haptics.operator_grasps`): a grasp is not
given up while no robot state has been heard, and an ended grasp without an id waits for the
estimator's final estimate."""

from __future__ import annotations

from haptics.operator_grasps import DiscreteGrasps, over
from haptics.operator_link import OperatorView, Peer


def test_an_unstarted_grasp_is_kept_while_no_robot_state_is_heard():
    grasps = DiscreteGrasps(settle_s=0.5)
    grasps.add("g1", 10.0)
    grasps.update(OperatorView(t_s=20.0), (), 20.0)  # no robot state: nothing says it was refused
    assert list(grasps) == ["g1"] and grasps.latest == "g1"


def test_an_ended_grasp_without_an_id_waits_for_the_live_estimators_final_estimate():
    estimator = Peer(name="estimator", source="estimator", alive=True, seen_ago_s=0.1)
    view = OperatorView(t_s=1.0, peers=(estimator,), phase="ended", grasp_id=None)
    assert not over(view)
    assert not over(view, ended_blind="g7")
