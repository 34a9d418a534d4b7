"""The operator's link (:mod:`haptics.operator_link`) on fake sockets and a fake clock: the grasp it shows
from the robot's events, the forces and estimates it keeps for that grasp, what a cleared grasp still
sends, the polls' bound and heartbeat, the robot node's subscription, and what it sends."""

from __future__ import annotations

import dataclasses
import itertools

import numpy as np
import pytest
from support.operator_fakes import Clock, QueuedSubscriber, SubscribedPublisher

import haptics.operator_link as operator_link
from haptics.operator_link import MAX_DRAIN, OperatorLink
from teleop.bus.wire import make_message
from teleop.errors import BusError, BusSecurityError
from teleop.settings import load_settings

_seq = itertools.count()


def _link() -> tuple[OperatorLink, QueuedSubscriber, Clock]:
    clock = Clock()
    subscriber = QueuedSubscriber(clock)
    return OperatorLink(publisher=SubscribedPublisher(), subscriber=subscriber, clock=clock), subscriber, clock


def _msg(kind: str, source: str = "robot", **fields):
    message = make_message(kind, t_capture_s=0.0, **fields)
    return dataclasses.replace(message, source=source, topic=kind, seq=next(_seq))


def _event(event: str, grasp_id: str, object_name: str = "duck"):
    return _msg("grasp_event", event=event, grasp_id=grasp_id, object_name=object_name)


def _estimate(grasp_id: str, e_pa: float, provisional: bool = False):
    return _msg("estimate", source="estimator", grasp_id=grasp_id, method="series", E_pa=e_pa,
                interval_pa=[e_pa / 2, e_pa * 2], state="ok", reason="", provisional=provisional, latency_s=0.01)


def _force(grasp_id: str | None, *values: float):
    return _msg("force", grasp_id=grasp_id, t_s=np.arange(len(values), dtype=float),
                value_n=np.array(values, dtype=float))


def test_a_cleared_grasps_late_messages_do_not_bring_it_back():
    link, subscriber, _ = _link()
    subscriber.queue += [_event("start", "op-1"), _event("end", "op-1"), _estimate("op-1", 5e4, provisional=True)]
    link.poll()
    assert link.view.grasp_id == "op-1" and link.view.phase == "ended" and link.view.estimate is not None
    link.clear()  # the operator pressed next: ready for the next object
    subscriber.queue += [_estimate("op-1", 6e4), _event("end", "op-1")]  # the final estimate, a repeated end: late
    link.poll()
    view = link.view
    assert view.grasp_id is None and view.phase == "idle" and view.estimate is None and view.estimates == 0


def test_the_peak_force_is_the_current_grasps_own_highest():
    link, subscriber, _ = _link()
    subscriber.queue += [_event("start", "op-1"), _force("op-1", 5.0, 20.0, 12.0), _force("op-1", 8.0)]
    link.poll()
    assert link.view.peak_force_n == 20.0 and link.view.force_n == 8.0  # the peak kept, the newest shown
    subscriber.queue += [_force(None, 30.0), _force("op-other", 40.0)]  # fingers idle, or another grasp's: not this one's
    link.poll()
    assert link.view.peak_force_n == 20.0 and link.view.force_n == 40.0
    subscriber.queue += [_event("end", "op-1"), _event("start", "op-2"), _force("op-2", 3.0)]
    link.poll()
    assert link.view.grasp_id == "op-2" and link.view.peak_force_n == 3.0  # not the last grasp's 20 N


def test_clear_also_dismisses_a_grasp_known_only_by_its_estimates():
    link, subscriber, _ = _link()
    # The link came up mid-grasp: the grasp's start was before it, only its estimates are heard.
    subscriber.queue += [_estimate("op-9", 5e4, provisional=True)]
    link.poll()
    assert link.view.grasp_id is None and link.view.estimate.grasp_id == "op-9"
    link.clear()
    subscriber.queue += [_estimate("op-9", 6e4)]  # its final, late: not the next object's
    link.poll()
    assert link.view.estimate is None and link.view.estimates == 0


def test_a_late_estimate_of_the_last_grasp_is_not_shown_as_the_current_grasps():
    link, subscriber, _ = _link()
    subscriber.queue += [_event("start", "op-1"), _event("end", "op-1"), _event("start", "op-2"),
                  _estimate("op-1", 5e4)]  # op-1's final, after op-2 started (no next pressed between)
    link.poll()
    assert link.view.grasp_id == "op-2" and link.view.estimate is None and link.view.estimates == 0
    subscriber.queue += [_estimate("op-2", 7e4, provisional=True)]
    link.poll()
    assert link.view.estimate.grasp_id == "op-2" and link.view.estimates == 1


class _HeartbeatRecorder(SubscribedPublisher):
    def __init__(self):
        self.asked: list[float | None] = []

    def heartbeat_if_due(self, now_s: float | None = None) -> bool:
        self.asked.append(now_s)
        return True


def test_every_poll_gives_the_operators_heartbeat_its_chance_on_the_links_clock():
    clock = Clock()
    publisher = _HeartbeatRecorder()
    link = OperatorLink(publisher=publisher, subscriber=QueuedSubscriber(clock), clock=clock)
    link.poll()
    clock.t += 0.5
    link.poll()
    assert publisher.asked == [100.0, 100.5]


