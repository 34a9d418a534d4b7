"""The operator's bus link (:mod:`haptics.operator_link`) on loopback: the latest of each message, who is alive,
what it sends."""

from __future__ import annotations

import dataclasses
import time

import numpy as np
import pytest

from haptics.operator_link import OperatorLink
from teleop.bus.pubsub import Publisher, Subscriber
from teleop.bus.wire import Message
from teleop.errors import BusError, MessageRejected
from teleop.node import COMMAND_TOPICS
from teleop.settings import load_settings


def _wait(predicate, link: OperatorLink, timeout_s: float = 5.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not predicate(link.view):
        assert time.monotonic() < deadline, link.view
        link.poll(0.02)


def test_the_link_keeps_the_latest_of_each_and_who_is_alive():
    settings = load_settings()
    bus = dataclasses.replace(settings.bus, command="tcp://127.0.0.1:*", heartbeat_s=0.1)
    with (
        Publisher("tcp://127.0.0.1:*", lossless=True, source="robot", heartbeat_s=0.1) as robot,
        Publisher("tcp://127.0.0.1:*", lossless=False, source="estimator", heartbeat_s=0.1) as estimator,
        Publisher("tcp://127.0.0.1:*", lossless=False, source="renderer", heartbeat_s=0.1) as renderer,
    ):
        bus = dataclasses.replace(bus, robot_pub=robot.endpoint, estimate_pub=estimator.endpoint,
                                  display_pub=renderer.endpoint)
        with OperatorLink.from_settings(bus) as link:
            robot.wait_for_subscriber("grasp_event", "force")
            estimator.wait_for_subscriber("estimate")
            renderer.wait_for_subscriber("display")
            for publisher in (robot, estimator, renderer):
                publisher.heartbeat_if_due()
            _wait(lambda v: all(p.alive for p in v.peers), link)
            assert link.view.phase == "idle" and link.view.grasp_id is None
            # heard, but no node subscribed to the link's commands: the console shows it waiting
            assert [p.subscribed for p in link.view.peers] == [False, None, None]
            t = time.monotonic()
            robot.send("grasp_event", t_capture_s=t, event="start", grasp_id="g1", object_name="duck")
            robot.send("force", t_capture_s=t, grasp_id="g1", t_s=np.array([t, t]), value_n=np.array([1.0, 2.5]))
            robot.send("width", t_capture_s=t, grasp_id="g1", t_s=np.array([t]), value_m=np.array([0.031]))
            estimator.send("estimate", t_capture_s=t, grasp_id="g1", method="hybrid", E_pa=3.6e6,
                           interval_pa=[2e6, 6e6], state="ok", reason="loading phase 0.1-0.4 s", provisional=True,
                           latency_s=0.01)
            renderer.send("display", t_capture_s=t, grasp_id="g1", phase="active", stiffness=0.9,
                          uncertainty_decades=0.3, rigid=False, unknown=False, provisional=True, E_pa=3.6e6,
                          level=57, level_max=63)
            _wait(lambda v: v.estimate is not None and v.display is not None and v.width_m is not None, link)
            view = link.view
            assert (view.grasp_id, view.object_name, view.phase) == ("g1", "duck", "loading")
            assert view.force_n == 2.5 and view.width_m == 0.031 and view.estimate.E_pa == 3.6e6
            assert view.peak_force_n == 2.5  # the grasp's highest force so far
            assert view.stiffness == 0.9 and view.estimates == 1
            robot.send("robot_state", t_capture_s=t, mode="following", grasp_id="g1", target_width_m=0.03,
                       enable=True)
            robot.send("robot_notice", t_capture_s=t, event="watchdog", action="follow", grasp_id="g1",
                       reason="no follow for 0.2 s: fingers stopped")
            robot.send("grasp_event", t_capture_s=t, event="end", grasp_id="g1", object_name="duck")
            _wait(lambda v: v.phase == "ended", link)
            assert link.view.robot.mode == "following" and link.view.notice.event == "watchdog"
            assert link.view.notice_t_s is not None
            link.clear()
            assert link.view.grasp_id is None and link.view.estimate is None and link.view.phase == "idle"
            # what the cleared grasp still sends stays out of the view
            estimator.send("estimate", t_capture_s=t, grasp_id="g1", method="hybrid", E_pa=3.5e6,
                           interval_pa=[2e6, 6e6], state="ok", reason="final", provisional=False, latency_s=0.01)
            robot.send("grasp_event", t_capture_s=t, event="end", grasp_id="g1", object_name="duck")
            robot.send("grasp_event", t_capture_s=t, event="start", grasp_id="g2", object_name="ball")
            _wait(lambda v: v.grasp_id == "g2", link)
            assert link.view.estimate is None and link.view.phase == "loading"
            assert link.view.peak_force_n is None  # a new grasp: no force of its own yet
            # the estimator goes quiet: shown dead after three heartbeat periods
            deadline = time.monotonic() + 0.5
            while time.monotonic() < deadline:
                robot.heartbeat_if_due()
                renderer.heartbeat_if_due()
                link.poll(0.02)
            assert link.view.alive("robot node") and link.view.alive("display") and not link.view.alive("estimator")


def test_the_link_sends_follows_and_commands_once_the_robot_node_hears_them():
    settings = load_settings()
    bus = dataclasses.replace(settings.bus, command="tcp://127.0.0.1:*")
    with OperatorLink.from_settings(bus) as link:
        # Sent before the node's subscription arrived, a grasp was lost while the console waited on it.
        with Subscriber(link.publisher.endpoint, ("",)) as recorder:
            link.publisher.wait_for_subscriber("")
            with pytest.raises(BusError, match=f"robot node has not subscribed to {link.publisher.endpoint}"):
                link.start_grasp(target_force_n=10.0, grasp_id="g0")
            with pytest.raises(BusError, match="a follow now would reach no one"):
                link.follow(0.05, enable=True, grasp_id="g0")
            assert recorder.recv(timeout_s=0.2) is None and link.commands_sent == link.follows_sent == 0
        with Subscriber(link.publisher.endpoint, COMMAND_TOPICS) as robot:
            deadline = time.monotonic() + 5.0
            while not link.robot_subscribed():
                assert time.monotonic() < deadline, "the node's subscription never arrived"
                time.sleep(0.01)
            link.follow(0.05, enable=True, grasp_id="g1")
            link.start_grasp(target_force_n=10.0, grasp_id="g2")
            link.release("g2")
            got = [robot.recv(timeout_s=2.0) for _ in range(3)]
    assert [m.type for m in got] == ["follow", "command", "command"]
    assert dict(got[0].body) == {"grasp_id": "g1", "target_width_m": 0.05, "enable": True}
    assert got[1].body["action"] == "start_grasp" and got[1].body["params"] == {"target_force_n": 10.0}
    assert got[2].body["action"] == "release" and got[0].source == "operator"


def test_the_link_sends_a_label_and_shows_it_with_its_grasp():
    settings = load_settings()
    bus = dataclasses.replace(settings.bus, command="tcp://127.0.0.1:*")
    with (
        OperatorLink.from_settings(bus) as link,
        Subscriber(link.publisher.endpoint, ("label",)) as listener,
    ):
        link.publisher.wait_for_subscriber("label")
        link.handle(Message("grasp_event", {"event": "start", "grasp_id": "g1", "object_name": None}, 1.0,
                            source="robot"))
        link.label("g1", "stress_ball", modulus_pa=4e4, source="catalogue", detail="objects.toml")
        got = listener.recv(timeout_s=2.0)
        assert link.view.label.object_name == "stress_ball" and link.labels_sent == 1
        with pytest.raises(MessageRejected):
            link.label("g1", "x", source="guess")
        link.clear()
        assert link.view.label is None
    assert got.type == "label" and got.source == "operator"
    assert dict(got.body) == {"grasp_id": "g1", "object_name": "stress_ball", "modulus_pa": 4e4,
                              "source": "catalogue", "detail": "objects.toml"}
