"""The robot node, from the devices to the bus.

The node opens the gripper, one tactile camera per sensor and the load cell through their
device families (:mod:`teleop.devices`, backends from the settings), reads each in its own
thread (:mod:`teleop.node_devices`) and publishes everything they capture, losslessly, with its
capture timestamps (``time.monotonic()`` of this host): ``frame/<finger>`` (the camera's JPEG
bytes as a buffer, never re-encoded), ``force`` and ``width`` sample batches. Data captured during a grasp names
the grasp; the rest names none.

Grasps are commanded on the bus (``command`` messages on ``bus.command``):

``start_grasp``
    ``grasp_id`` names the grasp (default ``grasp-<n>``); a grasp that has ended, commanded or
    followed (one of the last :data:`~teleop.follow.ENDED_KEPT`), is not started again. With the simulated backends the
    node simulates a grasp of the next object of its scene (or ``params.object_index``, an
    index into the scene's objects repeated ``grasps_per_object`` times) with
    :func:`~teleop.sim.grasp.simulate_grasp`, seeded from the scene's seed and the grasp
    count, squeezing to ``params.target_force_n`` when given (else to a drawn share of
    ``gripper.target_force_n``), and plays it through the simulated devices in real time (the
    empty approach before the record's first sample is skipped). With hardware it closes the gripper with
    ``params.target_force_n`` (default ``gripper.target_force_n``), holds ``hold_s`` and
    opens again.
``stop``
    Stop the gripper where it is, whatever grasp it names (or none): stopping is always safe,
    so anyone's stop wins.
``release``
    Open the gripper. A release naming another grasp than the one in progress is refused (it
    would open the fingers on someone else's object); one naming none releases whatever is in
    progress.

A simulated scripted grasp is the replay of a record simulated whole: it holds and releases by
itself, and refuses ``stop`` and ``release``.
``reload_model``
    Not for the node (the estimator service's); ignored.

The operator also drives a grasp continuously with ``follow`` messages (also on ``bus.command``):
a *follow grasp*, the fingers following the operator's target width, force-capped, with a
watchdog; see :mod:`teleop.follow`.

A ``grasp_event`` *start* (naming the object when simulated) goes out before the grasp's
first data and an *end* after its last. In between, a *loading_end* marks when the gripper's
grasp command completed (the fingers stopped at the target force: the object is loaded;
:attr:`~teleop.devices.gripper.Gripper.last_stop`), stamped with that time. It goes out once
the width the gripper read at the stop has gone out and, when the load cell delivers during
the grasp, a force sample captured at or after the stop, so the widths and forces captured up to
the stop precede the marker on the bus. Frames are not waited for (a camera period, 33 ms at
30 Hz, would be added to every final estimate): the cameras' frames up to the stop precede it
as long as their reader keeps up with the camera. The simulated gripper
stops where the simulated record's fingers stop. No marker goes out when the gripper could
not read its width at the stop (nor for follow grasps: no grasp command stops them).

A command that cannot be carried out (a start_grasp during a grasp or above the maximum force, a
follow during a scripted grasp or beyond the gripper's width, ...) is logged and answered with a
``robot_notice`` *refused* with the reason, and the node carries on. A sender's values must not
flood the log or the bus (:mod:`teleop.node_refusals`): the first refusal of a kind (the action and
its reason without the values) is logged, then the 10th, 100th, ... with their count; the same
refusal of the same grasp goes out at most once per :data:`REFUSAL_REPEAT_S`, and at most
:data:`~teleop.node_refusals.NOTICES_PER_KIND` of a kind per :data:`REFUSAL_REPEAT_S`. A
``robot_state`` goes out on every change of the node's mode, grasp, target width or enable, and with every heartbeat.

A gripper command that fails (the gripper's link down: its grasp command, or a release, move or
stop the node gives by itself) is answered with a ``robot_notice`` *device* (action ``gripper``)
with the reason, the grasp in progress ends at once (its *end* goes out; a failed grasp command
never reports *holding*), and the node carries on; commands the gripper cannot carry out meanwhile
are refused.
"""

