"""The operator's link (:mod:`haptics.operator_link`) on fake sockets and a fake clock: the dead-man it
sends, the newest readings it keeps, which notices count as refusals, what ``clear`` dismisses, how long a
peer that announced no heartbeat period stays alive, and what the display's stiffness reads as (cases
the other operator-link tests leave open)."""

from __future__ import annotations

import dataclasses
import itertools

import numpy as np
import pytest
from support.operator_fakes import Clock, QueuedSubscriber, SubscribedPublisher

import haptics.operator_link as operator_link
from haptics.operator_link import OperatorLink, OperatorView, Peer
from teleop.bus.messages import DisplayBody
from teleop.bus.wire import make_message
from teleop.settings import load_settings

_seq = itertools.count()


def _link(publisher=None) -> tuple[OperatorLink, QueuedSubscriber, Clock]:
    clock = Clock()
    subscriber = QueuedSubscriber(clock)
    link = OperatorLink(publisher=publisher or SubscribedPublisher(), subscriber=subscriber, clock=clock)
    return link, subscriber, clock


def _message(kind: str, source: str = "robot", **fields):
    return dataclasses.replace(make_message(kind, t_capture_s=0.0, **fields), source=source, topic=kind,
                               seq=next(_seq))


def _estimate(grasp_id: str, e_pa: float):
    return _message("estimate", source="estimator", grasp_id=grasp_id, method="series", E_pa=e_pa,
                    interval_pa=[e_pa / 2, e_pa * 2], state="ok", reason="", provisional=True, latency_s=0.01)


@pytest.mark.parametrize("enable", [True, False])
def test_a_follow_goes_out_with_the_enable_it_was_given(enable):
    # enable=False is the dead-man let go: the fingers must stop, not follow.
    publisher, sent = SubscribedPublisher(), []
    publisher.send = lambda kind, **fields: sent.append((kind, fields)) or make_message(kind, **fields)
    link, _, _ = _link(publisher)
    link.follow(0.03, enable=enable, grasp_id="op-1")
    assert [(kind, fields["enable"]) for kind, fields in sent] == [("follow", enable)]


def test_the_width_shown_is_the_newest_sample_of_a_message():
    link, subscriber, _ = _link()
    subscriber.queue.append(_message("width", grasp_id=None, t_s=np.arange(3, dtype=float),
                                     value_m=np.array([0.08, 0.06, 0.05])))
    link.poll()
    assert link.view.width_m == 0.05


@pytest.mark.parametrize("action", ["start_grasp", "follow"])
def test_a_notice_other_than_a_refusal_is_no_refused_start_or_follow(action):
    link, subscriber, _ = _link()
    subscriber.queue.append(_message("robot_notice", event="force_limit", action=action, grasp_id="op-1",
                                     reason="the force passed the limit"))
    link.poll()
    assert link.view.notice.event == "force_limit"
    assert link.view.refused_starts == () and link.view.refused_follows == ()


def test_clear_dismisses_a_grasp_known_only_by_its_events():
    link, subscriber, _ = _link()
    subscriber.queue += [_message("grasp_event", event="start", grasp_id="op-1", object_name="duck"),
                         _message("grasp_event", event="end", grasp_id="op-1", object_name="duck")]
    link.poll()
    link.clear()
    subscriber.queue.append(_message("grasp_event", event="end", grasp_id="op-1", object_name="duck"))  # late
    link.poll()
    assert link.view.grasp_id is None and link.view.phase == "idle"


def test_estimates_before_any_grasp_event_show_the_newest():
    link, subscriber, _ = _link()
    subscriber.queue += [_estimate("op-1", 5e4), _estimate("op-2", 7e4)]
    link.poll()
    assert link.view.grasp_id is None and link.view.estimate.grasp_id == "op-2"


def test_a_peer_with_no_announced_period_is_alive_for_three_of_the_bus_heartbeats():
    link, subscriber, clock = _link()
    subscriber.heartbeat.saw("robot")  # heard, no period announced
    for ago_s, alive in ((1.4, True), (1.6, False)):  # the link's heartbeat_s is 0.5 s
        clock.t = 100.0 + ago_s
        link.poll()
        assert link.view.alive("robot node") is alive


def _display(**fields) -> DisplayBody:
    body = {"phase": "active", "stiffness": 0.4, "uncertainty_decades": 0.2, "rigid": False, "unknown": False,
            "provisional": False, "E_pa": 1e6}
    return DisplayBody(**{**body, **fields})


@pytest.mark.parametrize(("display", "stiffness"), [
    (_display(), 0.4),
    (_display(rigid=True, stiffness=0.7), 1.0),
    (_display(phase="idle"), None),
    (_display(unknown=True), None),
], ids=["rendered", "rigid", "idle", "unknown"])
def test_the_stiffness_the_display_renders(display, stiffness):
    assert OperatorView(t_s=0.0, display=display).stiffness == stiffness


def test_a_peer_heard_a_second_ago_is_shown_seen_a_second_ago():
    link, subscriber, clock = _link()
    subscriber.heartbeat.saw("robot", interval_s=0.5)
    clock.t += 1.0
    link.poll()
    assert link.view.peer("robot node").seen_ago_s == pytest.approx(1.0)


def test_the_command_publisher_is_lossless_with_a_short_send_timeout(monkeypatch):
    # A command dropped silently would leave the fingers closed; a robot that stops reading must not
    # stall the loop.
    asked = {}

    def publisher(cls, bus, endpoint, **options):
        asked.update(options, endpoint=endpoint)
        return SubscribedPublisher()

    monkeypatch.setattr(operator_link.Publisher, "from_settings", classmethod(publisher))
    monkeypatch.setattr(operator_link.Subscriber, "from_settings",
                        classmethod(lambda cls, *a, **k: QueuedSubscriber(Clock())))
    bus = load_settings().bus
    OperatorLink.from_settings(bus)
    assert asked["endpoint"] == bus.command and asked["lossless"] is True
    assert asked["send_timeout_s"] == operator_link.SEND_TIMEOUT_S and asked["source"] == "operator"


def test_a_poll_waits_only_for_its_first_message():
    link, subscriber, _ = _link()
    subscriber.queue += [_message("width", grasp_id=None, t_s=np.zeros(1), value_m=np.array([0.05]))
                         for _ in range(3)]
    waits, recv = [], subscriber.recv
    subscriber.recv = lambda timeout_s=None: waits.append(timeout_s) or recv(timeout_s)
    assert link.poll(0.2) == 3
    assert waits == [0.2, 0, 0, 0]


@pytest.mark.parametrize("how", ["close", "with"])
def test_closing_the_link_closes_both_its_sockets(how):
    link, subscriber, _ = _link()
    closed = []
    link.publisher.close = lambda: closed.append("publisher")
    subscriber.close = lambda: closed.append("subscriber")
    if how == "close":
        link.close()
    else:
        with link:
            pass
    assert sorted(closed) == ["publisher", "subscriber"]


def test_a_peer_is_found_by_the_source_it_publishes_as_too():
    view = OperatorView(t_s=0.0, peers=(Peer("display", "renderer", True, 0.1),))
    assert view.peer("renderer").name == "display" and view.alive("renderer") and not view.down("renderer")
