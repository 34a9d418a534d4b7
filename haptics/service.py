"""The renderer service, from estimates on the bus to reports on the display.

It subscribes to the estimator's endpoint with latest-value delivery (``estimate`` and the
forwarded ``grasp_event``), feeds :class:`~haptics.renderer.HapticRenderer` (which owns the
mapping, smoothing, staleness, fading and the display's reconnection) and ticks it at
``tick_s`` between messages. It publishes heartbeats on its own endpoint (``bus.display_pub``).

A grasp's end reaches it only through the estimator, which forwards the robot node's
``grasp_event`` *end* after the grasp's final estimate (the robot's own end comes before that
final, which the renderer would then ignore). So when the estimator that sent the estimate rendered, once
heard with a heartbeat period, goes unheard for three of its periods, the display fades to free:
no one vouches for the value held, which would otherwise press on the operator's next grasp. A
grasp that had its final estimate ends there (no end can come for it). One still loading is only
released: should its estimator be heard again (it was starved, not gone), its next estimate
engages the display again; one restarted mid-grasp refuses the grasp at its end (a final with no
estimate) and forwards that end, as after any grasp.

What it renders
---------------
Every time the renderer writes a report to the display (a changed command, or a keep-alive
every ``keepalive_s``), the service publishes one ``display`` message on that endpoint
(latest value; :mod:`teleop.bus.wire` has the schema): the grasp rendered (nil when idle),
the renderer's phase, the percept as numbers (``stiffness`` as a fraction of the display's
range, ``uncertainty_decades``, the ``rigid``, ``unknown`` and ``provisional`` flags), the
modulus the stiffness stands for on the display's range (``E_pa``, nil when free or
unknown) and the ``level`` written of ``level_max``, and what the display itself says it
does: ``device_state`` and ``device_faults`` from its latest status report (nil before one was
read since it connected), so a display whose actuator a fault disabled reads ``fault`` (level 0
in truth) whatever level was written. ``t_capture_s`` is the time of the write on the service's
clock. A session log therefore holds what the operator felt. A message that cannot be published
is logged and dropped: publishing never stops rendering.

Device status
-------------
After every renderer call the service takes, without waiting, the status reports the display
sent since (haptics/PROTOCOL.md, INPUT report 0x03). A change of its trouble (a ``fault`` or
``watchdog`` state, or fault bits) is logged once, as a warning, and so is its clearing; a
report that does not decode is logged (the first, then a count at every power of ten) and
skipped, the link kept. A display that is not connected has no status (nil again until its next
report after a reconnect).

Latency
-------
For every FINAL estimate it records the end-to-end latency: from the capture of the last
loading frame (the message's ``t_capture_s``) to the completion of the first display report
written after the estimate arrived, both on this host's monotonic clock (the robot node runs
on the same host in the demo; across hosts the figure is meaningless), and what the display
renders for it: the percept the estimate maps to (``display_fraction`` of the display's range,
1 = the stiff end, the ``rigid`` and ``unknown`` flags, the interval's width in decades) and its
``level`` of ``level_max``, the level the display settles on. One JSON object per final estimate goes
to ``report``. A latency outside :data:`PLAUSIBLE_LATENCY_S` is no latency (a capture time on
another clock, or a broken one): it is logged (the first, then a count at every power of ten),
counted (``unmeasured``) and left out, as null; the estimate is rendered all the same. A final
estimate whose grasp stops being rendered (its end, a release, another grasp's estimate, the
service stopping) before any report was written after it (the display was not connected) was
never shown: it is logged and reported as not shown, ``latency_ms`` and ``level`` null
(``display_fraction`` and the flags still say what it maps to), with the estimates its grasp had
by then; the first is logged, then a count at every power of ten (``not_shown``). ``stats.finals`` keeps the last :data:`KEPT_FINALS`
finals (``stats.final_estimates`` counts them all); the report has each one.

An estimate the renderer cannot take (the wire accepted it, the mapping does not) is skipped and
counted (``bad_messages``); the first is logged, then a count at every power of ten.
"""

from __future__ import annotations

import logging
import math
import time
from collections import deque
from collections.abc import Callable, Hashable
from dataclasses import dataclass, field
from typing import Any

