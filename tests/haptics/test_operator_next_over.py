"""What ``next`` leaves behind: the last grasp for the summary (``haptics operate --json``), and no wait
for a final estimate that cannot come (the grasp ended while the estimator was down); against a fake
link and device."""

from __future__ import annotations

from support.operator_fakes import (
    loop_rig,
    press,
)

from haptics.operate_cli import summary
from haptics.operator_link import OperatorView, Peer
from teleop.bus.messages import EstimateBody

ALIVE = (Peer("robot node", "robot", True, 0.1, True), Peer("estimator", "estimator", True, 0.1))
ESTIMATOR_DOWN = (Peer("robot node", "robot", True, 0.1, True), Peer("estimator", "estimator", False, 4.0))


def _estimate(grasp_id: str, provisional: bool) -> EstimateBody:
    return EstimateBody(grasp_id=grasp_id, method="hybrid", E_pa=3.6e6, interval_pa=[2.0e6, 6.0e6], state="ok",
                        reason="loading phase", provisional=provisional, latency_s=0.01)


def _ended(peers, *, provisional: bool):
    """A discrete grasp pressed and shown ended with its estimate (final or not); the loop stepped once."""
    clock, link, _, loop = loop_rig()
    press(loop, clock, "grasp")
    grasp_id = loop.status.grasp_id
    link.view = OperatorView(t_s=clock(), peers=peers, grasp_id=grasp_id, phase="ended",
                             estimate=_estimate(grasp_id, provisional=provisional))
    loop.step()
    return clock, link, loop, grasp_id


def test_the_summary_names_the_last_grasp_next_cleared_with_its_final_estimate():
    clock, link, loop, grasp_id = _ended(ALIVE, provisional=False)
    press(loop, clock, "next")
    assert link.cleared == 1 and loop.status.view.grasp_id is None
    shown = summary("sim", loop.status)
    assert shown["grasp_id"] == grasp_id and shown["phase"] == "ended"
    assert shown["estimate"]["provisional"] is False and shown["estimate"]["E_pa"] == 3.6e6
    # A grasp shown now is the last one.
    link.view = OperatorView(t_s=clock(), peers=ALIVE, grasp_id="op-later", phase="loading")
    loop.step()
    assert summary("sim", loop.status)["grasp_id"] == "op-later"


def test_next_does_not_wait_for_the_final_of_a_grasp_that_ended_while_the_estimator_was_down():
    # g; the estimator killed; the grasp ends; the estimator started again; n clears at once.
    clock, link, loop, grasp_id = _ended(ESTIMATOR_DOWN, provisional=True)
    clock.t += 3.0
    link.view = OperatorView(t_s=clock(), peers=ALIVE, grasp_id=grasp_id, phase="ended",
                             estimate=_estimate(grasp_id, provisional=True), estimate_orphaned=True)
    loop.step()
    press(loop, clock, "next")
    assert link.cleared == 1 and loop.status.last_action.startswith("next object: ready")
    press(loop, clock, "grasp")
    assert link.kinds()[-1] == "start_grasp"


def test_next_still_waits_for_the_final_of_a_grasp_that_ended_with_the_estimator_alive():
    clock, link, loop, _ = _ended(ALIVE, provisional=True)
    press(loop, clock, "next")
    assert link.cleared == 0 and "its final estimate is in" in loop.status.last_action
