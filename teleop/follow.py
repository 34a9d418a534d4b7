"""Follow grasps: the robot node's leader-follower handling (:class:`Follower`).

The operator drives a grasp continuously with ``follow`` messages (also on ``bus.command``,
about :data:`~teleop.operator.FOLLOW_RATE_HZ`): the fingers follow the message's target width,
force-capped (:mod:`teleop.operator`). A follow counts only with ``enable`` (the dead-man) held:

* while idle, it starts a *follow grasp* (``grasp_id`` names it, default ``grasp-<n>``; a grasp
  that has ended, commanded or followed, one of the last :data:`ENDED_KEPT`, is not started
  again, nor is one a ``release`` cancelled while it prepared). With the simulated backends the node simulates the
  scene's next object live (:mod:`teleop.sim.live`, prepared ahead in its simulator thread: at
  start for the first object, after each grasp for the next; the fingers may move once it is
  ready) and the simulated devices sample it (:mod:`teleop.devices.live_sim`); an object still
  between the closed fingers (a grasp ended by the watchdog) is grasped again, unless a
  ``release`` opened them meanwhile (the object then leaves, and the scene's next one comes);
* during a follow grasp it moves the fingers' target (:meth:`~teleop.devices.gripper.Gripper.follow`).
  It must name that grasp: a follow naming another grasp or none (another operator's) is refused
  and counts for nothing, neither moving the fingers nor keeping the grasp from the watchdog.
  The fingers never exceed the settings' maximum grasp force (``gripper.target_force_n``): the
  simulated physics stalls there; with hardware the node stops closing once the load cell
  reads it (checked on each follow and, while the fingers close, on each node step between follows), and
  not at all while the load cell is silent (no force for
  :data:`FORCE_SILENT_S`: a ``robot_notice`` *refused* says so). Reaching it sends a
  ``robot_notice`` *force_limit*, once per grasp.

A follow without enable stops the fingers where they are (while the grasp is preparing: it
clears the target, so going live moves nothing). When no follow came for
:data:`~teleop.operator.WATCHDOG_S`, the node stops the fingers, sends a ``robot_notice``
*watchdog* and ends the grasp (mode *stopped*); so too when the node itself did not look for
commands for that long (stopped, starved of CPU): the follows that queued meanwhile are refused,
not taken in one go. ``release`` ends a follow grasp: the fingers
open, then the grasp ends; with no grasp open it opens fingers the watchdog left closed on an
object; a grasp still preparing is cancelled instead (a ``robot_notice`` *refused* says the
fingers had nothing to open). ``stop`` stops the fingers and ignores further follows until
``release`` (or the watchdog) ends the grasp; a grasp still preparing then never goes live.

A follow that cannot be carried out (during a scripted grasp, naming another grasp, beyond the
gripper's width, ...) raises; the node answers it with a ``robot_notice`` *refused*
(:mod:`teleop.node`).
"""

from __future__ import annotations

import itertools
import logging
import math
from concurrent.futures import Future
from typing import TYPE_CHECKING, Any

import numpy as np

from teleop.errors import DeviceError, InvalidCommandError, SimulationError
from teleop.operator import WATCHDOG_S

if TYPE_CHECKING:
    from teleop.node import RobotNode, _Grasp

__all__ = ["Follower"]

FORCE_SILENT_S = 0.1  # with hardware, the fingers close only on a force this fresh: 8 samples at the HX711's 80 Hz

# Grasps remembered as ended (commanded or followed). A follow or start_grasp naming one is
# refused rather than starting it again: the follows a console sends for its grasp after the
# watchdog or a release ended it (until its operator lets go of the enable), and those still in
# flight. Only the last few grasps' follows can still come, so this many ids (each at most the
# bus's 256 characters) are ample; the ids are the senders', and a sender making up new ones must
# not grow the node without end.
ENDED_KEPT = 1024

WATCHED = ("preparing", "following", "stopped")  # the follow grasp's phases the watchdog ends

log = logging.getLogger("teleop.node")  # the node's own logger, so filters on the node see the follower