import zmq

from haptics.errors import DisplayError, DisplayNotConnectedError, HapticsError, ProtocolError
from haptics.mapping import FREE, EstimateUpdate, Percept, modulus_from_fraction, to_command
from haptics.protocol import FAULT_BITS, DeviceStatus, StiffnessCommand
from haptics.renderer import HapticRenderer
from teleop.bus.pubsub import Publisher, Subscriber, is_decade
from teleop.bus.wire import Message
from teleop.errors import BusError, ComplianceTeleopError
from teleop.live import JsonLines, ServiceLoop

__all__ = ["INPUT_TOPICS", "KEPT_FINALS", "PLAUSIBLE_LATENCY_S", "FinalLatency", "RendererService", "check_tick_s"]

log = logging.getLogger(__name__)

INPUT_TOPICS = ("estimate", "grasp_event")
_COUNTED_GRASPS = 16  # grasps whose estimates are counted at once: more only when their ends were lost
# Capture to report (s) on one host's monotonic clock: a camera stamps at most 1 s late
# (sensors' camera_latency_s), and no final comes an hour after its last loading frame.
PLAUSIBLE_LATENCY_S = (-1.0, 3600.0)
#: Finals kept in ``stats.finals`` (and the ``--json`` summary's ``finals``): the last ones; a long run's
#: report has each, and ``stats.final_estimates`` counts them all.
KEPT_FINALS = 1000
_STATUS_READS = 64  # most status reports taken at once: the display sends one per report written
_TROUBLE_STATES = ("fault", "watchdog")  # device states logged (haptics/PROTOCOL.md)


def check_tick_s(tick_s: float, *, keepalive_s: float, heartbeat_s: float | None, name: str = "tick_s =") -> None:
    """Refuse a tick longer than the shortest period the service must keep between two messages:
    the display's keep-alive (``[display] keepalive_s``) and, when it publishes, its heartbeat
    (``[bus] heartbeat_s``). A longer wait for a message would starve them (the display's watchdog
    setting it free, subscribers taking the renderer for dead) and overrun a run's duration.

    Raises
    ------
    HapticsError
        ``tick_s`` is longer (named with ``name``, and the settings it must keep).
    """
    periods = {"[display] keepalive_s": keepalive_s}
    if heartbeat_s is not None:
        periods["[bus] heartbeat_s"] = heartbeat_s
    longest = min(periods.values())
    if tick_s > longest:
        kept = ", ".join(f"{key} = {value:g} s" for key, value in periods.items())
        raise HapticsError(f"{name} {tick_s:g}: longer than a period the renderer must keep ({kept}); "
                           f"expected at most {longest:g} s")


@dataclass(frozen=True)
class FinalLatency:
    """A final estimate as the display got it: latency from the last loading frame to the report
    (None when not measured or never shown: module docstring), and what the display renders for it
    (``percept``; ``level`` of ``level_max``, None before a display was connected and when the final
    was never shown)."""

    grasp_id: str
    state: str
    e_pa: float | None
    latency_s: float | None
    estimates_received: int
    percept: Percept = FREE
    level: int | None = None
    level_max: int | None = None

    def to_json(self) -> dict[str, Any]:
        return {"grasp_id": self.grasp_id, "state": self.state, "E_pa": self.e_pa,
                "latency_ms": None if self.latency_s is None else self.latency_s * 1e3,
                "estimates_received": self.estimates_received,
                "display_fraction": self.percept.stiffness, "rigid": self.percept.rigid,
                "unknown": self.percept.unknown, "uncertainty_decades": self.percept.uncertainty_decades,
                "level": self.level, "level_max": self.level_max}


@dataclass
class _Pending:
    """A final estimate waiting for the report that shows it."""

    grasp_id: str
    update: EstimateUpdate
    reports_before: int
    percept: Percept
    estimates_received: int  # its grasp's, the final included: the count goes with the grasp's end