from __future__ import annotations

import contextlib
import logging
import math
import queue
import time
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from typing import Any

import numpy as np

from teleop.bus.pubsub import Publisher, Subscriber
from teleop.bus.wire import Message
from teleop.devices.camera import TactileCamera, make_camera
from teleop.devices.gripper import GraspStop, Gripper, make_gripper
from teleop.devices.loadcell import LoadCell, make_load_cell
from teleop.devices.simulated import robot_is_simulated
from teleop.errors import (
    DeviceError,
    InvalidCommandError,
    SimulationError,
    TeleopError,
)
from teleop.follow import Follower
from teleop.live import ServiceLoop
from teleop.node_devices import READ_TIMEOUT_S, NodeDevices
from teleop.node_refusals import REFUSAL_REPEAT_S, Refusals
from teleop.operator import WATCHDOG_S
from teleop.record import GraspRecord
from teleop.scene import Scene
from teleop.settings import Settings

__all__ = ["COMMAND_TOPICS", "NodeStats", "RobotNode"]

log = logging.getLogger(__name__)

COMMAND_TOPICS = ("command", "follow")
START_GRASP_PARAMS = frozenset({"object_index", "target_force_n"})  # what a start_grasp command may set
APPROACH_LEAD_S = 0.05  # a replay starts this long before the record's first sample
TAIL_S = 2 * READ_TIMEOUT_S  # after a grasp's last data is due, wait this long for the readers
# A step takes at most this many commands before the grasp advances (about 5 ms of refused follows):
# a flood of commands must not hold off the watchdog (teleop.follow) until all of it is taken.
COMMANDS_PER_STEP = 50


@dataclass
class NodeStats:
    grasps: int = 0
    frames: int = 0
    force_batches: int = 0
    width_batches: int = 0
    bad_commands: int = 0
    device_errors: int = 0
    watchdogs: int = 0
    frames_dropped: int = 0  # by the cameras: captured, never read (a reader behind)

    def as_dict(self) -> dict[str, int]:
        return dict(self.__dict__)


@dataclass
class _Grasp:
    """The grasp in progress and where it stands."""

    grasp_id: str
    object_name: str | None
    prepared: Future | None = None  # the simulation, until it is done
    motion: Future | None = None  # the gripper's grasp, then its release
    # simulated: preparing -> tail (the replay); hardware: grasping -> holding -> releasing -> tail
    phase: str = "preparing"
    phase_until_s: float = math.inf
    started_s: float = math.inf  # when the start event went out: data captured from then on is the grasp's
    grasp_command: Future | None = None  # the gripper's grasp, for the loading-end marker
    stop: GraspStop | None = None  # where the grasp command stopped, until its marker went out
    # Follow grasps: phases preparing (the live object) -> following (-> stopped) -> releasing -> tail.
    follow: bool = False
    target_width_m: float | None = None  # the latest enabled target
    force_limited: bool = False  # the force_limit notice went out


def _first_sample_s(record: GraspRecord) -> float:
    """Record time of its first sample or frame."""
    return min(float(s.t_s[0]) for s in (record.force_n, record.width_m, *record.frames) if len(s))


