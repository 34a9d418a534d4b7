"""The operator's side of the bus, and the loop that drives the gripper from an input device.

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
heartbeat periods.

It sends ``follow`` messages (target width, dead-man enable, grasp id), the discrete
``command`` actions ``start_grasp`` (``params.target_force_n``), ``stop`` and ``release``, and
``label`` messages: what the object of a grasp is and its modulus, from the catalogue or a Shore
reading (:mod:`teleop.labels`), which ``teleop record`` logs with the session (it records every
topic of ``bus.command``) and ``teleop export`` takes as the grasp's label. The
command publisher is lossless (commands are never dropped silently) with a short send timeout
(:data:`SEND_TIMEOUT_S`), so a robot that stops reading cannot stall the operator's loop; a send
that fails raises, and :class:`OperatorLoop` shows it instead of stopping.

:class:`OperatorLoop` reads an operator input device (:mod:`haptics.inputs`) and turns it into
those messages (:meth:`OperatorLoop.step`):

* the grip (0 open .. 1 squeezed) sets the fingers' target width,
  :func:`teleop.operator.grip_to_width_m` over ``gripper.max_width_m``;
* while the dead-man enable is held, ``follow`` goes out at
  :data:`teleop.operator.FOLLOW_RATE_HZ` with ``enable=True``; when it is let go, follows go on
  at the rate with ``enable=False`` (the fingers stop where they are) for as long as the robot
  runs that follow grasp (its ``robot_state`` or grasp events say so), at least
  :data:`RELEASE_FOLLOWS` of them: an operator pausing keeps the grasp, while the robot's
  watchdog ends it when the console dies (follows stop arriving);
* :meth:`OperatorLoop.label` (any thread) names the object of a grasp; the loop sends the
  ``label`` on its next step;
* buttons: ``grasp`` starts a discrete grasp at the chosen force, ``release`` opens the fingers,
  ``stop`` stops them where they are, ``next`` ends the grasp shown (releasing it if still under
  way) and clears the view for the next object, ``quit`` ends the loop;
* after ``stop``, ``release`` or ``next``, and when the robot ends the follow grasp (released,
  the watchdog), no follow goes out until the enable has been let go and held again: a held
  enable never moves the fingers again, nor starts a new grasp, by itself;
* the robot side's force, width and the display's stiffness go back to the device
  (``device.feel``): the simulated operator closes its loop on them.

A follow grasp takes a new grasp id when enable is first held after the previous grasp ended;
a discrete grasp takes one per ``grasp`` press. Ids are ``op-<HHMMSS>-<n>``, unique within a
session.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from datetime import datetime
from typing import Any, Protocol

from teleop.bus.pubsub import Publisher, Subscriber
from teleop.bus.wire import Message
from teleop.errors import BusError, ComplianceTeleopError
from teleop.operator import BUTTONS, FOLLOW_RATE_HZ, grip_to_width_m
from teleop.settings import BusSettings, Settings

__all__ = [
    "LIVENESS_PERIODS",
    "PEERS",
    "RELEASE_FOLLOWS",
    "ROBOT_TOPICS",
    "LoopStatus",
    "OperatorLink",
    "OperatorLoop",
    "OperatorView",
    "Peer",
]

log = logging.getLogger(__name__)

#: (what the operator calls it, the ``source`` it publishes as), in display order.
PEERS = (("robot node", "robot"), ("estimator", "estimator"), ("display", "renderer"))
ROBOT_TOPICS = ("grasp_event", "force", "width", "robot_state", "robot_notice")
LIVENESS_PERIODS = 3.0  # a peer unheard for this many heartbeat periods is shown dead (as Heartbeat.is_alive)
SEND_TIMEOUT_S = 0.05  # a lossless send waits at most this long for room
RELEASE_FOLLOWS = 3  # follows with enable=False sent at least when the dead-man is let go
MAX_DRAIN = 500  # messages taken per poll, so a flood cannot starve the loop
IDLE_TICK_S = 0.01  # the loop's longest wait when not sending follows


@dataclass(frozen=True)
class Peer:
    """One process of the live system as the operator sees it."""

    name: str  # "robot node", "estimator", "display"
    source: str  # the ``source`` it publishes as
    alive: bool
    seen_ago_s: float | None  # seconds since last heard from; None: never


@dataclass(frozen=True)
class OperatorView:
    """What the operator link knows, at ``t_s`` (this host's monotonic clock).

    ``phase``: ``idle`` (no grasp yet, or cleared for the next object), ``loading`` (started),
    ``loaded`` (the gripper's grasp command completed: fingers stopped at the force), ``ended``.
    ``robot``, ``estimate``, ``display`` and ``notice`` are the latest such message bodies
    (``estimate``: the current grasp's), None before any. ``label``: the body of the last
    ``label`` this link sent for the current grasp, None if none.
    """

    t_s: float
    peers: tuple[Peer, ...] = ()
    grasp_id: str | None = None
    object_name: str | None = None
    phase: str = "idle"
    force_n: float | None = None
    width_m: float | None = None
    robot: Mapping[str, Any] | None = None
    estimate: Mapping[str, Any] | None = None
    estimates: int = 0  # estimates received for the current grasp
    display: Mapping[str, Any] | None = None
    notice: Mapping[str, Any] | None = None
    notice_t_s: float | None = None
    refused: int = 0  # bus messages the subscription refused (malformed, unknown type)
    label: Mapping[str, Any] | None = None

    def peer(self, name: str) -> Peer | None:
        return next((p for p in self.peers if p.name == name or p.source == name), None)

    def alive(self, name: str) -> bool:
        """Whether the peer named ``name`` (or publishing as ``name``) is alive."""
        peer = self.peer(name)
        return peer is not None and peer.alive

    @property
    def stiffness(self) -> float | None:
        """What the display renders as a fraction of its range (1: rigid); None when unknown or idle."""
        shown = self.display
        if shown is None or shown["unknown"] or shown["phase"] == "idle":
            return None
        return 1.0 if shown["rigid"] else float(shown["stiffness"])


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
        self._width_m: float | None = None
        self._robot: Mapping[str, Any] | None = None
        self._estimates: dict[str, tuple[Mapping[str, Any], int]] = {}
        self._display: Mapping[str, Any] | None = None
        self._notice: tuple[Mapping[str, Any], float] | None = None
        self._dismissed: set[str] = set()  # grasps cleared from the view: their late messages are ignored
        self._labels: dict[str, Mapping[str, Any]] = {}  # grasp id -> the last label sent for it
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

    def follow(self, target_width_m: float, *, enable: bool, grasp_id: str | None = None) -> None:
        """Send one ``follow``: the fingers' target width (m), the dead-man enable and the grasp's id."""
        self.publisher.send("follow", t_capture_s=self.clock(), grasp_id=grasp_id,
                            target_width_m=float(target_width_m), enable=bool(enable))
        self.follows_sent += 1

    def command(self, action: str, *, grasp_id: str | None = None, **params: float) -> None:
        """Send one ``command`` (``start_grasp``, ``stop``, ``release``) with numeric ``params``."""
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
        self._labels[grasp_id] = dict(sent.body)
        self.view = self._snapshot()

    def clear(self) -> None:
        """Forget the grasp shown (its phase and estimate, and whatever it still sends): ready for the
        next object."""
        self._dismissed.update(self._estimates)
        if self._grasp_id is not None:
            self._dismissed.add(self._grasp_id)
        self._grasp_id, self._object_name, self._phase = None, None, "idle"
        self._estimates.clear()
        self.view = self._snapshot()

    # ------------------------------------------------------------------ receiving

    def poll(self, timeout_s: float = 0.0) -> int:
        """Take what arrived (waiting up to ``timeout_s`` for the first message), heartbeat, and
        refresh :attr:`view`; returns how many messages were taken."""
        self.publisher.heartbeat_if_due(self.clock())
        taken = 0
        message = self.subscriber.recv(timeout_s=timeout_s)
        while message is not None:
            self.handle(message)
            taken += 1
            if taken >= MAX_DRAIN:
                break
            message = self.subscriber.recv(timeout_s=0)
        self.view = self._snapshot()
        return taken

    def handle(self, message: Message) -> None:
        """Keep what ``message`` says (called by :meth:`poll`; public for tests and replays)."""
        body = message.body
        kind = message.type
        if kind in ("grasp_event", "estimate") and body["grasp_id"] in self._dismissed:
            return
        if kind == "grasp_event" and message.source == "robot":
            if body["event"] == "start" or body["grasp_id"] != self._grasp_id:
                self._grasp_id, self._object_name = body["grasp_id"], body["object_name"]
                self._estimates = {k: v for k, v in self._estimates.items() if k == self._grasp_id}
            self._phase = {"start": "loading", "loading_end": "loaded", "end": "ended"}[body["event"]]
        elif kind == "force":
            self._force_n = float(body["value_n"][-1])
        elif kind == "width":
            self._width_m = float(body["value_m"][-1])
        elif kind == "robot_state":
            self._robot = dict(body)
        elif kind == "robot_notice":
            self._notice = (dict(body), self.clock())
        elif kind == "estimate":
            _, count = self._estimates.get(body["grasp_id"], (None, 0))
            self._estimates[body["grasp_id"]] = (dict(body), count + 1)
        elif kind == "display":
            self._display = dict(body)

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
            peers.append(Peer(name, source, alive, max(0.0, now - last)))
        return tuple(peers)

    def _snapshot(self) -> OperatorView:
        now = self.clock()
        estimate, count = self._estimates.get(self._grasp_id, (None, 0)) if self._grasp_id else (None, 0)
        if self._grasp_id is None and self._estimates:  # estimates before any grasp event: the newest
            estimate, count = next(reversed(self._estimates.values()))
        notice, notice_t = self._notice if self._notice is not None else (None, None)
        return OperatorView(
            t_s=now, peers=self._peers(now), grasp_id=self._grasp_id, object_name=self._object_name,
            phase=self._phase, force_n=self._force_n, width_m=self._width_m, robot=self._robot,
            estimate=estimate, estimates=count, display=self._display, notice=notice, notice_t_s=notice_t,
            refused=sum(self.subscriber.stats.refused.values()),
            label=self._labels.get(self._grasp_id) if self._grasp_id is not None else None,
        )


# --------------------------------------------------------------------------- the loop


class InputDevice(Protocol):
    """What the loop needs of an operator input device (:mod:`haptics.inputs`)."""

    def read(self, *, timeout_s: float) -> Any: ...

    def feel(self, *, force_n: float, width_m: float, stiffness: float | None) -> None: ...


class Link(Protocol):
    """What the loop needs of a link: :class:`OperatorLink` or a test's fake."""

    view: OperatorView

    def poll(self, timeout_s: float = 0.0) -> int: ...

    def follow(self, target_width_m: float, *, enable: bool, grasp_id: str | None = None) -> None: ...

    def start_grasp(self, *, target_force_n: float, grasp_id: str | None = None) -> None: ...

    def stop(self, grasp_id: str | None = None) -> None: ...

    def release(self, grasp_id: str | None = None) -> None: ...

    def clear(self) -> None: ...

    def label(self, grasp_id: str, object_name: str, *, modulus_pa: float | None = None, source: str,
              detail: str = "") -> None: ...


@dataclass(frozen=True)
class LoopStatus:
    """The loop's state for a user interface (a frozen snapshot, safe to read from any thread)."""

    view: OperatorView
    grip: float = 0.0
    enable: bool = False
    operator_force_n: float | None = None  # the operator's grip force, where the device measures it
    target_width_m: float | None = None
    mode: str = "idle"  # "idle", "follow" (driving with enable), "discrete" (a commanded grasp under way)
    grasp_id: str | None = None  # the grasp the loop drives or commanded last
    force_n: float = 0.0  # the discrete grasp's force
    last_action: str = ""  # what the operator did last, in words
    problem: str = ""  # the last thing that went wrong (a send or read that failed), in words
    follows_sent: int = 0
    commands_sent: int = 0
    quit: bool = False
    log: tuple[str, ...] = field(default_factory=tuple)
    label_grasp_id: str | None = None  # the grasp a label would name now: the current one, else the last
    labels: Mapping[str, Any] = field(default_factory=dict)  # grasp id -> the label body sent, this session


class OperatorLoop:
    """Drives the gripper from an operator input device over a link (module docstring).

    Parameters
    ----------
    link : OperatorLink
        Or anything with its sending methods, ``poll`` and ``view``.
    device : OperatorInputDevice
        Connected; the loop reads it and feeds the robot's state back to it.
    settings : Settings
        ``gripper.max_width_m`` (the grip's span) and ``gripper.target_force_n`` (the most a
        discrete grasp may ask for, and its default).
    force_n : float, optional
        The discrete grasp's force; ``gripper.target_force_n`` by default.
    follow_rate_hz : float
        How often ``follow`` goes out while enable is held.
    clock : callable
        Monotonic seconds.

    Raises
    ------
    ValueError
        ``force_n`` is not in (0, gripper.target_force_n], or the rate is not positive.
    """

    def __init__(self, link: Link, device: InputDevice, settings: Settings, *, force_n: float | None = None,
                 follow_rate_hz: float = FOLLOW_RATE_HZ, clock: Callable[[], float] = time.monotonic):
        limit = settings.gripper.target_force_n
        force = limit if force_n is None else float(force_n)
        if not (math.isfinite(force) and 0 < force <= limit):
            raise ValueError(f"force {force_n!r} N: expected a force in (0, {limit:g}] N, the settings' "
                             "maximum grasp force (gripper.target_force_n)")
        if not (math.isfinite(follow_rate_hz) and follow_rate_hz > 0):
            raise ValueError(f"follow_rate_hz = {follow_rate_hz!r}: expected a rate > 0")
        self.link = link
        self.device = device
        self.settings = settings
        self.max_width_m = settings.gripper.max_width_m
        self.force_n = force
        self.period_s = 1.0 / follow_rate_hz
        self.clock = clock
        self.quit = False
        self._session = datetime.now().strftime("%H%M%S")
        self._count = 0
        self._enable = False
        self._release_left = 0  # enable=False follows still to send
        self._next_follow_s = -math.inf
        self._follow_grasp: str | None = None  # the follow grasp's id, until it ends
        self._rearm = False  # follows suspended until the enable is let go and held again
        self._discrete_grasp: str | None = None
        self._input: Any = None
        self._target_m: float | None = None
        self._pressed: list[str] = []  # buttons pushed from another thread (press())
        self._to_label: list[tuple[str, Any]] = []  # (grasp id, ObjectLabel) from another thread (label())
        self._labels: dict[str, Mapping[str, Any]] = {}  # grasp id -> the label body sent
        self._last_grasp: str | None = None  # the last grasp seen or commanded (what a label names after "next")
        self._lock = threading.Lock()
        self._last_action = ""
        self._problem = ""
        self._log: list[str] = []
        self.status = self._status()

    # ------------------------------------------------------------------ from other threads

    def press(self, button: str) -> None:
        """Press ``button`` (one of :data:`teleop.operator.BUTTONS`) as if on the device; any thread."""
        if button not in BUTTONS:
            raise ValueError(f"button {button!r}: expected one of {', '.join(BUTTONS)}")
        with self._lock:
            self._pressed.append(button)

    def label(self, grasp_id: str, label: Any) -> None:
        """Send ``label`` (a :class:`teleop.labels.ObjectLabel`) for grasp ``grasp_id`` on the next step;
        any thread. The loop's status then holds it (:attr:`LoopStatus.labels`)."""
        if not grasp_id:
            raise ValueError("a label needs the id of the grasp it names")
        with self._lock:
            self._to_label.append((grasp_id, label))

    def set_force(self, force_n: float) -> float:
        """Set the discrete grasp's force, clipped to [1 N, gripper.target_force_n]; the force set. Any thread."""
        limit = self.settings.gripper.target_force_n
        self.force_n = min(max(float(force_n), min(1.0, limit)), limit)
        return self.force_n

    # ------------------------------------------------------------------ the loop

    def step(self, timeout_s: float = 0.0) -> LoopStatus:
        """Read the device, act on its buttons, send ``follow`` when due, take what the bus
        brought (waiting up to ``timeout_s``), feed the robot's state back; the new status."""
        try:
            reading = self.device.read(timeout_s=0.0)
        except ComplianceTeleopError as exc:
            self._trouble(f"input device: {exc}")
            reading = None
        with self._lock:
            pressed, self._pressed = self._pressed, []
            to_label, self._to_label = self._to_label, []
        if reading is not None:
            self._input = reading
            pressed = [*pressed, *(b for b in BUTTONS if b in reading.buttons)]
            # The grip and enable first: a release pressed as the enable is let go goes out after
            # the follow that lets it go.
            self._drive(reading)
        for button in pressed:
            self._button(button)
        for grasp_id, label in to_label:
            self._send_label(grasp_id, label)
        try:
            self.link.poll(timeout_s)
        except ComplianceTeleopError as exc:
            self._trouble(f"bus: {exc}")
        self._track()
        self._feel()
        self.status = self._status()
        return self.status

    def run(self, stop: threading.Event | None = None, *, duration_s: float | None = None,
            on_status: Callable[[LoopStatus], None] | None = None) -> LoopStatus:
        """Step until ``quit`` is pressed, ``stop`` is set or ``duration_s`` passed, then :meth:`finish`;
        ``on_status`` sees the status after every step."""
        deadline = None if duration_s is None else self.clock() + duration_s
        while not self.quit and not (stop is not None and stop.is_set()):
            now = self.clock()
            if deadline is not None and now >= deadline:
                break
            wait = IDLE_TICK_S
            if self._enable or self._release_left:
                wait = min(wait, max(0.0, self._next_follow_s - now))
            status = self.step(timeout_s=wait)
            if on_status is not None:
                on_status(status)
        self.finish()
        return self.status

    def finish(self) -> None:
        """The dead-man let go on the way out: a follow with enable=False if the loop was driving."""
        if self._enable or self._release_left:
            self._send(lambda: self.link.follow(self._target_m or self.max_width_m, enable=False,
                                                grasp_id=self._follow_grasp))
            self._enable, self._release_left = False, 0
        self.status = self._status()

    # ------------------------------------------------------------------ pieces

    def _new_grasp_id(self) -> str:
        self._count += 1
        return f"op-{self._session}-{self._count:03d}"

    def _button(self, button: str) -> None:
        view = self.link.view
        current = self._follow_grasp or self._discrete_grasp or view.grasp_id
        if button == "grasp":
            grasp_id = self._new_grasp_id()
            if self._send(lambda: self.link.start_grasp(target_force_n=self.force_n, grasp_id=grasp_id)):
                self._discrete_grasp = grasp_id
                self._act(f"grasp {grasp_id} at {self.force_n:g} N")
        elif button == "release":
            if self._send(lambda: self.link.release(current)):
                self._act(f"release {current or ''}".rstrip())
            self._suspend()
        elif button == "stop":
            if self._send(lambda: self.link.stop(current)):
                self._act(f"stop {current or ''}".rstrip())
            self._suspend()
        elif button == "next":
            self._suspend()
            if view.grasp_id is not None and view.phase in ("loading", "loaded"):
                self._send(lambda: self.link.release(view.grasp_id))
            self.link.clear()
            self._follow_grasp = self._discrete_grasp = None
            self._act("next object: ready")
        elif button == "quit":
            self.quit = True
            self._act("quit")

    def _send_label(self, grasp_id: str, label: Any) -> None:
        sent = self._send(lambda: self.link.label(grasp_id, label.object_name, modulus_pa=label.modulus_pa,
                                                  source=label.source, detail=label.detail))
        if sent:
            self._labels = {**self._labels, grasp_id: label.body(grasp_id)}
            value = "the catalogue's E" if label.modulus_pa is None else f"E {label.modulus_pa:.3g} Pa"
            self._act(f"label {grasp_id}: {label.object_name}, {value} ({label.source})")

    def _drive(self, reading: Any) -> None:
        now = self.clock()
        self._target_m = grip_to_width_m(reading.grip, max_width_m=self.max_width_m)
        held = bool(reading.enable)
        if self._rearm and not held:
            self._rearm = False
        enable = held and not self._rearm  # after a stop or release: not until held anew
        if enable and not self._enable:
            if self._follow_grasp is None:
                self._follow_grasp = self._new_grasp_id()
                self._act(f"follow {self._follow_grasp}: enable held")
            self._next_follow_s = now  # the first one at once
        elif self._enable and not enable:
            self._release_left = RELEASE_FOLLOWS
            self._next_follow_s = now
            if not self._rearm:
                self._act("enable let go")
        self._enable = enable
        if not (enable or self._release_left or self._follow_live()) or now < self._next_follow_s:
            return
        target = self._target_m
        grasp_id = self._follow_grasp
        self._send(lambda: self.link.follow(target, enable=enable, grasp_id=grasp_id))
        if not enable and self._release_left:
            self._release_left -= 1
        # Keep the rate; after a stall, start again from now rather than sending a burst.
        self._next_follow_s = max(self._next_follow_s + self.period_s, now + 0.5 * self.period_s)

    def _follow_live(self) -> bool:
        """Whether the robot runs this loop's follow grasp: while it does, follows go on without
        the enable (they stop nothing more), so that its watchdog tells a dead console from a
        paused operator."""
        if self._follow_grasp is None:
            return False
        view = self.link.view
        robot = view.robot or {}
        if robot.get("grasp_id") == self._follow_grasp and robot.get("mode") in ("following", "stopped"):
            return True
        return view.grasp_id == self._follow_grasp and view.phase in ("loading", "loaded")

    def _track(self) -> None:
        """Forget a grasp's id once the robot says it ended (the next enable starts another)."""
        view = self.link.view
        if view.phase == "ended" and view.grasp_id is not None:
            if view.grasp_id == self._follow_grasp:
                self._follow_grasp = None
                if self._enable:  # a new grasp only once the enable is let go and held again
                    self._suspend()
            if view.grasp_id == self._discrete_grasp:
                self._discrete_grasp = None

    def _suspend(self) -> None:
        """Send no more follows until the enable is let go and held again."""
        if self._enable:
            self._rearm = True
            self._act("let go of the enable to drive again")

    def _feel(self) -> None:
        view = self.link.view
        try:
            self.device.feel(force_n=view.force_n if view.force_n is not None else 0.0,
                             width_m=view.width_m if view.width_m is not None else self.max_width_m,
                             stiffness=view.stiffness)
        except ComplianceTeleopError as exc:
            self._trouble(f"input device: {exc}")

    def _send(self, send: Callable[[], None]) -> bool:
        try:
            send()
        except ComplianceTeleopError as exc:
            self._trouble(f"not sent: {exc}")
            return False
        return True

    def _act(self, what: str) -> None:
        self._last_action = what
        self._log = [*self._log[-19:], what]
        log.info("%s", what)

    def _trouble(self, what: str) -> None:
        if what != self._problem:
            log.warning("%s", what)
            self._log = [*self._log[-19:], what]
        self._problem = what

    def _status(self) -> LoopStatus:
        reading = self._input
        view = self.link.view
        current = self._follow_grasp or self._discrete_grasp or view.grasp_id
        if current is not None:
            self._last_grasp = current
        if self._rearm:
            mode = "follow suspended (let go of the enable)"
        elif self._enable:
            mode = "follow"
        elif self._discrete_grasp is not None:
            mode = "discrete"
        elif self._follow_live():
            mode = "follow (paused)"
        else:
            mode = "idle"
        return LoopStatus(
            view=view,
            grip=0.0 if reading is None else float(reading.grip),
            enable=self._enable,
            operator_force_n=None if reading is None else reading.force_n,
            target_width_m=self._target_m,
            mode=mode,
            grasp_id=self._follow_grasp or self._discrete_grasp,
            force_n=self.force_n,
            last_action=self._last_action,
            problem=self._problem,
            follows_sent=getattr(self.link, "follows_sent", 0),
            commands_sent=getattr(self.link, "commands_sent", 0),
            quit=self.quit,
            log=tuple(self._log),
            label_grasp_id=self._last_grasp,
            labels=self._labels,
        )