@dataclass
class ServiceStats:
    estimates: int = 0
    bad_messages: int = 0
    grasp_ends: int = 0
    display_messages: int = 0  # ``display`` messages published, one per report written
    display_failures: int = 0  # reports whose ``display`` message could not be published
    ignored: int = 0  # estimates of grasps that had ended or had their final (late, or replayed)
    unmeasured: int = 0  # finals whose latency was left out: outside PLAUSIBLE_LATENCY_S
    not_shown: int = 0  # finals never shown: their grasps were no longer rendered before a report went out
    final_estimates: int = 0  # finals recorded (reported), all of them
    #: The last :data:`KEPT_FINALS` finals recorded, the oldest first (the report has each one).
    finals: deque[FinalLatency] = field(default_factory=lambda: deque(maxlen=KEPT_FINALS))

    def as_dict(self) -> dict[str, Any]:
        """The counts, and ``finals``: the last :data:`KEPT_FINALS` finals (``final_estimates`` counts them all;
        the service's ``report`` has each one)."""
        return {"estimates": self.estimates, "bad_messages": self.bad_messages, "grasp_ends": self.grasp_ends,
                "display_messages": self.display_messages, "display_failures": self.display_failures,
                "ignored": self.ignored, "unmeasured": self.unmeasured, "not_shown": self.not_shown,
                "final_estimates": self.final_estimates, "finals": [f.to_json() for f in self.finals]}