class RobotNode(ServiceLoop):
    """The robot side of the live system (see the module docstring).

    Parameters
    ----------
    settings : Settings
        Devices (backends from ``gripper.backend``, ``load_cell.backend`` and each sensor's
        ``camera_backend``) and the simulation.
    publisher : Publisher
        Lossless publisher of grasp data (``source`` should be ``"robot"``).
    commands : Subscriber, optional
        Subscription to operator commands; None: only :meth:`start_grasp` starts grasps.
    scene : Scene, optional
        Objects to simulate; required with the simulated backends.
    clock : callable
        Monotonic seconds, the devices' clock.
    """

    def __init__(self, settings: Settings, *, publisher: Publisher, commands: Subscriber | None = None,
                 scene: Scene | None = None, clock: Callable[[], float] = time.monotonic):
        self.settings = settings
        self.publisher = publisher
        self.commands = commands
        self.scene = scene
        self.clock = clock
        self.simulated = robot_is_simulated(settings)
        if self.simulated and scene is None:
            raise SimulationError("the simulated robot needs a scene to know what to grasp")
        self.objects = () if scene is None else tuple(o for o in scene.objects for _ in range(scene.grasps_per_object))
        self.stats = NodeStats()
        self.gripper: Gripper = make_gripper(settings.gripper)
        self.cameras: list[TactileCamera] = [make_camera(s) for s in settings.sensors]
        self.load_cell: LoadCell = make_load_cell(settings.load_cell)
        self._captured: queue.Queue[tuple[str, Any]] = queue.Queue()  # the readers' captures, grasp wake-ups
        self._io = NodeDevices(self.gripper, self.cameras, self.load_cell, self._captured)
        self._simulator = ThreadPoolExecutor(max_workers=1, thread_name_prefix="simulate")
        self._grasp: _Grasp | None = None
        self._count = 0  # simulated grasps that took the scene's next object: its index and seed
        # Capture time of the newest sample published per stream ("width", "force"): the marker waits on them.
        self._newest_s: dict[str, float] = {}
        self._latest: dict[str, float] = {}  # the newest force (N) and width (m) published
        self._follower = Follower(self)  # follow grasps (teleop.follow)
        self._refusals = Refusals()  # what was refused: which refusals are logged and said
        self._state: tuple | None = None  # the last robot_state sent
        self._looked_s = math.inf  # when the node last looked for commands (inf: not yet)
        self._commands_left = 0  # commands this step may still take

    # ------------------------------------------------------------------ lifecycle

    def connect(self) -> RobotNode:
        """Connect the devices and start one reader thread per device."""
        # Only a hardware cell is tared: a simulated one sends nothing outside a simulated grasp.
        self._io.connect(tare=not self.load_cell.simulated)
        if self.simulated:
            self._follower.prepare_next()
        return self

    def close(self) -> None:
        """Stop the readers and release the devices; calling twice is fine."""
        self._io.stop()
        self._simulator.shutdown(wait=False, cancel_futures=True)
        self._io.close()

    def __enter__(self) -> RobotNode:
        return self.connect()

    def __exit__(self, *exc: Any) -> None:
        self.close()

    # ------------------------------------------------------------------ loop

    def finish(self) -> None:
        """A grasp under way when the loop stops ends here, its fingers stopped; the stats take the
        frames the cameras dropped."""
        if self._grasp is not None and math.isfinite(self._grasp.started_s):
            log.warning("stopping during grasp %s: it ends here", self._grasp.grasp_id)
            try:  # a grasp that holds stops pressing: nobody is left to release it
                self.gripper.stop()
            except DeviceError as exc:
                log.error("stopping during grasp %s: the fingers could not be stopped: %s", self._grasp.grasp_id, exc)
            self._end()
        self.stats.frames_dropped = sum(camera.dropped for camera in self.cameras)

    def step(self, timeout_s: float = 0.005) -> None:
        """Take commands, publish what the devices captured (waiting up to ``timeout_s`` for
        something), advance the grasp in progress, heartbeat. It takes at most
        :data:`COMMANDS_PER_STEP` commands; more wait for the next step, which then does not wait
        for captures."""
        if self.publisher.heartbeat_if_due(self.clock()):
            self._state = None  # a robot_state goes out with every heartbeat
        self._commands_left = COMMANDS_PER_STEP
        self._take_commands()
        with contextlib.suppress(queue.Empty):
            self._publish(*self._captured.get(timeout=timeout_s if self._commands_left > 0 else 0))
            while True:
                # A long backlog to publish is neither the operator's silence nor the node stalled:
                # follows that came meanwhile count before the watchdog looks (within the step's
                # share: behind a flood they wait, and the watchdog may go first).
                self._take_commands()
                self._publish(*self._captured.get_nowait())
        self._take_commands()
        try:
            self._advance()
        except DeviceError as exc:  # a gripper command failed (the link down): the node carries on
            self._gripper_failed(exc)
        self._send_state()

    def _take_commands(self) -> None:
        """Take the commands that came, within what is left of the step's share (:meth:`step`). A node
        that did not look for them for over WATCHDOG_S stalled: the watchdog goes first
        (:meth:`teleop.follow.Follower.stalled`)."""
        while self.commands is not None and self._commands_left > 0:
            now = self.clock()
            if now - self._looked_s > WATCHDOG_S:
                try:
                    self._follower.stalled(now - self._looked_s)
                except DeviceError as exc:
                    self._gripper_failed(exc)
            self._looked_s = now
            if (message := self.commands.recv(timeout_s=0)) is None:
                return
            self.handle_command(message)
            self._looked_s = self.clock()  # a command's own gripper call (a stop) is no stall of the node
            self._commands_left -= 1

    @property
    def _devices(self) -> tuple[Any, ...]:
        return (self.gripper, *self.cameras, self.load_cell)

    @property
    def _next_live(self) -> tuple[int, Future] | None:
        """The next live object being prepared (:attr:`teleop.follow.Follower.next_live`)."""
        return self._follower.next_live

    @property
    def busy(self) -> bool:
        """Whether a grasp is being prepared or run."""
        return self._grasp is not None

    # ------------------------------------------------------------------ commands

    def handle_command(self, message: Message) -> None:
        """Carry out one operator command or follow; one that cannot be carried out is refused
        (module docstring)."""
        body = message.fields
        action = "follow" if message.type == "follow" else body.action
        try:
            if message.type == "follow":
                self._follower.follow(body.grasp_id, body.target_width_m, body.enable)
            elif action == "start_grasp":
                params = body.params
                unknown = sorted(set(params) - START_GRASP_PARAMS)
                if unknown:  # a misspelt option would otherwise be dropped without a word
                    raise InvalidCommandError(f"start_grasp params {', '.join(unknown)}: expected only "
                                              f"{', '.join(sorted(START_GRASP_PARAMS))}")
                index = params.get("object_index")
                self.start_grasp(body.grasp_id, object_index=None if index is None else _index(index),
                                 target_force_n=params.get("target_force_n"))
            elif action in ("stop", "release") and self._replaying():
                raise DeviceError(f"grasp {self._grasp.grasp_id!r} is a simulated replay: it holds and releases by "
                                  f"itself, and a {action} cannot change what it plays")
            elif action == "stop":
                self.gripper.stop()
                if self._grasp is not None and self._grasp.follow:
                    self._follower.stop(self._grasp)
            elif action == "release":
                self._release(body.grasp_id)
            else:
                log.debug("command %s is not for the robot node", action)
        except TeleopError as exc:
            self.stats.bad_commands += 1
            grasp_id = body.grasp_id or (self._grasp.grasp_id if self._grasp is not None else None)
            kind = self._refusals.kind(action, exc)
            if count := self._refusals.refused(kind):
                log.warning("command %s from %s not carried out: %s%s", action, message.source or "?", exc,
                            "" if count == 1 else f" ({count} refusals like it so far)")
            self._notice("refused", action, grasp_id, str(exc), repeat_s=REFUSAL_REPEAT_S, kind=kind)

    def _replaying(self) -> bool:
        """Whether a simulated scripted grasp runs: a replay of a record simulated whole, which
        neither stops nor releases early (its grasp command completing would mark a false loading end)."""
        return self.simulated and self._grasp is not None and not self._grasp.follow

    def _release(self, grasp_id: str | None) -> None:
        grasp = self._grasp
        if grasp is not None and grasp_id is not None and grasp_id != grasp.grasp_id:
            raise DeviceError(f"grasp {grasp.grasp_id!r} is in progress, not {grasp_id!r}")
        self._follower.stopped = False  # the operator took the fingers back from the watchdog
        if grasp is not None and grasp.follow:
            self._follower.release(grasp)
        elif grasp is None and self.simulated and self._follower.live is None:
            log.info("release: nothing between the simulated fingers")
        else:  # hardware, or an object left between the simulated fingers by a grasp the watchdog ended
            self.gripper.move_async(self.settings.gripper.max_width_m)

    # ------------------------------------------------------------------ notices and state

    def _notice(self, event: str, action: str, grasp_id: str | None, reason: str, *, repeat_s: float = 0.0,
                kind: tuple[str, str, str] | None = None) -> bool:
        """Send a robot_notice unless the same one (action, grasp and reason) went out less than
        ``repeat_s`` ago, or ``kind`` had its share of notices (:mod:`teleop.node_refusals`); True if
        sent. A notice naming another grasp is not a repeat: the operator's console clears its
        pending grasp only on a refusal naming that grasp."""
        now = self.clock()
        if not self._refusals.may_send(action, grasp_id, reason, now, repeat_s=repeat_s, kind=kind):
            return False
        self.publisher.send("robot_notice", t_capture_s=now, event=event, action=action, grasp_id=grasp_id,
                            reason=reason)
        return True

    def _mode(self) -> str:
        grasp = self._grasp
        if grasp is None:
            return "stopped" if self._follower.stopped else "idle"
        if grasp.follow:
            return {"preparing": "following", "following": "following", "stopped": "stopped"}.get(
                grasp.phase, "releasing")
        return {"holding": "holding", "releasing": "releasing"}.get(
            grasp.phase, "releasing" if grasp.phase == "tail" and not self.simulated else "grasping")

    def _send_state(self) -> None:
        """A robot_state when anything in it changed (or after a heartbeat)."""
        grasp = self._grasp
        state = (self._mode(), None if grasp is None else grasp.grasp_id,
                 grasp.target_width_m if grasp is not None and grasp.follow else None, self._follower.enable)
        if state != self._state:
            self._state = state
            mode, grasp_id, target, enable = state
            self.publisher.send("robot_state", t_capture_s=self.clock(), mode=mode, grasp_id=grasp_id,
                                target_width_m=target, enable=enable)

    def start_grasp(self, grasp_id: str | None = None, *, object_index: int | None = None,
                    target_force_n: float | None = None) -> str:
        """Start a grasp (see the module docstring); returns its id.

        Raises
        ------
        DeviceError
            A grasp is already in progress, ``grasp_id`` names a grasp that ended, or the gripper
            refuses the command.
        SimulationError
            ``object_index`` is outside the scene's objects.
        """
        if self._grasp is not None:
            raise DeviceError(f"grasp {self._grasp.grasp_id!r} is still in progress")
        maximum = self.settings.gripper.target_force_n
        if target_force_n is not None and not 0 < target_force_n <= maximum:
            raise InvalidCommandError(f"target_force_n = {target_force_n}: expected a force in (0, {maximum}] N, "
                                      "the settings' maximum")
        number = self._count
        grasp_id = self._follower.grasp_id(grasp_id)
        self._follower.stopped = False
        if not self.simulated:
            grasp = _Grasp(grasp_id, None, phase="grasping")
            grasp.motion = self.gripper.grasp_async(  # refuses a bad force at once
                0.0, force_n=target_force_n, epsilon_outer_m=self.settings.gripper.max_width_m)
            self._grasp = grasp
            self._announce("start")
            self._watch_grasp_command(grasp)
            return grasp_id
        index = number % len(self.objects) if object_index is None else object_index
        if not 0 <= index < len(self.objects):
            raise SimulationError(f"object_index {index}: the scene has objects 0..{len(self.objects) - 1}")
        obj = self.objects[index]
        seed = self.scene.seed * 10_000 + number
        self._count += 1
        self._grasp = _Grasp(grasp_id, obj.name)
        self._grasp.prepared = self._simulator.submit(self._simulate, obj, seed, target_force_n)
        log.info("grasp %s: simulating %s (seed %d)", grasp_id, obj.name, seed)
        return grasp_id

    def _simulate(self, obj: Any, seed: int, force_n: float | None) -> GraspRecord:
        from teleop.sim.grasp import simulate_grasp

        return simulate_grasp(obj, settings=self.settings, rng=np.random.default_rng(seed), seed=seed,
                              force_n=force_n)[0]

    # ------------------------------------------------------------------ grasp progress

    def _advance(self) -> None:
        grasp = self._grasp
        if grasp is None:
            return
        now = self.clock()
        if grasp.follow and self._follower.advance(grasp, now):
            return
        if grasp.phase == "preparing" and grasp.prepared.done():
            self._play(grasp)
        elif grasp.phase == "grasping" and grasp.motion.done():
            if not grasp.motion.cancelled() and grasp.motion.exception() is not None:
                raise grasp.motion.exception()  # the grasp command failed: nothing is held
            grasp.phase, grasp.phase_until_s = "holding", now + self.settings.gripper.hold_s
        elif grasp.phase == "holding" and now >= grasp.phase_until_s:
            grasp.phase, grasp.motion = "releasing", self.gripper.move_async(self.settings.gripper.max_width_m)
        elif grasp.phase == "releasing" and grasp.motion.done():
            grasp.phase, grasp.phase_until_s = "tail", now + TAIL_S
        elif grasp.phase == "tail" and now >= grasp.phase_until_s:
            if self.simulated and not grasp.follow:
                # A replay lets go where its record ends; a hardware release opens the fingers fully,
                # and so must the next object (a follow grasp's) find them.
                self.gripper.move_async(self.settings.gripper.max_width_m)
            self._end()

    def _play(self, grasp: _Grasp) -> None:
        """Replay the simulated grasp through the simulated devices, from its first sample."""
        from teleop.devices.playback import GraspPlayback

        try:
            record = grasp.prepared.result()
        except SimulationError as exc:
            log.error("grasp %s of %s cannot be simulated: %s", grasp.grasp_id, grasp.object_name, exc)
            self._announce("start")
            self._end()
            return
        playback = GraspPlayback(record, clock=self.clock)
        # The last replay's opening move may still run: the replay takes the fingers now, and its grasp
        # command must not queue behind that move (its stop is the loading-end marker).
        self.gripper.stop()
        self._follower.live = None
        for device in self._devices:
            device.replay(playback)
        self._announce("start")
        playback.start(self.clock() - (_first_sample_s(record) - playback.origin_s) + APPROACH_LEAD_S)
        grasp.motion = self.gripper.grasp_async(0.0, epsilon_outer_m=self.settings.gripper.max_width_m)
        self._watch_grasp_command(grasp)
        # The replay holds and releases by itself: the grasp ends once all of it is due.
        grasp.phase = "tail"
        grasp.phase_until_s = playback.live_time(playback.origin_s + playback.duration_s) + TAIL_S

    def _watch_grasp_command(self, grasp: _Grasp) -> None:
        """Wake the loop when the gripper's grasp command completes (its loading-end marker)."""
        grasp.grasp_command = grasp.motion
        grasp.motion.add_done_callback(lambda future: self._captured.put(("grasp_stopped", future)))

    def _grasp_stopped(self, future: Future) -> None:
        grasp = self._grasp
        if grasp is None or grasp.grasp_command is not future or future.cancelled():
            return
        if future.exception() is not None:
            log.warning("grasp %s: the grasp command failed: %s", grasp.grasp_id, future.exception())
            if not self._replaying():  # a replay holds and releases by itself
                self._gripper_failed(future.exception())
            return
        grasp.stop = self.gripper.last_stop
        if grasp.stop is None:
            log.warning("grasp %s: no width read when the fingers stopped, or a stop came before they began: "
                        "no loading-end marker", grasp.grasp_id)
        self._mark_loading_end()

    def _gripper_failed(self, exc: BaseException) -> None:
        """A gripper command failed: a ``robot_notice`` *device* says so, and the grasp in
        progress ends here (a later command the gripper cannot carry out is refused)."""
        grasp = self._grasp
        self.stats.device_errors += 1
        log.error("the gripper command failed%s: %s", "" if grasp is None else f" (grasp {grasp.grasp_id})", exc)
        self._notice("device", "gripper", None if grasp is None else grasp.grasp_id,
                     f"the gripper command failed: {exc}", repeat_s=REFUSAL_REPEAT_S)
        if grasp is None:
            return
        grasp.grasp_command = None  # handled here: its queued wake-up (drained by _end) does nothing
        if math.isfinite(grasp.started_s):
            self._end()
        else:  # never started: nothing on the bus to end, but its console's follows must not start it again
            self._grasp = None
            self._follower.record_ended(grasp.grasp_id)

    def _mark_loading_end(self) -> None:
        """The loading-end marker, once the width read at the stop and a force sample captured at
        or after the stop have gone out (module docstring)."""
        grasp = self._grasp
        if grasp is None or grasp.stop is None:
            return
        if self._newest_s.get("width", -math.inf) < grasp.stop.width_t_s:
            return
        # A load cell silent since the grasp began (a device that delivers nothing) cannot hold it up.
        if grasp.started_s <= self._newest_s.get("force", -math.inf) < grasp.stop.stopped_s:
            return
        self._announce("loading_end", t_s=grasp.stop.stopped_s)
        grasp.stop = None

    def _announce(self, event: str, *, t_s: float | None = None) -> None:
        grasp = self._grasp
        now = self.clock() if t_s is None else t_s
        if event == "start":
            grasp.started_s = now
        self.publisher.send("grasp_event", t_capture_s=now, event=event, grasp_id=grasp.grasp_id,
                            object_name=grasp.object_name)

    def _end(self) -> None:
        with contextlib.suppress(queue.Empty):
            while True:  # everything the readers captured during the grasp goes out first
                self._publish(*self._captured.get_nowait())
        self._announce("end")
        self.stats.grasps += 1
        grasp = self._grasp
        log.info("grasp %s ended", grasp.grasp_id)
        self._grasp = None
        self._follower.grasp_ended(grasp)

    # ------------------------------------------------------------------ publishing

    def _grasp_of(self, t_s: float) -> str | None:
        """The grasp data captured at ``t_s`` belongs to: the open one if captured after its start."""
        grasp = self._grasp
        return grasp.grasp_id if grasp is not None and t_s >= grasp.started_s else None

    def _published(self, stream: str, t_s: float) -> None:
        """Note the newest capture time published on ``stream``; the marker may be due now."""
        self._newest_s[stream] = max(self._newest_s.get(stream, -math.inf), t_s)
        self._mark_loading_end()

    def _publish(self, kind: str, item: Any) -> None:
        if kind == "frame":
            self.publisher.send("frame", t_capture_s=item.t_s, finger=item.finger, grasp_id=self._grasp_of(item.t_s),
                                index=item.index, encoding=item.encoding, data=item.encoded)
            self.stats.frames += 1
        elif kind in ("force", "width"):
            self._latest[kind] = float(item.value[-1])
            values = {"value_n" if kind == "force" else "value_m": item.value}
            self.publisher.send(kind, t_capture_s=float(item.t_s[-1]), grasp_id=self._grasp_of(float(item.t_s[0])),
                                t_s=item.t_s, **values)
            if kind == "force":
                self.stats.force_batches += 1
            else:
                self.stats.width_batches += 1
            self._published(kind, float(item.t_s[-1]))
        elif kind == "grasp_stopped":
            self._grasp_stopped(item)
        else:  # a reader's device failed, or reads again: already logged by the reader
            name, reason = item
            self.stats.device_errors += reason != "reading again"
            self._notice("device", name, None, reason)


def _index(value: float) -> int:
    if not float(value).is_integer():
        raise SimulationError(f"object_index {value!r}: expected a whole number")
    return int(value)
