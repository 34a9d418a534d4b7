"""The operator's side of the bus: :class:`OperatorLink` and its snapshot, :class:`OperatorView`.

:class:`OperatorLink` is the operator's bus link, with no user interface: ``haptics operate``
draws it in a terminal (:mod:`haptics.console`) and the demo's simulated operator runs it
headless. It publishes on ``bus.command`` (bound here: the operator owns that endpoint, as the
demo's operator does) and subscribes to the three publishers of the live system:

=================  ===========================================================================
``bus.robot_pub``  ``grasp_event``, ``force``, ``width``, ``robot_state``, ``robot_notice``
``bus.estimate``   ``estimate`` (the estimator's ``estimate_pub``)
``bus.display``    ``display`` (what the haptic renderer writes to the softness display)
=================  ===========================================================================

and every publisher's ``heartbeat``. It keeps the latest of each in an :class:`OperatorView`
(a frozen snapshot, safe to read from another thread): the grasp's id, object and phase, the
newest force (N) and width (m), the robot's mode, the grasp's newest estimate with its interval,
state and reason, what the display renders, the last robot notice, and who is alive: a peer is
alive when heard from (a heartbeat or any message) within :data:`LIVENESS_PERIODS` of its
heartbeat periods. While the robot node, once heard, is not alive its force, width and state are dropped (a
dead node's last readings are not its fingers' now; a node started again sends its own). A node started
again faster than that (killed and restarted within three heartbeats) is told by its messages'
sequence: a new process numbers each topic from 0 again, so a robot topic whose ``seq`` falls is a
new node; the view counts these in ``robot_restarts`` and drops the old node's readings then too. The
last notice that ended a grasp (the watchdog) is kept beside the newest notice until the view is
cleared, so that a refusal coming after it (a follow sent before the end was heard) does not hide it.
So are the ids of the last :data:`REFUSED_STARTS_KEPT` ``start_grasp`` commands the robot refused
(``refused_starts``), and the grasp ids of as many refused follows (``refused_follows``): a refusal
followed by another notice within one poll is not lost to the loop.

It sends ``follow`` messages (target width, dead-man enable, grasp id), the discrete
``command`` actions ``start_grasp`` (``params.target_force_n``), ``stop`` and ``release``, and
``label`` messages: what the object of a grasp is and its modulus, from the catalogue or a Shore
reading (:mod:`teleop.labels`), which ``teleop record`` logs with the session (it records every
topic of ``bus.command``) and ``teleop export`` takes as the grasp's label. The
command publisher is lossless (commands are never dropped silently) with a short send timeout
(:data:`SEND_TIMEOUT_S`), so a robot that stops reading cannot stall the operator's loop; a send
that fails raises, and :class:`~haptics.operator_loop.OperatorLoop` shows it instead of stopping.
A ``follow`` or ``command`` is refused the same way while the robot node's subscription has not
reached the command endpoint (it is down or still connecting): sent then, it would reach no one.
The view's robot peer says whether it has (``Peer.subscribed``), and how many robot nodes subscribe
(``Peer.nodes``, :meth:`OperatorLink.robot_nodes`): a second node on another ``bus.robot_pub`` takes
every command too, a gripper nobody watches or records, so while more than one does a
``start_grasp`` or a follow with the enable is refused (those that stop the fingers still go).

The loop that drives the gripper from an input device over this link is
:class:`~haptics.operator_loop.OperatorLoop` (:mod:`haptics.operator_loop`).
"""

from __future__ import annotations

import collections
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from teleop.bus.messages import (
    DisplayBody,
    EstimateBody,
    LabelBody,
    RobotNoticeBody,
    RobotStateBody,
)
from teleop.bus.pubsub import Publisher, Subscriber
from teleop.bus.wire import Message
from teleop.errors import BusError
from teleop.node import COMMAND_TOPICS as NODE_COMMAND_TOPICS
from teleop.settings import BusSettings

__all__ = [
    "LIVENESS_PERIODS",
    "PEERS",
    "ROBOT_TOPICS",
    "OperatorLink",
    "OperatorView",
    "Peer",
]