class RendererService(ServiceLoop):
    """Drives a :class:`HapticRenderer` from a bus subscription (see the module docstring).

    Parameters
    ----------
    renderer : HapticRenderer
    subscriber : Subscriber
        Latest-value subscription to :data:`INPUT_TOPICS` on the estimator's endpoint.
    publisher : Publisher, optional
        Where heartbeats and ``display`` messages go (latest value, ``source`` should be
        ``"renderer"``).
    report : JsonLines, optional
        Receives one JSON object per final estimate.
    tick_s : float
        Longest time between renderer ticks (smoothing, fading, keep-alive): at most the display's
        ``keepalive_s`` and the publisher's ``heartbeat_s`` (:func:`check_tick_s`).
    clock : callable
        Monotonic seconds, the clock the robot stamps captures with.
    """

    def __init__(self, renderer: HapticRenderer, *, subscriber: Subscriber, publisher: Publisher | None = None,
                 report: JsonLines | None = None, tick_s: float = 0.01,
                 clock: Callable[[], float] = time.monotonic):
        if isinstance(tick_s, bool) or not isinstance(tick_s, int | float) or not (
                math.isfinite(tick_s) and tick_s > 0):
            raise HapticsError(f"tick_s = {tick_s!r}: expected a finite number of seconds > 0")
        check_tick_s(tick_s, keepalive_s=renderer.settings.keepalive_s,
                     heartbeat_s=None if publisher is None else publisher.heartbeat_s)
        self.renderer = renderer
        self.subscriber = subscriber
        self.publisher = publisher
        self.report = report or JsonLines(None)
        self.tick_s = tick_s
        self.clock = clock
        self.stats = ServiceStats()
        self._received: dict[str, int] = {}
        self._pending: _Pending | None = None
        self._reports_published = renderer.stats.reports_sent
        self._last_grasp: Hashable = None  # the grasp active last: the one a fade renders
        self._publish_failing = False
        self._estimates_from = ""  # the source of the last estimate rendered: whose death ends its grasp
        self._device_status: DeviceStatus | None = None  # the display's latest status report
        self._trouble_said: tuple[str, frozenset[str]] | None = None  # the device trouble logged last
        self._bad_status = 0  # status reports that did not decode
        self._written: StiffnessCommand | None = None  # the command of the last report written

    def step(self) -> Message | None:
        """Wait up to ``tick_s`` for a message and handle it; tick the renderer; heartbeat."""
        if self.publisher is not None:
            self.publisher.heartbeat_if_due(self.clock())
        message = self.subscriber.recv(timeout_s=self.tick_s)
        if message is not None:
            self.handle(message)
        self._check_estimator()
        self.renderer.tick(self.clock())
        written_s = self.clock()  # before the display message goes out: the latency ends at the report
        self._publish_display()
        self._check_pending(written_s)
        return message

    def finish(self) -> None:
        """Before the service stops (a stop signal, the duration over): set the display free.

        A renderer stopped mid-grasp (or mid-fade) last wrote a stiffness, which the display would
        hold until its own watchdog (or for ever, one with none); so the free command (level 0, as
        the idle renderer writes) goes to the display, and the matching ``display`` message (idle,
        no grasp) on the bus. A display that is not connected, or whose write fails, is left alone
        (logged): nothing more can reach it. A final still waiting for a report to show it is
        reported as never shown."""
        self._check_pending(self.clock(), stopping=True)
        renderer, display = self.renderer, self.renderer.display
        info = display.info
        if info is None:
            return
        free = to_command(FREE, level_max=int(info.level_max))
        if not display.connected:
            last = self._written or display.last_command
            if last is not None and (last.level > 0 or last.rigid):
                watchdog = f"watchdog_ms = {info.watchdog_ms}" if info.watchdog_ms else "it has none"
                log.warning("%s: not connected on stopping, so not set free: it may hold the last level written, "
                            "%d of %d, until its own watchdog (%s)", display, last.level, info.level_max, watchdog)
            else:
                log.info("%s: not connected on stopping, so not set free (the last level written was 0)", display)
            return
        if renderer.phase == "idle" and display.last_command in (None, free):
            return
        try:
            display.write_command(free)
        except (DisplayError, OSError) as exc:
            log.warning("%s: not set free on stopping: %s", display, exc)
            return
        self._read_status()  # its answer to the free command
        if self.publisher is None:
            return
        body = {"grasp_id": None, "phase": "idle", "stiffness": 0.0, "uncertainty_decades": 0.0, "rigid": False,
                "unknown": False, "provisional": False, "E_pa": None, "level": int(free.level),
                "level_max": int(info.level_max), **self._device_fields()}
        try:
            self.publisher.send("display", t_capture_s=self.clock(), **body)
        except (ComplianceTeleopError, zmq.ZMQError) as exc:
            self.stats.display_failures += 1
            log.warning("display message (free, on stopping) not published: %s", exc)
            return
        self.stats.display_messages += 1

    def handle(self, message: Message) -> None:
        """Take one estimate or grasp event; one that cannot be rendered is logged and skipped."""
        try:
            if message.type == "grasp_event":
                event = message.fields
                if event.event == "end":
                    self.renderer.on_grasp_end(event.grasp_id, self.clock())
                    self.stats.grasp_ends += 1
                    self._check_pending(self.clock())  # a final never shown is recorded so now
                    self._received.pop(event.grasp_id, None)
                return
            if message.type != "estimate":
                return
            update = EstimateUpdate.from_estimate(message.fields, message.t_capture_s)
            reports_before = self.renderer.stats.reports_sent
            ignored_before = self.renderer.stats.estimates_ignored
            self.renderer.on_estimate(update, self.clock())
            written_s = self.clock()
        except HapticsError as exc:
            self.stats.bad_messages += 1
            count = self.stats.bad_messages
            if count == 1:
                log.warning("estimate from %s (seq %d) not rendered: %s; further ones are counted, not each "
                            "logged", message.source or "?", message.seq, exc)
            elif is_decade(count):  # the 10th, 100th, ... as the bus logs its refusals
                log.warning("%d estimates not rendered so far, the last from %s (seq %d): %s", count,
                            message.source or "?", message.seq, exc)
            return
        finally:
            self._publish_display()  # for a report written on the estimate or the grasp's end
        self.stats.estimates += 1
        self._check_pending(written_s)  # before another grasp's final takes its place
        if self.renderer.stats.estimates_ignored != ignored_before:
            self.stats.ignored += 1
            return  # not counted: a late estimate of an ended grasp would keep its count for good
        self._estimates_from = message.source
        self._received[update.grasp_id] = self._received.pop(update.grasp_id, 0) + 1  # the newest last
        if len(self._received) > _COUNTED_GRASPS:  # grasps whose end never came: the oldest goes
            del self._received[next(iter(self._received))]
        if not update.provisional:
            self._pending = _Pending(update.grasp_id, update, reports_before, self.renderer.target,
                                     self._received[update.grasp_id])
            self._check_pending(written_s)

    def _check_estimator(self) -> None:
        """Set the display free when the estimator that sent what it renders is heard dead, ending the
        grasp if its final was in (module docstring); one never heard with a heartbeat period cannot
        be judged, and is left alone."""
        grasp_id = self.renderer.grasp_id
        if grasp_id is None or self.subscriber is None:
            return
        heartbeat = self.subscriber.heartbeat  # on its own clock: it stamped when each peer was heard
        if heartbeat.last_seen_s(self._estimates_from) is None:  # handed in, not heard (a replay, a test)
            return
        try:
            alive = heartbeat.is_alive(self._estimates_from)
        except BusError:  # heard, but no heartbeat period announced
            return
        if alive:
            return
        if self.renderer.has_final:
            log.warning("the estimator (%s) is unheard: grasp %s ends here, as its end cannot come",
                        self._estimates_from or "?", grasp_id)
            self.renderer.on_grasp_end(grasp_id, self.clock())
            self._received.pop(grasp_id, None)
        else:
            log.warning("the estimator (%s) is unheard mid-grasp: the display is set free until it renders "
                        "grasp %s again", self._estimates_from or "?", grasp_id)
            self.renderer.release(self.clock())
        self._publish_display()

    def _display_body(self) -> dict[str, Any]:
        """The body of a ``display`` message for what the renderer shows now (see the module docstring)."""
        renderer = self.renderer
        percept, phase = renderer.percept, renderer.phase
        grasp_id = {"idle": None, "fading": self._last_grasp}.get(phase, renderer.grasp_id)
        e_pa = None
        if percept.stiffness > 0 and not percept.unknown:
            e_pa = modulus_from_fraction(float(percept.stiffness), e_soft_pa=renderer.settings.e_soft_pa,
                                         e_rigid_pa=renderer.settings.e_rigid_pa)
        info, command = renderer.display.info, renderer.command
        level_max = None if info is None else int(info.level_max)
        level = None if command is None or level_max is None else int(command.level)
        return {"grasp_id": None if grasp_id is None else str(grasp_id), "phase": phase,
                "stiffness": float(percept.stiffness), "uncertainty_decades": float(percept.uncertainty_decades),
                "rigid": bool(percept.rigid), "unknown": bool(percept.unknown),
                "provisional": bool(percept.provisional), "E_pa": e_pa, "level": level, "level_max": level_max,
                **self._device_fields()}

    def _device_fields(self) -> dict[str, str | None]:
        """``device_state`` and ``device_faults`` of a ``display`` message: the latest status's."""
        status = self._device_status
        if status is None:
            return {"device_state": None, "device_faults": None}
        return {"device_state": status.state,
                "device_faults": ",".join(name for name in FAULT_BITS if name in status.faults)}

    def _read_status(self) -> None:
        """Take the status reports the display sent since the last call, without waiting; log a change of
        its trouble (module docstring). A report that does not decode is logged and skipped."""
        display = self.renderer.display
        for _ in range(_STATUS_READS):
            if not display.connected:
                self._device_status = None  # until its next report says what it does
                return
            try:
                status = display.read_status(timeout_s=0)
            except ProtocolError as exc:
                self._bad_status += 1
                if self._bad_status == 1:
                    log.warning("%s: a status report skipped: %s; further ones are counted, not each logged",
                                display, exc)
                elif is_decade(self._bad_status):
                    log.warning("%s: %d status reports skipped so far, the last: %s", display, self._bad_status, exc)
                continue
            except DisplayNotConnectedError:  # closed meanwhile
                self._device_status = None
                return
            except DisplayError as exc:  # the link failed: the renderer reconnects it
                log.warning("%s: status read failed (%s); reconnecting", display, exc)
                self._device_status = None
                return
            if status is None:
                return
            self._device_status = status
            trouble = (status.state, status.faults) if (
                status.state in _TROUBLE_STATES or status.faults) else None
            if trouble != self._trouble_said:
                if trouble is not None:
                    faults = ", ".join(name for name in FAULT_BITS if name in status.faults) or "none"
                    log.warning("%s reports state %s, level %d, faults: %s", display, status.state, status.level,
                                faults)
                else:
                    log.info("%s reports state %s again, no faults (was %s)", display, status.state,
                                self._trouble_said[0])
                self._trouble_said = trouble

    def _publish_display(self) -> None:
        """Publish one ``display`` message if the renderer wrote a report since the last one.

        Called right after each renderer call, so the renderer's state is what that report
        carried; the display's status reports are taken first (:meth:`_read_status`). A failure
        is logged (once per run of failures) and counted; it never reaches the rendering.
        """
        self._read_status()
        if self.renderer.grasp_id is not None:
            self._last_grasp = self.renderer.grasp_id
        sent = self.renderer.stats.reports_sent
        if sent == self._reports_published:
            return
        self._reports_published = sent
        self._written = self.renderer.command
        if self.publisher is None:
            return
        try:
            self.publisher.send("display", t_capture_s=self.clock(), **self._display_body())
        except (ComplianceTeleopError, zmq.ZMQError) as exc:
            self.stats.display_failures += 1
            if not self._publish_failing:
                log.warning("display message not published (rendering goes on): %s", exc)
            self._publish_failing = True
            return
        if self._publish_failing:
            log.info("display messages published again after %d failure(s)", self.stats.display_failures)
        self._publish_failing = False
        self.stats.display_messages += 1

    def _check_pending(self, written_s: float, *, stopping: bool = False) -> None:
        """Record the pending final estimate's latency once a report went out after it (``written_s``:
        the clock just after the renderer call that may have written it), or as never shown once its
        grasp is no longer rendered with none gone out (module docstring), or the service is ``stopping``."""
        pending = self._pending
        if pending is None:
            return
        shown = self.renderer.grasp_id == pending.grasp_id
        if shown and self.renderer.stats.reports_sent == pending.reports_before:
            if not stopping:
                return
            shown = False  # the service stops before any report showed it
        update = pending.update
        info = self.renderer.display.info
        level_max = None if info is None else info.level_max
        if not shown:
            self.stats.not_shown += 1
            count, connected = self.stats.not_shown, "connected" if self.renderer.display.connected else "not connected"
            if count == 1:
                log.warning("grasp %s: its final estimate (E %s Pa, %s) was never shown: no report reached the "
                            "display (%s) before the grasp was no longer rendered; further ones are counted, not "
                            "each logged", pending.grasp_id, update.value_pa, update.state, connected)
            elif is_decade(count):
                log.warning("%d final estimates never shown so far (no report reached the display before their "
                            "grasps were no longer rendered), the last grasp %s's (display %s)", count,
                            pending.grasp_id, connected)
            self._record(pending, latency_s=None, level=None, level_max=level_max)
            return
        level = None if level_max is None else to_command(pending.percept, level_max=level_max).level
        latency_s = written_s - update.t_s
        low, high = PLAUSIBLE_LATENCY_S
        if not low <= latency_s <= high:
            # Not refused: the value is sound and already shown; only its capture time cannot be read here.
            self.stats.unmeasured += 1
            count = self.stats.unmeasured
            if count == 1:
                log.warning("grasp %s: final estimate captured at %.6f s, a latency of %.3g s on this clock, "
                            "outside %g..%g s: a capture time on another clock or a broken one; its latency is "
                            "left out, and further ones are counted, not each logged", pending.grasp_id,
                            update.t_s, latency_s, low, high)
            elif is_decade(count):  # the 10th, 100th, ... as the bus logs its refusals
                log.warning("%d final estimates' latencies left out so far (outside %g..%g s), the last grasp %s's "
                            "(%.3g s)", count, low, high, pending.grasp_id, latency_s)
            latency_s = None
        self._record(pending, latency_s=latency_s, level=level, level_max=level_max)

    def _record(self, pending: _Pending, *, latency_s: float | None, level: int | None,
                level_max: int | None) -> None:
        """Report the pending final estimate, and forget it."""
        update = pending.update
        final = FinalLatency(grasp_id=str(pending.grasp_id), state=update.state, e_pa=update.value_pa,
                             latency_s=latency_s, estimates_received=pending.estimates_received,
                             percept=pending.percept, level=level, level_max=level_max)
        self.stats.finals.append(final)  # the oldest beyond KEPT_FINALS goes
        self.stats.final_estimates += 1
        self.report.write(final.to_json())
        self._pending = None
