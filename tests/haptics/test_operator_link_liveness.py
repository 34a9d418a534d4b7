"""The operator's link on loopback: what it keeps when the robot node or the estimator dies, and the notice that
ended a grasp; and, on a fake clock, the liveness of a peer that announced no heartbeat period."""

from __future__ import annotations

import dataclasses
import time

import numpy as np
from support.operator_fakes import Clock, QueuedSubscriber, SubscribedPublisher

from haptics.operator_link import LIVENESS_PERIODS, OperatorLink
from teleop.bus.pubsub import Publisher
from teleop.settings import load_settings

HEARTBEAT_S = 0.05


def _wait(predicate, link: OperatorLink, *publishers: Publisher, timeout_s: float = 5.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not predicate(link.view):
        assert time.monotonic() < deadline, link.view
        for publisher in publishers:
            publisher.heartbeat_if_due()
        link.poll(0.01)


def _robot_link(robot: Publisher) -> OperatorLink:
    settings = load_settings()
    bus = dataclasses.replace(settings.bus, command="tcp://127.0.0.1:*", heartbeat_s=HEARTBEAT_S,
                              robot_pub=robot.endpoint, estimate_pub="tcp://127.0.0.1:1",
                              display_pub="tcp://127.0.0.1:2")
    return OperatorLink.from_settings(bus)


def _readings(robot: Publisher, force_n: float, width_m: float) -> None:
    t = time.monotonic()
    robot.send("force", t_capture_s=t, grasp_id=None, t_s=np.array([t]), value_n=np.array([force_n]))
    robot.send("width", t_capture_s=t, grasp_id=None, t_s=np.array([t]), value_m=np.array([width_m]))
    robot.send("robot_state", t_capture_s=t, mode="grasping", grasp_id="g1", target_width_m=None, enable=False)


def test_a_dead_robot_nodes_force_width_and_state_are_not_shown():
    with Publisher("tcp://127.0.0.1:*", lossless=True, source="robot", heartbeat_s=HEARTBEAT_S) as robot, \
            _robot_link(robot) as link:
        robot.wait_for_subscriber("force", "width", "robot_state")
        robot.heartbeat_if_due()
        _readings(robot, 15.1, 0.02)
        _wait(lambda v: v.force_n == 15.1 and v.robot is not None and v.width_m == 0.02, link, robot)
        _wait(lambda v: v.down("robot node"), link)  # the node dies: no heartbeat any more
        view = link.view
        assert view.force_n is None and view.width_m is None and view.robot is None
        # Started again: what it sends now, and nothing of the old node's.
        t = time.monotonic()
        robot.send("width", t_capture_s=t, grasp_id=None, t_s=np.array([t]), value_m=np.array([0.08]))
        _wait(lambda v: v.alive("robot node") and v.width_m == 0.08, link, robot)
        assert link.view.force_n is None and link.view.robot is None


def test_the_notice_that_ended_a_grasp_stays_beside_a_later_refusal():
    with Publisher("tcp://127.0.0.1:*", lossless=True, source="robot", heartbeat_s=HEARTBEAT_S) as robot, \
            _robot_link(robot) as link:
        robot.wait_for_subscriber("robot_notice", "grasp_event")
        t = time.monotonic()
        robot.send("grasp_event", t_capture_s=t, event="start", grasp_id="op-1", object_name="duck")
        robot.send("robot_notice", t_capture_s=t, event="watchdog", action="follow", grasp_id="op-1",
                   reason="no follow command for 0.210 s (watchdog 0.2 s): the fingers stopped")
        robot.send("grasp_event", t_capture_s=t, event="end", grasp_id="op-1", object_name="duck")
        robot.send("robot_notice", t_capture_s=t, event="refused", action="follow", grasp_id="op-1",
                   reason="grasp 'op-1' has ended: name a new grasp to start one")
        _wait(lambda v: v.notice is not None and v.notice.event == "refused", link, robot)
        assert link.view.ended_by.event == "watchdog" and link.view.ended_by_t_s is not None
        link.clear()  # the next object: the old grasp's notices are no longer shown
        assert link.view.ended_by is None and link.view.notice is None


def test_an_estimate_from_an_estimator_that_died_since_is_not_current():
    settings = load_settings()
    with Publisher("tcp://127.0.0.1:*", lossless=True, source="estimator", heartbeat_s=HEARTBEAT_S) as estimator:
        bus = dataclasses.replace(settings.bus, command="tcp://127.0.0.1:*", heartbeat_s=HEARTBEAT_S,
                                  robot_pub="tcp://127.0.0.1:1", estimate_pub=estimator.endpoint,
                                  display_pub="tcp://127.0.0.1:2")
        with OperatorLink.from_settings(bus) as link:
            estimator.wait_for_subscriber("estimate")

            def estimate(e_pa: float) -> None:
                estimator.send("estimate", t_capture_s=time.monotonic(), grasp_id="op-1", method="hybrid", E_pa=e_pa,
                               interval_pa=[e_pa / 2, e_pa * 2], state="ok", reason="", provisional=True,
                               latency_s=0.01)

            estimator.heartbeat_if_due()
            estimate(4.5e4)
            _wait(lambda v: v.estimate is not None, link, estimator)
            assert not link.view.estimate_orphaned
            _wait(lambda v: v.down("estimator"), link)  # it dies mid-grasp ...
            _wait(lambda v: v.alive("estimator"), link, estimator)  # ... and is started again
            assert link.view.estimate.E_pa == 4.5e4 and link.view.estimate_orphaned  # not its grasp: no final
            estimate(5e4)  # it does go on with the grasp after all
            _wait(lambda v: v.estimate.E_pa == 5e4, link, estimator)
            assert not link.view.estimate_orphaned


def test_a_peer_heard_without_an_announced_period_is_dead_after_liveness_periods_of_the_links_own():
    # A data message before the node's first heartbeat: the bus knows no period of its own for it.
    clock = Clock()
    subscriber = QueuedSubscriber(clock)
    heartbeat_s = 0.5
    link = OperatorLink(publisher=SubscribedPublisher(), subscriber=subscriber, heartbeat_s=heartbeat_s, clock=clock)
    subscriber.heartbeat.saw("robot")  # as the Subscriber sees a data message's source: no interval_s
    link.poll()
    assert link.view.alive("robot node")
    clock.t += LIVENESS_PERIODS * heartbeat_s - 0.01
    link.poll()
    assert link.view.alive("robot node")
    clock.t += 0.02
    link.poll()
    assert link.view.down("robot node")