class _EstimatorOnly(SubscribedPublisher):
    """bus.command with the estimator's subscription ("command") but no robot node's ("follow")."""

    endpoint = "tcp://127.0.0.1:5555"

    def subscriptions(self, prefix: str) -> int:
        return 1 if prefix == "command" else 0


def test_the_estimators_subscription_is_not_taken_for_the_robot_nodes():
    clock = Clock()
    subscriber = QueuedSubscriber(clock)
    link = OperatorLink(publisher=_EstimatorOnly(), subscriber=subscriber, clock=clock)
    assert not link.robot_subscribed() and link.robot_nodes() == 0
    with pytest.raises(BusError, match="has not subscribed"):
        link.follow(0.05, enable=True, grasp_id="op-1")
    with pytest.raises(BusError, match="has not subscribed"):
        link.start_grasp(target_force_n=5.0, grasp_id="op-2")
    assert link.follows_sent == 0 and link.commands_sent == 0
    subscriber.queue.append(_msg("robot_state", mode="idle", grasp_id=None, target_width_m=None, enable=False))
    link.poll()
    assert link.view.peer("robot node").subscribed is False


def test_the_loading_end_shows_the_grasp_loaded():
    link, subscriber, _ = _link()
    subscriber.queue += [_event("start", "op-1")]
    link.poll()
    assert link.view.phase == "loading"
    subscriber.queue += [_event("loading_end", "op-1")]
    link.poll()
    assert link.view.phase == "loaded"
    subscriber.queue += [_event("end", "op-1")]
    link.poll()
    assert link.view.phase == "ended"


def test_a_grasp_whose_start_was_not_heard_is_shown_from_its_next_event():
    link, subscriber, _ = _link()
    # The console came up while the robot ran op-5: its start was before the link subscribed.
    subscriber.queue += [_event("loading_end", "op-5", "sponge")]
    link.poll()
    assert (link.view.grasp_id, link.view.object_name, link.view.phase) == ("op-5", "sponge", "loaded")
    subscriber.queue += [_force("op-5", 9.0), _event("end", "op-5", "sponge"), _event("end", "op-6", "duck")]
    link.poll()
    # op-6's start was lost: its end still names it, with none of op-5's peak.
    assert (link.view.grasp_id, link.view.object_name, link.view.phase) == ("op-6", "duck", "ended")
    assert link.view.peak_force_n is None


def test_a_flood_is_taken_in_bounded_polls_so_the_loop_keeps_its_rate():
    link, subscriber, _ = _link()
    subscriber.queue += [_force(None, float(i)) for i in range(MAX_DRAIN + 100)]
    assert link.poll() == MAX_DRAIN
    assert link.view.force_n == float(MAX_DRAIN - 1)  # the view refreshed with what was taken
    assert link.poll() == 100 and link.view.force_n == float(MAX_DRAIN + 99)


def test_next_object_forgets_the_last_grasps_peak_force():
    link, subscriber, _ = _link()
    subscriber.queue += [_event("start", "op-1"), _force("op-1", 14.0), _event("end", "op-1")]
    link.poll()
    assert link.view.peak_force_n == 14.0
    link.clear()
    assert link.view.phase == "idle" and link.view.peak_force_n is None


def test_only_the_robot_nodes_grasp_events_move_the_grasp_shown():
    link, subscriber, _ = _link()
    subscriber.queue += [_event("start", "op-1")]
    link.poll()
    stray = dataclasses.replace(_event("start", "op-x", "ghost"), source="estimator")
    subscriber.queue += [stray]
    link.poll()
    assert (link.view.grasp_id, link.view.object_name, link.view.phase) == ("op-1", "duck", "loading")


def test_a_link_that_cannot_subscribe_frees_the_command_endpoint_it_bound(monkeypatch):
    closed = []

    class BoundCommand(SubscribedPublisher):
        def close(self) -> None:
            closed.append(True)

    def refuse(*args, **kwargs):
        raise BusSecurityError("bus.robot_pub leaves loopback without keys")

    monkeypatch.setattr(operator_link.Publisher, "from_settings", classmethod(lambda cls, *a, **k: BoundCommand()))
    monkeypatch.setattr(operator_link.Subscriber, "from_settings", classmethod(lambda cls, *a, **k: refuse()))
    with pytest.raises(BusSecurityError):
        OperatorLink.from_settings(load_settings().bus)
    assert closed == [True]  # bus.command is free again: a second try is not told another operator holds it


class _SendRecorder(SubscribedPublisher):
    def __init__(self):
        self.sent: list[tuple[str, dict]] = []

    def send(self, kind: str, **fields):
        self.sent.append((kind, fields))
        return make_message(kind, **fields)


def test_the_counts_of_follows_and_commands_sent_are_what_went_out():
    clock = Clock()
    publisher = _SendRecorder()
    link = OperatorLink(publisher=publisher, subscriber=QueuedSubscriber(clock), clock=clock)
    link.follow(0.05, enable=True, grasp_id="op-1")
    link.follow(0.04, enable=False, grasp_id="op-1")
    link.start_grasp(target_force_n=6, grasp_id="op-2")
    link.release("op-2")
    assert (link.follows_sent, link.commands_sent) == (2, 2)
    assert publisher.sent[0] == ("follow", {"t_capture_s": 100.0, "grasp_id": "op-1", "target_width_m": 0.05,
                                            "enable": True})
    assert publisher.sent[2][1]["params"] == {"target_force_n": 6.0} and publisher.sent[2][1]["action"] == "start_grasp"
