"""The operator's loop: drives the gripper from an input device over an operator link.

The link is :class:`haptics.operator_link.OperatorLink` (the operator's side of the bus, described
there) or anything with its sending methods, ``poll`` and ``view``.

:class:`OperatorLoop` reads an operator input device (:mod:`haptics.inputs`) and turns it into
the link's messages, ``follow``, ``command`` and ``label`` (:meth:`OperatorLoop.step`; what it needs
of both and the status it shows: :mod:`haptics.operator_status`; the grasps it tracks:
:mod:`haptics.operator_grasps`):

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
* buttons: ``grasp`` starts a discrete grasp at the chosen force (one the robot refuses, as while
  another runs, is forgotten and the one running stays tracked), ``release`` opens the fingers,
  ``stop`` stops them where they are (both name this loop's grasp the robot runs,
  :func:`~haptics.operator_grasps.running`, not a grasp pressed since and not answered yet, else
  the one this loop drives or commanded last), ``next`` ends the grasp shown (releasing it unless the robot
  already does; refused, with a notice, while a discrete grasp of this loop is in progress that
  the view does not show yet: the operator releases it or waits for its end first)
  and, once the robot has ended it and its final estimate is in (an operator's grasp
  gets it only after its end; not awaited when no estimator is alive), clears the view for the next
  object (meanwhile the device is read but drives nothing, and of its buttons only quit acts: an
  enable held then drives once the view is cleared, so a simulated operator starts the next grasp
  only then),
  ``quit`` ends the loop, letting go of the enable and releasing a follow grasp the robot runs (it
  ends on that command, not by the watchdog once follows stop) and a discrete grasp in progress;
* a device that ``waits_for_robot`` (the simulated operator) is not read while the robot node is
  down or has not subscribed to the commands: it starts squeezing once the node hears them;
* when the robot node, once heard, goes down, its grasp is forgotten (a node started again runs
  the next grasp under a new id) and follows are suspended as after ``stop``; so too when the link
  hears the node started again without having seen it down (``OperatorView.robot_restarts``: a
  node killed and restarted within three heartbeats), so that a held enable does not drive the new
  node under the old grasp's id; the follows letting go of the enable name the grasp lost (a node that
  took it refuses follows naming none);
* an enable first held while the robot node is down or has not subscribed to the commands drives
  nothing, then or once the node is heard, until it has been let go and held again: the operator
  holds it anew knowing the node is there; so too while more than one robot node subscribes (a node
  on another ``robot_pub``: it would move unwatched): the status's problem says so, ``grasp`` is
  refused, and a held enable is suspended;
* after ``stop``, ``release`` or ``next``, when the robot ends the follow grasp (released,
  the watchdog: its ``grasp_event`` end or its ``watchdog`` notice naming the grasp), and when it
  refuses a follow naming the grasp while it does not run it (its end went unheard, or another
  grasp runs), no follow goes out until the enable has been let go and held again: a held
  enable never moves the fingers again, nor starts a new grasp, by itself;
* so too when the loop starts (an enable already held does not drive until it has been let go),
  and after a gap in the device (:mod:`haptics.operator_device`): a read that failed (unplugged:
  the enable reads let go, and the device is opened again every :data:`RECONNECT_S`), the device
  opened again, a reading it marks ``lost`` (the display's grip not heard): what the hand did
  meanwhile does not drive until the enable has been read let go and held again;
* the robot side's force, width and the display's stiffness go back to the device
  (``device.feel``, not while it is disconnected): the simulated operator closes its loop on them.

A follow grasp takes a new grasp id when enable is first held after the previous grasp ended,
or after a release cancelled it while the robot prepared it (no end comes for that one);
a discrete grasp takes one per ``grasp`` press. Ids are ``op-<MMDD>-<HHMMSS>-<n>``, unique within a
session.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable
from datetime import datetime
from functools import partial
from typing import Any

from haptics.errors import HapticsError
from haptics.operator_device import RECONNECT_S, DeviceReader
from haptics.operator_grasps import (
    CROWDED,
    DiscreteGrasps,
    crowded,
    over,
    releasing,
    running,
    unreachable,
)
from haptics.operator_link import LIVENESS_PERIODS, OperatorView
from haptics.operator_status import InputDevice, Link, LoopStatus
from teleop.bus.messages import LabelBody
from teleop.errors import BusError, ComplianceTeleopError, MessageRejected
from teleop.live import check_duration_s
from teleop.operator import BUTTONS, FOLLOW_RATE_HZ, grip_to_width_m
from teleop.settings import Settings

__all__ = ["RECONNECT_S", "RELEASE_FOLLOWS", "LoopStatus", "OperatorLoop"]

log = logging.getLogger(__name__)

RELEASE_FOLLOWS = 3  # follows with enable=False sent at least when the dead-man is let go
IDLE_TICK_S = 0.01  # the loop's longest wait when not sending follows
NEXT_WAIT_S = 5.0  # after "next", the longest wait for the grasp left to end and get its final
_UNSENT_ON_THE_BUS = "not sent (bus): "  # a send the link refused or could not make; the next one made mends it


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
        # The day too: the node refuses every id it has seen end, and may run past midnight.
        self._session = datetime.now().strftime("%m%d-%H%M%S")
        self._count = 0
        self._enable = False
        self._release_left = 0  # enable=False follows still to send
        self._next_follow_s = -math.inf
        self._follow_grasp: str | None = None  # the follow grasp's id, until it ends
        self._rearm = True  # follows suspended until the enable is let go and held again: so at the start
        # A robot state comes with every heartbeat, and a node unheard for LIVENESS_PERIODS of them is down.
        self._discrete = DiscreteGrasps(settle_s=(LIVENESS_PERIODS + 1) * settings.bus.heartbeat_s)
        self._lost_follow: str | None = None  # the follow grasp the robot node took down: let-go follows name it
        self._ended_blind: str | None = None  # a grasp seen ended while no estimator was alive: no final comes
        self._last_ended: OperatorView | None = None  # the last grasp "next" cleared, for the summary
        self._leaving: tuple[str, float] | None = None  # after "next": (the grasp left, when) until it is over
        self._shown_over = False  # a status showed the grasp left over (its final in): clear on the next step
        self._waiting: bool | None = None  # waiting for the robot node: whether for a second one to go; None: not
        self._robot_up = False  # the robot node was heard alive at the last step
        self._robot_restarts = 0  # the link's count of robot node restarts at the last step
        self._unreachable = False  # the robot node was down or not subscribed at the last step
        self._crowded = ""  # the notice while more than one robot node subscribed at the last step
        self._input: Any = None
        self._reader = DeviceReader(device, clock, act=self._act, trouble=self._trouble, resolved=self._resolved)
        self._target_m: float | None = None
        self._pressed: list[str] = []  # buttons pushed from another thread (press())
        self._to_label: list[tuple[str, Any]] = []  # (grasp id, ObjectLabel) from another thread (label())
        self._labels: dict[str, LabelBody] = {}  # grasp id -> the label body sent
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
        """Set the discrete grasp's force, clipped to [1 N, gripper.target_force_n]; the force set. Any thread.

        Raises ValueError for a force that is not a finite number (clipping would keep a NaN)."""
        if not math.isfinite(force_n):
            raise ValueError(f"force_n = {force_n!r}: expected a finite force (N)")
        limit = self.settings.gripper.target_force_n
        self.force_n = min(max(float(force_n), min(1.0, limit)), limit)
        return self.force_n

    # ------------------------------------------------------------------ the loop

    def step(self, timeout_s: float = 0.0) -> LoopStatus:
        """Read the device, act on its buttons, send ``follow`` when due, take what the bus
        brought (waiting up to ``timeout_s``), feed the robot's state back; the new status."""
        reading, gap = None, False
        # Not before the node hears our commands: an enable it held before would drive nothing (_drive).
        waiting = self.device.waits_for_robot and unreachable(self.link.view)
        # Said again when why changes: a second node is seen after the wait began, or is gone.
        why = bool(crowded(self.link.view)) if waiting else None
        if waiting and why != self._waiting:
            self._act("waiting for the robot node: the input device is read once the node is heard"
                      + (" alone" if why else ""))
        self._waiting = why
        if not waiting:
            reading, gap = self._reader.read(self._input)
        if gap:
            self._input_gap()
        if reading is not None and self._leaving is not None:
            self._read_while_leaving(reading)
            reading = None  # drives nothing until the view is cleared
        with self._lock:
            pressed, self._pressed = self._pressed, []
            to_label, self._to_label = self._to_label, []
        if reading is not None:
            self._input = reading
            pressed = [*pressed, *(b for b in BUTTONS if b in reading.buttons)]
            # The grip and enable first: a release pressed as the enable is let go goes out after
            # the follow that lets it go.
            self._drive(reading, gap)
        for button in pressed:
            self._button(button)
        for grasp_id, label in to_label:
            self._send_label(grasp_id, label)
        try:
            self.link.poll(timeout_s)
            self._resolved("bus:")
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
        check_duration_s(duration_s, HapticsError)
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
        """On the way out: the dead-man let go (a follow with enable=False) if the loop was driving,
        and a follow grasp the robot runs released, so that it ends on a command, not by the
        watchdog once follows stop; each discrete grasp that may be in progress (one running, one
        pressed since and not answered yet) is released too (as ``release`` does), unless the robot
        already releases it."""
        grasp_id = self._follow_grasp
        robot = self.link.view.robot
        released = releasing(robot, grasp_id)
        if self._enable or self._release_left or self._follow_live():
            let_go = grasp_id or self._lost_follow
            target = self.max_width_m if self._target_m is None else self._target_m  # 0 m is a target
            self._send(lambda: self.link.follow(target, enable=False, grasp_id=let_go))
            self._enable, self._release_left = False, 0
        if grasp_id is not None and not released and self._send(lambda: self.link.release(grasp_id)):
            self._follow_grasp = None
            self._act(f"release {grasp_id}: the console quits")
        for discrete in self._discrete:  # each discrete grasp that may be in progress: the release `r` sends
            if (discrete != grasp_id and not releasing(robot, discrete)
                    and self._send(partial(self.link.release, discrete))):
                self._discrete.remove(discrete)
                self._act(f"release {discrete}: the console quits")
        self.status = self._status()

    # ------------------------------------------------------------------ pieces

    def _read_while_leaving(self, reading: Any) -> None:
        """After ``next``, while the last grasp ends: the device is read, so that the status shows
        its grip and enable as they are (an enable held now drives once that grasp is over, as the
        status says), but drives nothing yet; of its buttons only quit acts."""
        if reading.enable and not (self._input is not None and self._input.enable):
            self._act("enable held: the next grasp starts once the last one has ended")
        self._input = reading
        if "quit" in reading.buttons:
            self._button("quit")
        elif reading.buttons:
            self._act(f"{', '.join(sorted(reading.buttons))} pressed while the last grasp ends: not taken, press again")

    @property
    def _discrete_grasp(self) -> str | None:
        """The discrete grasp commanded last and not known over."""
        return self._discrete.latest

    def _new_grasp_id(self) -> str:
        self._count += 1
        return f"op-{self._session}-{self._count:03d}"

    def _button(self, button: str) -> None:
        view = self.link.view
        # This loop's grasp the robot runs first: one pressed since, not answered yet, would be refused
        # by name; another operator's grasp is never named (the node refuses to open it for us).
        robot_runs = running(view)
        own = robot_runs if robot_runs in (self._follow_grasp, *self._discrete) else None
        current = own or self._follow_grasp or self._discrete_grasp or view.grasp_id
        if button == "grasp":
            grasp_id = self._new_grasp_id()
            if self._send(lambda: self.link.start_grasp(target_force_n=self.force_n, grasp_id=grasp_id)):
                self._discrete.add(grasp_id, self.clock())
                self._act(f"grasp {grasp_id} at {self.force_n:g} N{self._robot_down()}")
        elif button == "release":
            if self._send(lambda: self.link.release(current)):
                self._act(f"release {current or ''}".rstrip())
                if self._follow_grasp is not None and view.grasp_id != self._follow_grasp:
                    # Cancelled while the robot prepared it: no end will come, and the robot never
                    # starts it again, so the next hold of the enable starts a new grasp.
                    self._follow_grasp = None
            self._suspend()
        elif button == "stop":  # the robot holds the grasp, prepared or not, until released or its watchdog
            if self._send(lambda: self.link.stop(current)):
                self._act(f"stop {current or ''}".rstrip())
            self._suspend()
        elif button == "next":
            self._suspend()
            if self._discrete_grasp is not None and view.grasp_id != self._discrete_grasp:
                # Not shown yet (the robot prepares it): clearing the view would hide a grasp the
                # robot runs, and its start would bring it back.
                self._act(f"next refused: grasp {self._discrete_grasp} is in progress: release it (r) "
                          "or wait for it to end, then press n again")
                return
            if view.grasp_id is None or over(view, self._ended_blind):
                self._next_object()
                return
            robot = view.robot
            if view.phase != "ended" and (robot is None or robot.grasp_id != view.grasp_id
                                          or robot.mode != "releasing"):
                self._send(lambda: self.link.release(view.grasp_id))
            self._leaving = (view.grasp_id, self.clock())
            if view.alive("estimator"):
                self._act(f"next object: once {view.grasp_id} ends and its final estimate is in")
            else:
                self._act(f"next object: once {view.grasp_id} ends (the estimator is down: no final "
                          "estimate will come)")
        elif button == "quit":
            self.quit = True
            self._act("quit")

    def _robot_down(self) -> str:
        """What to add to a command's log line when the link hears the robot node dead: a command the
        link sends reaches the node's subscription, and a stalled node reads it when it runs again."""
        down = self.link.view.down("robot node")
        return " (the robot node is not heard: nothing moves until it runs again)" if down else ""

    def _send_label(self, grasp_id: str, label: Any) -> None:
        sent = self._send(lambda: self.link.label(grasp_id, label.object_name, modulus_pa=label.modulus_pa,
                                                  source=label.source, detail=label.detail))
        if sent:
            self._labels = {**self._labels, grasp_id: LabelBody(**label.body(grasp_id))}
            value = "the catalogue's E" if label.modulus_pa is None else f"E {label.modulus_pa:.3g} Pa"
            self._act(f"label {grasp_id}: {label.object_name}, {value} ({label.source})")

    def _drive(self, reading: Any, gap: bool = False) -> None:
        now = self.clock()
        self._target_m = grip_to_width_m(reading.grip, max_width_m=self.max_width_m)
        held = bool(reading.enable)
        if self._rearm and not held and not gap and not getattr(reading, "lost", False):  # let go as read
            self._rearm = False
        enable = held and not self._rearm  # after a stop, release or gap: not until held anew
        if enable and not self._enable and unreachable(self.link.view):
            # Held now, it would drive the node the moment it is heard, the operator unaware: held anew then.
            self._rearm, enable = True, False
            self._act("enable held while more than one robot node subscribes: let go of it and hold it again "
                      "once one remains" if crowded(self.link.view) else
                      "enable held while the robot node is down or not subscribed: let go of it and hold it "
                      "again once the node is heard")
        if enable and not self._enable:
            self._lost_follow = None
            if self._follow_grasp is None:
                self._follow_grasp = self._new_grasp_id()
                self._act(f"follow {self._follow_grasp}: enable held{self._robot_down()}")
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
        grasp_id = self._follow_grasp or self._lost_follow  # after a loss: the let-go follows
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
        robot = view.robot
        if robot is not None and robot.grasp_id == self._follow_grasp and robot.mode in ("following", "stopped"):
            return True
        return view.grasp_id == self._follow_grasp and view.phase in ("loading", "loaded")

    def _next_object(self) -> None:
        view = self.link.view
        no_final = (view.grasp_id is not None and view.phase == "ended" and not view.alive("estimator")
                    and (view.estimate is None or view.estimate.provisional))
        self._leaving, self._shown_over = None, False
        if view.grasp_id is not None:
            self._last_ended = view
        self.link.clear()
        self._follow_grasp = None
        self._discrete.clear()
        self._act(f"next object: ready ({view.grasp_id}'s final estimate did not come: the estimator is down)"
                  if no_final else "next object: ready")

    def _track(self) -> None:
        """Forget a grasp's id once the robot says it ended (the next enable starts another) or
        refused to start it; after ``next``, clear the view once a status has shown the grasp left
        over (:func:`~haptics.operator_grasps.over`: its final is seen before it goes), or after :data:`NEXT_WAIT_S`."""
        view = self.link.view
        if self._robot_up and view.down("robot node"):
            self._robot_lost()
        elif self._robot_up and view.robot_restarts != self._robot_restarts:
            self._robot_lost(restarted=True)  # started again before it was seen down
        self._robot_restarts = view.robot_restarts
        view = self.link.view
        self._robot_up = view.alive("robot node")
        if self._crowded != (now_crowded := crowded(view)):
            if now_crowded:
                self._trouble(now_crowded)
            else:
                self._resolved(CROWDED)
                self._act("no more than one robot node subscribes to the commands now")
            self._crowded = now_crowded
        if self._unreachable and not unreachable(view):
            self._resolved(_UNSENT_ON_THE_BUS)  # the node's subscription is back: what it refused is past
        elif not self._unreachable and unreachable(view) and self._enable and not self._rearm:
            # Its subscription goes before its liveness: a node killed and started again at once
            # would otherwise take the held enable's follows before its restart is heard.
            self._act("more than one robot node hears the console" if now_crowded
                      else "the robot node no longer hears the console")
            self._suspend()
        self._unreachable = unreachable(view)
        if view.phase == "ended" and not view.alive("estimator"):
            self._ended_blind = view.grasp_id
        if self._leaving is not None:
            grasp_id, since = self._leaving
            if view.grasp_id != grasp_id or self._shown_over or self.clock() - since >= NEXT_WAIT_S:
                self._next_object()
                return
            self._shown_over = over(view, self._ended_blind)  # with the estimator down, ended is over
        ended = view.grasp_id if view.phase == "ended" else None
        # The watchdog's notice names the grasp it ended, even one whose start never came (preparing).
        stopped = view.ended_by.grasp_id if view.ended_by is not None else None
        # A follow refused naming this grasp while the robot does not run it: it ended unheard (its
        # end or watchdog notice lost), or another grasp runs; it will not start under this id.
        refused = self._follow_grasp if self._follow_grasp in view.refused_follows and not self._follow_live() else None
        if self._follow_grasp is not None and self._follow_grasp in (ended, stopped, refused):
            if refused is not None:
                self._act(f"follow {refused} refused by the robot: {view.notice.reason}" if view.notice is not None
                          and view.notice.grasp_id == refused else f"follow {refused} refused by the robot")
            self._follow_grasp = None
            if self._enable:  # a new grasp only once the enable is let go and held again
                self._suspend()
        self._discrete.update(view, (ended, stopped), self.clock())

    def _robot_lost(self, *, restarted: bool = False) -> None:
        """The robot node went down (killed, crashed; ``restarted``: and was already heard started
        again): its grasp went with it. Forget the grasp, so that a node started again never runs a
        new grasp under its id, and suspend the follows, so that a held enable does not drive that
        node until it is let go and held again."""
        view = self.link.view
        lost = self._follow_grasp or self._discrete_grasp or (view.grasp_id if view.phase != "ended" else None)
        self._lost_follow = self._follow_grasp or self._lost_follow  # a node that took it refuses follows naming none
        self._follow_grasp = None
        self._discrete.clear()
        if view.phase in ("loading", "loaded"):
            self.link.clear()  # no end or final comes for it: "next" need not wait
        what = "the robot node restarted" if restarted else "the robot node is down"
        self._act(what + (f": grasp {lost} is lost" if lost else ""))
        self._suspend()

    def _suspend(self) -> None:
        """Send no more follows until the enable is let go and held again."""
        if self._enable:
            self._rearm = True
            self._act("let go of the enable to drive again")

    def _input_gap(self) -> None:
        """The device was not heard (failed, opened again, its reading lost): the enable counts as let
        go, and drives again only once it has been read let go and held again."""
        if self._enable and not self._rearm:
            self._act("input device not heard: the enable counts as let go; let go of it and hold it again")
        self._rearm = True

    def _feel(self) -> None:
        view = self.link.view
        self._reader.feel(force_n=view.force_n if view.force_n is not None else 0.0,
                          width_m=view.width_m if view.width_m is not None else self.max_width_m,
                          stiffness=view.stiffness)

    def _send(self, send: Callable[[], None]) -> bool:
        try:
            send()
        except ComplianceTeleopError as exc:  # the link's failure is mended by any send that goes through,
            bus = isinstance(exc, BusError) and not isinstance(exc, MessageRejected)  # not a label's bad fields
            self._trouble(f"{_UNSENT_ON_THE_BUS if bus else 'not sent: '}{exc}")
            return False
        self._resolved(_UNSENT_ON_THE_BUS)
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

    def _resolved(self, kind: str) -> None:
        """A problem of ``kind`` (its prefix) no longer holds: the status stops showing it (the log keeps it)."""
        if self._problem.startswith(kind):
            self._problem = ""

    def _status(self) -> LoopStatus:
        reading = self._input
        view = self.link.view
        current = self._follow_grasp or self._discrete_grasp or view.grasp_id
        if current is not None:
            self._last_grasp = current
        held = reading is not None and bool(reading.enable)
        if self._rearm and held:
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
            held=held,
            suspended=self._rearm and held,
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
            last_ended=self._last_ended,
        )