class Follower:
    """The follow state of one :class:`~teleop.node.RobotNode` and what it does with follows.

    Holds the live object between the simulated fingers (``live``), the next one being prepared
    (``next_live``: its grasp number and the future of (LiveObject, rng)), when the operator's last
    follow came, the operator's enable, whether the watchdog stopped the node and the last
    :data:`ENDED_KEPT` grasps that ended.
    """

    def __init__(self, node: RobotNode):
        self.node = node
        self.live: Any = None
        self.next_live: tuple[int, Future] | None = None
        self.last_follow_s = -math.inf
        self.enable = False
        self.stopped = False  # mode "stopped" while no grasp runs: after the watchdog
        self.closing = False  # the hardware fingers were last driven closing: the cap watches them between follows
        # The last ENDED_KEPT grasps that ended, oldest first: never started again.
        self.ended: dict[str, None] = {}
        self._ids = itertools.count()  # for grasps started without an id

    # ------------------------------------------------------------------ commands

    def follow(self, grasp_id: str | None, target_width_m: float, enable: bool) -> None:
        """One follow message (module docstring); raises what makes it refused, before it changes
        anything: a refused follow neither feeds the watchdog nor sets the enable."""
        node = self.node
        grasp = node._grasp
        if grasp is not None and not grasp.follow:
            raise DeviceError(f"grasp {grasp.grasp_id!r} is a commanded grasp: the fingers cannot follow until it ends")
        # Another operator's follows, or follows naming no grasp, must not steer nor keep alive this one.
        if grasp is not None and grasp_id is None:
            raise DeviceError(f"grasp {grasp.grasp_id!r} is in progress: a follow must name it")
        if grasp is not None and grasp_id != grasp.grasp_id:
            raise DeviceError(f"grasp {grasp.grasp_id!r} is in progress, not {grasp_id!r}")
        max_width = node.settings.gripper.max_width_m
        if enable and target_width_m > max_width:
            raise InvalidCommandError(f"target_width_m = {target_width_m}: the fingers open to {max_width} m at most")
        if enable and grasp is None:
            grasp = self._start(grasp_id)
        self.last_follow_s = node.clock()
        self.enable = enable
        if not enable:
            if grasp is not None and grasp.phase in ("preparing", "following") and grasp.target_width_m is not None:
                if grasp.phase == "following":  # preparing: the fingers are not the grasp's yet
                    node.gripper.stop()
                    self.closing = False
                grasp.target_width_m = None  # nor does going live drive it
            return
        if grasp.phase not in ("preparing", "following"):
            return  # stopped or releasing: the operator's targets no longer move the fingers
        grasp.target_width_m = target_width_m
        if grasp.phase == "following":
            self._drive_fingers(grasp)

    def stop(self, grasp: _Grasp) -> None:
        """``stop`` during a follow grasp: further follows are ignored until it ends; one still
        preparing never goes live."""
        if grasp.phase in ("preparing", "following"):
            grasp.phase = "stopped"

    def release(self, grasp: _Grasp) -> None:
        """``release`` of a follow grasp: the fingers open, then the grasp ends; one that never
        went live is cancelled (it took no object, and the fingers have nothing to open)."""
        node = self.node
        if grasp.phase not in ("preparing", "following", "stopped"):
            raise DeviceError(f"follow grasp {grasp.grasp_id!r} is {grasp.phase}: nothing to release")
        if not _went_live(grasp):
            node._grasp = None
            self.record_ended(grasp.grasp_id)  # its console's follows, the enable still held, must not start it again
            node._notice("refused", "release", grasp.grasp_id,
                         f"follow grasp {grasp.grasp_id!r} had not started: cancelled, the fingers have nothing to open")
            return
        node.gripper.stop()
        grasp.phase = "releasing"
        grasp.motion = node.gripper.move_async(node.settings.gripper.max_width_m)

    def _start(self, grasp_id: str | None) -> _Grasp:
        from teleop.node import _Grasp

        node = self.node
        number = node._count
        grasp_id = self.grasp_id(grasp_id)
        self.stopped = self.closing = False
        grasp = node._grasp = _Grasp(grasp_id, None, follow=True, phase="following")
        if not node.simulated:
            node._announce("start")
        elif not self._let_go():  # the object is still between the fingers: grasp it again (no new object)
            grasp.object_name = self.live.object.name
            node._announce("start")
        else:  # the next object, taken once it is live (_go_live)
            if self.next_live is None or self.next_live[0] != number:
                self.prepare_next(number)
            grasp.phase, grasp.prepared = "preparing", self.next_live[1]
        return grasp

    def grasp_id(self, given: str | None) -> str:
        """The id of a grasp to start: ``given``, or for one started without an id ``grasp-<n>``;
        never that of a grasp that ended (:attr:`ended`).

        Raises
        ------
        DeviceError
            ``given`` names a grasp that ended.
        """
        if given and given in self.ended:
            raise DeviceError(f"grasp {given!r} has ended: name a new grasp to start one")
        while not given or given in self.ended:
            given = f"grasp-{next(self._ids):04d}"
        return given

    # ------------------------------------------------------------------ the live simulation

    def prepare_next(self, number: int | None = None) -> None:
        """Prepare the live object of grasp ``number`` (default: the next) in the simulator thread."""
        node = self.node
        number = node._count if number is None else number
        self.next_live = (number, node._simulator.submit(self._prepare_live, number))

    def _prepare_live(self, number: int) -> tuple[Any, np.random.Generator]:
        from teleop.sim.live import prepare_object

        node = self.node
        obj = node.objects[number % len(node.objects)]
        rng = np.random.default_rng(node.scene.seed * 10_000 + number)
        return prepare_object(obj, settings=node.settings, rng=rng), rng

    def _go_live(self, grasp: _Grasp) -> None:
        """The prepared object is ready: put it between the simulated fingers and start the grasp."""
        from teleop.devices.live_sim import LiveGrasp

        node = self.node
        self.next_live = None
        # Its object taken now: a grasp the watchdog ended while it was prepared took none, and one
        # that cannot be simulated is skipped.
        node._count += 1
        try:
            obj, rng = grasp.prepared.result()
        except SimulationError as exc:
            log.error("grasp %s cannot be simulated: %s", grasp.grasp_id, exc)
            node._notice("refused", "follow", grasp.grasp_id, f"the object cannot be simulated: {exc}")
            node._grasp = None
            self.prepare_next()
            return
        self.live = LiveGrasp(obj, settings=node.settings, rng=rng, width_m=node.gripper.read_width()[1],
                              clock=node.clock)
        for device in node._devices:
            device.live(self.live)
        grasp.object_name, grasp.phase = obj.name, "following"
        node._announce("start")
        if grasp.target_width_m is not None:
            self._drive_fingers(grasp)

    def grasp_ended(self, grasp: _Grasp) -> None:
        """A grasp ended: an object the fingers let go leaves them; the next one is prepared."""
        node = self.node
        self.record_ended(grasp.grasp_id)
        self._let_go()
        # The object prepared may be another grasp's (a commanded grasp took its number): the next one's is due.
        if node.simulated and self.live is None and (self.next_live is None or self.next_live[0] != node._count):
            self.prepare_next()

    def record_ended(self, grasp_id: str) -> None:
        """Follows and start_grasp commands naming ``grasp_id`` no longer start a grasp (:data:`ENDED_KEPT`)."""
        self.ended[grasp_id] = None
        if len(self.ended) > ENDED_KEPT:
            del self.ended[next(iter(self.ended))]

    def _let_go(self) -> bool:
        """Whether no live object is between the fingers: one they no longer press (let go, or opened
        by a ``release`` after the watchdog ended its grasp) leaves them now."""
        live = self.live
        if live is not None and live.force_at(self.node.clock()) <= 0:
            self.live = None
            for device in self.node._devices:
                device.live(None)
        return self.live is None

    # ------------------------------------------------------------------ progress

    def advance(self, grasp: _Grasp, now: float) -> bool:
        """Advance a follow grasp (watchdog, going live, force limit); False when nothing of
        this applies (the node's own progress then does)."""
        if grasp.phase in WATCHED and now - self.last_follow_s > WATCHDOG_S:
            self._watchdog(grasp)
        elif grasp.phase == "preparing" and grasp.prepared.done():
            self._go_live(grasp)
        elif grasp.phase == "following":
            if self.live is not None and self.live.at_force_limit():
                self._force_limit(grasp)
            elif self.closing and grasp.target_width_m is not None and self._cannot_close():
                self._drive_fingers(grasp)  # between follows: the fingers still closing stop now
        else:
            return False
        return True

    def _drive_fingers(self, grasp: _Grasp) -> None:
        """Move the fingers toward the grasp's target; with hardware, no closer once the load cell
        reads the maximum force, nor while it is silent (a force it does not read cannot be capped)."""
        from teleop.node import REFUSAL_REPEAT_S

        node = self.node
        closing = not node.simulated and grasp.target_width_m < node._latest.get("width", math.inf)
        why = self._cannot_close() if closing else None
        self.closing = closing and why is None
        if why == "silent":
            node.gripper.stop()
            node._notice("refused", "follow", grasp.grasp_id,
                         f"the load cell has sent no force for over {FORCE_SILENT_S} s: the fingers close no "
                         "further until it reads again", repeat_s=REFUSAL_REPEAT_S)
        elif why == "force_limit":
            node.gripper.stop()
            self._force_limit(grasp)
        else:
            node.gripper.follow(grasp.target_width_m)

    def _cannot_close(self) -> str | None:
        """Why hardware fingers must close no further: the load cell ``"silent"`` (a force it does not
        read cannot be capped) or at the maximum force (``"force_limit"``); None when they may."""
        node = self.node
        if node.clock() - node._newest_s.get("force", -math.inf) > FORCE_SILENT_S:
            return "silent"
        if node._latest.get("force", 0.0) >= node.settings.gripper.target_force_n:
            return "force_limit"
        return None

    def _force_limit(self, grasp: _Grasp) -> None:
        if not grasp.force_limited:
            grasp.force_limited = True
            self.node._notice("force_limit", "follow", grasp.grasp_id,
                              f"the fingers reached the maximum force {self.node.settings.gripper.target_force_n} N "
                              "and close no further")

    def stalled(self, stalled_s: float) -> None:
        """The node did not look for commands for ``stalled_s`` (over WATCHDOG_S: stopped, starved of
        CPU): the watchdog ends a follow grasp before the follows queued meanwhile move the fingers
        in one go (they name a grasp that ended, and are refused)."""
        grasp = self.node._grasp
        if grasp is not None and grasp.follow and grasp.phase in WATCHED:
            self._watchdog(grasp, f"the robot node itself stalled for {stalled_s:.3f} s")

    def _watchdog(self, grasp: _Grasp, why: str | None = None) -> None:
        """No follow came for WATCHDOG_S (or ``why``): stop the fingers and end the grasp. A stop the
        gripper fails is said too, and its DeviceError raised for the node to end the grasp."""
        node = self.node
        failed = None
        try:
            node.gripper.stop()
        except DeviceError as exc:  # the enable still goes and the watchdog still speaks: the node's own state
            failed = exc
        node.stats.watchdogs += 1
        why = why or f"no follow command for {node.clock() - self.last_follow_s:.3f} s"
        done = "the fingers stopped" if failed is None else f"stopping the fingers failed ({failed})"
        log.warning("grasp %s: %s: %s", grasp.grasp_id, why, done)
        node._notice("watchdog", "follow", grasp.grasp_id, f"{why} (watchdog {WATCHDOG_S} s): {done}")
        self.enable = self.closing = False
        self.stopped = True
        if failed is not None:
            raise failed  # the node's device notice names the grasp, then ends it as below
        if not _went_live(grasp):
            # No end goes out for it, but its console's stale follows must not start it again.
            self.record_ended(grasp.grasp_id)
            node._grasp = None
        else:
            node._end()


def _went_live(grasp: _Grasp) -> bool:
    """Whether the grasp's start event went out: one that never went live has no end either."""
    return grasp.started_s < math.inf