#: (what the operator calls it, the ``source`` it publishes as), in display order.
PEERS = (("robot node", "robot"), ("estimator", "estimator"), ("display", "renderer"))
ROBOT_TOPICS = ("grasp_event", "force", "width", "robot_state", "robot_notice")
LIVENESS_PERIODS = 3.0  # a peer unheard for this many heartbeat periods is shown dead (as Heartbeat.is_alive)
SEND_TIMEOUT_S = 0.05  # a lossless send waits at most this long for room
MAX_DRAIN = 500  # messages taken per poll, so a flood cannot starve the loop
# The command topic only a robot node subscribes to ("command" is the estimator's too, the recorder takes ""):
# its subscriptions count the robot nodes.
ROBOT_ONLY_TOPIC = "follow"
REFUSED_STARTS_KEPT = 32  # refused start_grasp ids kept: far more than an operator presses between two polls


@dataclass(frozen=True)
class Peer:
    """One process of the live system as the operator sees it."""

    name: str  # "robot node", "estimator", "display"
    source: str  # the ``source`` it publishes as
    alive: bool
    seen_ago_s: float | None  # seconds since last heard from; None: never
    subscribed: bool | None = None  # the robot node: its subscription reached our commands; None: not asked
    nodes: int | None = None  # the robot node: how many robot nodes subscribe to our commands; None: not asked


@dataclass(frozen=True)
class OperatorView:
    """What the operator link knows, at ``t_s`` (this host's monotonic clock).

    ``phase``: ``idle`` (no grasp yet, or cleared for the next object), ``loading`` (started),
    ``loaded`` (the gripper's grasp command completed: fingers stopped at the force), ``ended``.
    ``robot``, ``estimate``, ``display`` and ``notice`` are the latest such message bodies
    (``estimate``: the current grasp's), None before any. ``label``: the body of the last
    ``label`` this link sent for the current grasp, None if none. Each body is its type's
    dataclass (:mod:`teleop.bus.messages`).
    """

    t_s: float
    peers: tuple[Peer, ...] = ()
    grasp_id: str | None = None
    object_name: str | None = None
    phase: str = "idle"
    force_n: float | None = None
    peak_force_n: float | None = None  # the current grasp's highest force so far
    width_m: float | None = None
    robot: RobotStateBody | None = None
    estimate: EstimateBody | None = None
    estimates: int = 0  # estimates received for the current grasp
    estimate_orphaned: bool = False  # the estimate's estimator was heard dead since it came (none newer came)
    display: DisplayBody | None = None
    notice: RobotNoticeBody | None = None
    notice_t_s: float | None = None
    ended_by: RobotNoticeBody | None = None  # the last notice that ended a grasp (watchdog, failed gripper), until cleared
    ended_by_t_s: float | None = None
    refused: int = 0  # bus messages the subscription refused (malformed, unknown type)
    robot_restarts: int = 0  # times a robot topic's seq did not rise: the robot node was started again (a new process)
    refused_starts: tuple[str, ...] = ()  # the last start_grasp ids the robot refused, oldest first
    refused_follows: tuple[str, ...] = ()  # the grasp ids of the last follows the robot refused, oldest first
    label: LabelBody | None = None

    def peer(self, name: str) -> Peer | None:
        return next((p for p in self.peers if p.name == name or p.source == name), None)

    def alive(self, name: str) -> bool:
        """Whether the peer named ``name`` (or publishing as ``name``) is alive."""
        peer = self.peer(name)
        return peer is not None and peer.alive

    def down(self, name: str) -> bool:
        """Whether the peer named ``name`` (or publishing as ``name``) is listed and not alive."""
        peer = self.peer(name)
        return peer is not None and not peer.alive

    @property
    def stiffness(self) -> float | None:
        """What the display renders as a fraction of its range (1: rigid); None when unknown or idle."""
        shown = self.display
        if shown is None or shown.unknown or shown.phase == "idle":
            return None
        return 1.0 if shown.rigid else float(shown.stiffness)


class OperatorLink:
    """The operator's bus link (module docstring).

    Parameters
    ----------
    publisher : Publisher
        Where ``follow`` and ``command`` messages go (``bus.command``; ``source`` "operator").
    subscriber : Subscriber
        A subscription (every message, in order) to :data:`ROBOT_TOPICS`, ``estimate`` and
        ``display`` on the robot, estimator and display endpoints.
    heartbeat_s : float
        The bus's heartbeat period: a peer that announced none is alive when heard from within
        :data:`LIVENESS_PERIODS` of it.
    clock : callable
        Monotonic seconds.

    Use it from one thread (the sockets are not thread-safe); :attr:`view` may be read from any.
    """

    def __init__(self, *, publisher: Publisher, subscriber: Subscriber, heartbeat_s: float = 0.5,
                 clock: Callable[[], float] = time.monotonic):
        self.publisher = publisher
        self.subscriber = subscriber
        self.heartbeat_s = heartbeat_s
        self.clock = clock
        self.follows_sent = 0
        self.commands_sent = 0
        self.labels_sent = 0
        self._grasp_id: str | None = None
        self._object_name: str | None = None
        self._phase = "idle"
        self._force_n: float | None = None
        self._peak_force_n: float | None = None
        self._width_m: float | None = None
        self._robot: RobotStateBody | None = None
        self._estimates: dict[str, tuple[EstimateBody, int]] = {}
        self._display: DisplayBody | None = None
        self._notice: tuple[RobotNoticeBody, float] | None = None
        self._ended_by: tuple[RobotNoticeBody, float] | None = None  # the last notice that ended a grasp
        self._orphaned: set[str] = set()  # grasps whose last estimate came from an estimator heard dead since
        self._dismissed: set[str] = set()  # grasps cleared from the view: their late messages are ignored
        self._labels: dict[str, LabelBody] = {}  # grasp id -> the last label sent for it
        self._robot_seq: dict[str, int] = {}  # robot topic -> the last seq heard on it (this node process)
        self.robot_restarts = 0  # robot nodes heard started again (a topic's seq did not rise)
        self._refused_starts: collections.deque[str] = collections.deque(maxlen=REFUSED_STARTS_KEPT)
        self._refused_follows: collections.deque[str] = collections.deque(maxlen=REFUSED_STARTS_KEPT)
        self.view = self._snapshot()

    @classmethod
    def from_settings(cls, bus: BusSettings, *, clock: Callable[[], float] = time.monotonic) -> OperatorLink:
        """A link on ``bus``'s endpoints: binds ``bus.command``, connects to the three publishers.

        Raises BusError when ``bus.command`` cannot be bound (another operator holds it), and
        BusSecurityError when an endpoint leaves loopback without keys.
        """
        publisher = Publisher.from_settings(bus, bus.command, lossless=True, source="operator",
                                            send_timeout_s=SEND_TIMEOUT_S)
        try:
            subscriber = Subscriber.from_settings(bus, [bus.robot_pub, bus.estimate_pub, bus.display_pub],
                                                  (*ROBOT_TOPICS, "estimate", "display"))
        except BaseException:
            publisher.close()
            raise
        return cls(publisher=publisher, subscriber=subscriber, heartbeat_s=bus.heartbeat_s, clock=clock)

    def close(self) -> None:
        """Close both sockets; calling twice is fine."""
        self.publisher.close()
        self.subscriber.close()

    def __enter__(self) -> OperatorLink:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    # ------------------------------------------------------------------ sending

    def robot_subscribed(self) -> bool:
        """Whether the robot node's subscription to our commands is open (a send before is lost)."""
        return all(self.publisher.subscriptions(topic) for topic in NODE_COMMAND_TOPICS)

    def robot_nodes(self) -> int:
        """How many robot nodes subscribe to our commands now (the estimator and recorder not counted)."""
        return self.publisher.subscriptions(ROBOT_ONLY_TOPIC)

    def _check_robot_subscribed(self, what: str, *, drives: bool) -> None:
        if not self.robot_subscribed():
            raise BusError(f"the robot node has not subscribed to {self.publisher.endpoint} yet (it is down, or "
                           f"still connecting): a {what} now would reach no one")
        if drives and (nodes := self.robot_nodes()) > 1:
            # the fix first: an 80-column console cuts the line's end
            raise BusError(f"{nodes} robot nodes subscribe to the commands: stop all but one (a {what} now would "
                           f"drive every one; a node on its own bus.robot_pub still takes bus.command, "
                           f"{self.publisher.endpoint})")

    def follow(self, target_width_m: float, *, enable: bool, grasp_id: str | None = None) -> None:
        """Send one ``follow``: the fingers' target width (m), the dead-man enable and the grasp's id.
        BusError when the robot node is not subscribed (:meth:`robot_subscribed`), or with ``enable``
        when more than one is (:meth:`robot_nodes`)."""
        self._check_robot_subscribed("follow", drives=enable)
        self.publisher.send("follow", t_capture_s=self.clock(), grasp_id=grasp_id,
                            target_width_m=float(target_width_m), enable=bool(enable))
        self.follows_sent += 1

    def command(self, action: str, *, grasp_id: str | None = None, **params: float) -> None:
        """Send one ``command`` (``start_grasp``, ``stop``, ``release``) with numeric ``params``.
        BusError when the robot node is not subscribed (:meth:`robot_subscribed`), or for a
        ``start_grasp`` when more than one is (:meth:`robot_nodes`)."""
        self._check_robot_subscribed(action, drives=action == "start_grasp")
        self.publisher.send("command", t_capture_s=self.clock(), action=action, grasp_id=grasp_id,
                            params={k: float(v) for k, v in params.items()})
        self.commands_sent += 1

    def start_grasp(self, *, target_force_n: float, grasp_id: str | None = None) -> None:
        """A discrete grasp: close on the object until ``target_force_n``, hold, open."""
        self.command("start_grasp", grasp_id=grasp_id, target_force_n=target_force_n)

    def stop(self, grasp_id: str | None = None) -> None:
        """Stop the fingers where they are."""
        self.command("stop", grasp_id=grasp_id)

    def release(self, grasp_id: str | None = None) -> None:
        """Open the fingers (ends a follow grasp)."""
        self.command("release", grasp_id=grasp_id)

    def label(self, grasp_id: str, object_name: str, *, modulus_pa: float | None = None, source: str,
              detail: str = "") -> None:
        """Send one ``label``: grasp ``grasp_id`` held ``object_name``, of modulus ``modulus_pa`` (Pa;
        None: the catalogue's), from ``source`` (one of :data:`teleop.labels.LABEL_SOURCES`),
        ``detail`` in words. Raises MessageRejected for fields the ``label`` message refuses."""
        sent = self.publisher.send("label", t_capture_s=self.clock(), grasp_id=grasp_id, object_name=object_name,
                                   modulus_pa=None if modulus_pa is None else float(modulus_pa), source=source,
                                   detail=detail)
        self.labels_sent += 1
        self._labels[grasp_id] = sent.fields
        self.view = self._snapshot()

    def clear(self) -> None:
        """Forget the grasp shown (its phase and estimate, and whatever it still sends): ready for the
        next object."""
        self._dismissed.update(self._estimates)
        if self._grasp_id is not None:
            self._dismissed.add(self._grasp_id)
        self._grasp_id, self._object_name, self._phase = None, None, "idle"
        self._peak_force_n = None
        self._estimates.clear()
        self._orphaned.clear()
        self._notice = self._ended_by = None  # the last grasp's notices go with it
        self.view = self._snapshot()

    # ------------------------------------------------------------------ receiving

    def poll(self, timeout_s: float = 0.0) -> int:
        """Take what arrived (waiting up to ``timeout_s`` for the first message), heartbeat, and
        refresh :attr:`view`; returns how many messages were taken."""
        self.publisher.heartbeat_if_due(self.clock())
        taken = 0
        message = self.subscriber.recv(timeout_s=timeout_s)
        while message is not None:
            self._check_restart(message)
            self.handle(message)
            taken += 1
            if taken >= MAX_DRAIN:
                break
            message = self.subscriber.recv(timeout_s=0)
        self.view = self._snapshot()
        return taken

    def _check_restart(self, message: Message) -> None:
        """Count a robot node started again: a robot topic's ``seq`` did not rise (a new process numbers each
        topic from 0; the node sends a ``robot_state`` with every heartbeat, so a restart is heard
        within one). Heard however fast the node came back, unlike its liveness. The old node's
        readings are dropped, and its other topics' numbers forgotten: one restart counts once."""
        if message.source != "robot" or message.topic not in ROBOT_TOPICS:
            return
        last = self._robot_seq.get(message.topic)
        if last is not None and message.seq <= last:
            self.robot_restarts += 1
            self._robot_seq.clear()
            self._force_n = self._width_m = self._robot = None  # the old node's: not its fingers' now
        self._robot_seq[message.topic] = message.seq

    def handle(self, message: Message) -> None:
        """Keep what ``message`` says (called by :meth:`poll`; public for tests and replays)."""
        body = message.fields
        kind = message.type
        if kind in ("grasp_event", "estimate") and body.grasp_id in self._dismissed:
            return
        if kind == "grasp_event" and message.source == "robot":
            if body.event == "start" or body.grasp_id != self._grasp_id:
                self._grasp_id, self._object_name = body.grasp_id, body.object_name
                self._peak_force_n = None
                self._estimates = {k: v for k, v in self._estimates.items() if k == self._grasp_id}
            self._phase = {"start": "loading", "loading_end": "loaded", "end": "ended"}[body.event]
        elif kind == "force":
            self._force_n = float(body.value_n[-1])
            if body.grasp_id is not None and body.grasp_id == self._grasp_id:
                self._peak_force_n = max(self._peak_force_n or 0.0, float(body.value_n.max()))
        elif kind == "width":
            self._width_m = float(body.value_m[-1])
        elif kind == "robot_state":
            self._robot = body
        elif kind == "robot_notice":
            self._notice = (body, self.clock())
            if body.ended_grasp() is not None:
                self._ended_by = self._notice
            elif body.event == "refused" and body.action == "start_grasp" and body.grasp_id is not None:
                self._refused_starts.append(body.grasp_id)
            elif body.event == "refused" and body.action == "follow" and body.grasp_id is not None:
                self._refused_follows.append(body.grasp_id)
        elif kind == "estimate":
            self._orphaned.discard(body.grasp_id)
            _, count = self._estimates.get(body.grasp_id, (None, 0))
            self._estimates[body.grasp_id] = (body, count + 1)
        elif kind == "display":
            self._display = body

    def _peers(self, now: float) -> tuple[Peer, ...]:
        heartbeat = self.subscriber.heartbeat
        peers = []
        for name, source in PEERS:
            last = heartbeat.last_seen_s(source)
            if last is None:
                peers.append(Peer(name, source, False, None))
                continue
            try:  # three of its announced heartbeat periods (Heartbeat's rule)
                alive = heartbeat.is_alive(source, now_s=now)
            except BusError:  # heard from, but no period announced yet: the bus's
                alive = heartbeat.is_alive(source, timeout_s=LIVENESS_PERIODS * self.heartbeat_s, now_s=now)
            subscribed, nodes = (self.robot_subscribed(), self.robot_nodes()) if source == "robot" else (None, None)
            peers.append(Peer(name, source, alive, max(0.0, now - last), subscribed, nodes))
        return tuple(peers)

    def _snapshot(self) -> OperatorView:
        now = self.clock()
        peers = self._peers(now)
        if any(p.seen_ago_s is not None and not p.alive for p in peers if p.source == "robot"):
            self._force_n = self._width_m = self._robot = None  # heard, now dead: its readings are gone
        if any(p.seen_ago_s is not None and not p.alive for p in peers if p.source == "estimator"):
            self._orphaned.update(self._estimates)  # a restarted estimator does not go on with them
        estimate, count = self._estimates.get(self._grasp_id, (None, 0)) if self._grasp_id else (None, 0)
        if self._grasp_id is None and self._estimates:  # estimates before any grasp event: the newest
            estimate, count = next(reversed(self._estimates.values()))
        notice, notice_t = self._notice if self._notice is not None else (None, None)
        ended_by, ended_by_t = self._ended_by if self._ended_by is not None else (None, None)
        return OperatorView(
            t_s=now, peers=peers, grasp_id=self._grasp_id, object_name=self._object_name,
            phase=self._phase, force_n=self._force_n, peak_force_n=self._peak_force_n, width_m=self._width_m,
            robot=self._robot,
            estimate=estimate, estimates=count, display=self._display, notice=notice, notice_t_s=notice_t,
            estimate_orphaned=estimate is not None and estimate.grasp_id in self._orphaned,
            ended_by=ended_by, ended_by_t_s=ended_by_t,
            refused=sum(self.subscriber.stats.refused.values()), robot_restarts=self.robot_restarts,
            refused_starts=tuple(self._refused_starts), refused_follows=tuple(self._refused_follows),
            label=self._labels.get(self._grasp_id) if self._grasp_id is not None else None,
        )
