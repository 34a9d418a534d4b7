"""The live system on loopback: its processes as children of this one, which operates them.

:class:`LiveSystem` starts the four processes of the live system on loopback, on free ports:

==========  ====================  ==============================================================
name        command               role
==========  ====================  ==============================================================
node        ``teleop node``       simulated gripper, cameras and load cell; grasps on command
estimator   ``estimator serve``   provisional and final estimates (report: ``estimator.jsonl``), by
                                  the model of ``--model`` when given
renderer    ``haptics serve``     simulated softness display (report: ``renderer.jsonl``)
recorder    ``teleop record``     the session log (``session.mcap``)
==========  ====================  ==============================================================

This process is the operator: it publishes ``command`` messages and listens to grasp events,
estimates and the robot notices that end a grasp (``GraspOutcome.ended_by``). Each child runs in its own session (a Ctrl-C here stops them in order: node,
estimator, renderer, recorder, so the log gets everything) and is told by the kernel to stop
when this process dies (``PR_SET_PDEATHSIG`` on Linux), so none outlives it; a child that exits
early stops the system with the tail of its log (with an empty log: its folder's free space), except
a recorder whose recording a write error stopped (a full disk:
:data:`~teleop.session.recorder.RECORDING_STOPPED_STATUS`): that is said and
noted (:attr:`LiveSystem.recording_stopped`) and the session carries on; SIGTERM and SIGHUP stop it
as Ctrl-C does, and a second stop signal does not cut that ordered stop short. Children run with one
BLAS thread each and with progress bars off or rare (``TQDM_DISABLE``, ``TQDM_MININTERVAL``).

The estimator's sensor needs a colour-to-gradient calibration: :func:`simulated_calibration` fits
one on simulated ball presses of that sensor (a couple of seconds) where the settings name none
(:func:`configured_calibration`). :meth:`LiveSystem.load_model` switches the running estimator to
another model between grasps, as ``estimator reload`` does (which cannot bind the command endpoint
while the live system holds it). The ``teleop demo`` command around it is :mod:`teleop.system.demo`.
"""

from __future__ import annotations

import contextlib
import ctypes
import dataclasses
import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from haptics.settings import display_range_pa
from teleop.bus.messages import ModelEventBody
from teleop.bus.pubsub import Publisher, Subscriber
from teleop.bus.wire import Message
from teleop.catalogue import ObjectSpec
from teleop.devices.base import check_timeout
from teleop.errors import TeleopError
from teleop.live import ENDPOINTS, sigint_ignored
from teleop.node import COMMAND_TOPICS as NODE_COMMAND_TOPICS
from teleop.session.recorder import RECORDING_STOPPED, RECORDING_STOPPED_STATUS
from teleop.settings import Settings, load_settings, resolve_path
from teleop.system.outcome import GraspOutcome, ReportReader

__all__ = [
    "CHILDREN",
    "LiveSystem",
    "configured_calibration",
    "free_ports",
    "grasp_timeout_s",
    "simulated_calibration",
]

CHILDREN = ("recorder", "renderer", "estimator", "node")  # start order; stopped in reverse
STOP_TIMEOUT_S = 10.0
START_TIMEOUT_S = 60.0
SETTLE_S = 0.5  # after every peer is heard: subscriptions reconnect every 0.1 s
GRASP_TIMEOUT_S = 60.0  # the least any grasp is given, however quick the gripper
GRASP_MARGIN_S = 30.0  # a grasp's time besides closing and holding: opening, the estimate, the reports
REPORT_TIMEOUT_S = 3.0
CALIBRATION_PRESSES = 24
LOG_TAIL_LINES = 15
_PR_SET_PDEATHSIG = 1
# One BLAS thread per child; progress bars (which a log file does not need) off or rare.
_CHILD_ENV = {"OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1", "TQDM_DISABLE": "1",
              "TQDM_MININTERVAL": "60"}
# The child imports the packages from where this process did (not from its working folder, which
# `-c` would put first on sys.path: a user's estimator.py there would run): the same code as the parent.
_ENTRY = "import sys; sys.path.insert(0, {root!r}); from {package}.cli import main; sys.exit(main())"


def package_root() -> Path:
    """The folder this process imported the project's packages from (a checkout, or site-packages)."""
    import teleop

    return Path(teleop.__file__).resolve().parents[1]


def grasp_timeout_s(settings: Settings) -> float:
    """How long one grasp under ``settings`` may take before it counts as stuck (s): closing from the
    widest opening at the closing speed, the hold, and :data:`GRASP_MARGIN_S`; at least
    :data:`GRASP_TIMEOUT_S`."""
    gripper = settings.gripper
    closing_s = gripper.max_width_m / gripper.closing_speed_m_s
    return max(GRASP_TIMEOUT_S, closing_s + gripper.hold_s + GRASP_MARGIN_S)


def free_ports(n: int) -> list[int]:
    """``n`` distinct TCP ports free on 127.0.0.1 right now (the OS picks them)."""
    with contextlib.ExitStack() as stack:
        sockets = [stack.enter_context(socket.socket(socket.AF_INET, socket.SOCK_STREAM)) for _ in range(n)]
        for s in sockets:
            s.bind(("127.0.0.1", 0))
        return [s.getsockname()[1] for s in sockets]


def simulated_calibration(settings: Settings, out_dir: Path, *, finger: str | None = None,
                          n_presses: int = CALIBRATION_PRESSES, seed: int = 0) -> Path:
    """Fit a calibration of ``finger``'s simulated sensor on simulated ball presses; its path.

    The presses (a 2 mm ball, 0.3 to 1.0 mm deep) are written to ``out_dir/presses-<finger>.npz``
    and the calibration to ``out_dir/sim-<finger>.npz``, as ``teleop simulate-presses`` and
    ``estimator calibrate`` would.
    """
    from estimator.perception.calibration_fit import fit_calibration
    from estimator.perception.presses import load_presses
    from teleop.sim.optics import OpticsRenderer
    from teleop.sim.presses import simulate_presses, write_presses

    sensor = settings.sensor(finger or settings.sensing.finger)
    camera_rng, press_rng = np.random.default_rng(seed).spawn(2)
    camera = OpticsRenderer(sensor, sim=settings.simulation, rng=camera_rng)
    ball_m = 2e-3
    pack = simulate_presses(camera, n=n_presses, ball_radius_m=ball_m, depth_range_m=(3e-4, 1e-3), rng=press_rng)
    presses = load_presses(write_presses(out_dir / f"presses-{sensor.finger}.npz", pack)).in_sensor_frame(sensor)
    calibration = fit_calibration(presses.reference, presses.images, presses.centers_px, presses.radii_px,
                                  ball_radius_m=ball_m, pixel_pitch_m=sensor.pixel_pitch_m)
    return calibration.save(out_dir / f"sim-{sensor.finger}.npz")


def configured_calibration(settings: Settings) -> Path | None:
    """The calibration file the settings name for the estimator's finger, when it exists; else None."""
    sensor = settings.sensor(settings.sensing.finger)
    if not sensor.calibration:
        return None
    path = resolve_path(sensor.calibration)
    return path if path.is_file() else None


# Resolved here, not in the forked child: another thread may hold the loader's lock at fork time.
_prctl = ctypes.CDLL(None, use_errno=True).prctl if sys.platform.startswith("linux") else None


def _die_with_parent() -> None:
    """In the child, between fork and exec: have the kernel send SIGTERM when the parent dies."""
    if _prctl is not None:
        _prctl(_PR_SET_PDEATHSIG, signal.SIGTERM)


@dataclass
class _Child:
    name: str
    process: subprocess.Popen
    log_path: Path

    def tail(self) -> str:
        try:
            lines = self.log_path.read_text(encoding="utf-8", errors="replace").splitlines()
        except OSError:
            return "(no log)"
        return "\n".join(lines[-LOG_TAIL_LINES:])

    def why_silent(self) -> str:
        """What an empty log suggests: the child's messages go to its log, so on a full or read-only
        folder the error that stopped it was lost with them."""
        folder = self.log_path.parent
        try:
            free = f"free: {shutil.disk_usage(folder).free / 1e6:.0f} MB"
        except OSError as exc:
            free = f"free space unknown: {exc.strerror or exc}"
        return f"its log {self.log_path} is empty: is {folder} full or unwritable? ({free})"


class LiveSystem:
    """The live system's processes on loopback, and this process as their operator.

    Parameters
    ----------
    settings_path : Path
        Settings TOML every process reads (its bus endpoints are replaced by free ports).
    scene : str
        Scene name or path the node simulates.
    run_dir : Path
        Where the children's logs and reports and the session log go.
    calibration : Path
        The estimator finger's calibration.
    record : bool
        Also run the session recorder.
    foxglove : (host, port), optional
        The recorder also serves the bus live to Foxglove there (``teleop record --foxglove``).
    model : str, optional
        The estimator's ``--model``: a model folder, or "none" (analytical only); default: the settings'.
    """

    def __init__(self, settings_path: Path, scene: str, run_dir: Path, calibration: Path, *, record: bool = True,
                 foxglove: tuple[str, int] | None = None, model: str | None = None):
        self.settings_path = settings_path
        self.scene = scene
        self.run_dir = run_dir
        self.calibration = calibration
        self.record = record
        self.foxglove = foxglove
        self.model = model
        self.endpoints: dict[str, str] = {}
        self.bus = None  # the settings' BusSettings on self.endpoints, once started
        self.children: dict[str, _Child] = {}
        self.commands: Publisher | None = None
        self.events: Subscriber | None = None
        self.control: Publisher | None = None  # load_model's (see there)
        self.estimator_reports = ReportReader(run_dir / "estimator.jsonl")
        self.renderer_reports = ReportReader(run_dir / "renderer.jsonl")
        self.display_range: tuple[float, float] | None = None  # (e_soft_pa, e_rigid_pa), known once started
        self.grasp_timeout_s = GRASP_TIMEOUT_S  # the settings' (grasp_timeout_s), known once started
        self._followed: set[str] = set()  # grasps followed to their end
        self._later: list[Message] = []  # messages of a grasp that started while another was followed
        self.model_events: list[ModelEventBody] = []  # what the estimator said of its model, as heard
        self.recording_stopped: str | None = None  # why the recorder stopped early, when it did

    @property
    def session_log(self) -> Path | None:
        return self.run_dir / "session.mcap" if self.record else None

    def _command_lines(self) -> dict[str, list[str]]:
        ep, settings, out = self.endpoints, str(self.settings_path), self.run_dir
        lines = {
            "node": ["teleop", "node", "--settings", settings, "--scene", self.scene,
                     "--robot-pub", ep["robot_pub"], "--command", ep["command"]],
            "estimator": ["estimator", "serve", "--settings", settings, "--calibration", str(self.calibration),
                          "--robot-pub", ep["robot_pub"], "--estimate-pub", ep["estimate_pub"],
                          "--command", ep["command"], "--control", ep["control"],
                          "--report", str(out / "estimator.jsonl"),
                          *(["--model", str(self.model)] if self.model is not None else [])],
            "renderer": ["haptics", "serve", "--settings", settings, "--backend", "sim", "--estimate-pub", ep["estimate_pub"],
                         "--display-pub", ep["display_pub"], "--report", str(out / "renderer.jsonl")],
        }
        if self.record:
            lines["recorder"] = ["teleop", "record", "--out", str(self.session_log), "--settings", settings,
                                 "--scene", self.scene, *[a for name in ENDPOINTS for a in ("--endpoint", ep[name])]]
            if self.foxglove is not None:
                lines["recorder"] += ["--foxglove", "{}:{}".format(*self.foxglove)]
        return lines

    def start(self, *, timeout_s: float = START_TIMEOUT_S) -> None:
        """Start the children and wait until every one is up and connected.

        Raises
        ------
        TeleopError
            A child exits or stays silent for ``timeout_s``; the others are stopped.
        """
        self.run_dir.mkdir(parents=True, exist_ok=True)
        settings = load_settings(self.settings_path)
        self.display_range = display_range_pa(settings)
        self.grasp_timeout_s = grasp_timeout_s(settings)
        try:
            self.open_bus(settings)
            lines = self._command_lines()
            env = {**os.environ, **_CHILD_ENV}
            for name in CHILDREN:
                if name in lines:
                    self._spawn(name, lines[name], env)
            self._wait_ready(timeout_s)
        except BaseException:
            self.stop()
            raise

    def open_bus(self, settings: Settings) -> None:
        """Free loopback ports for the children, and this process's ends of them: :attr:`commands` and
        :attr:`events`, with the settings' keys, as the children have them (with ``bus.keys_dir`` set,
        CURVE runs on loopback too)."""
        self.endpoints = {name: f"tcp://127.0.0.1:{port}"
                          for name, port in zip(ENDPOINTS, free_ports(len(ENDPOINTS)), strict=True)}
        bus = self.bus = dataclasses.replace(settings.bus, **self.endpoints)
        self.commands = Publisher.from_settings(bus, bus.command, lossless=True, source="operator")
        self.events = Subscriber.from_settings(bus, [bus.robot_pub, bus.estimate_pub, bus.display_pub],
                                               ("grasp_event", "estimate", "force", "display", "model_event",
                                                "robot_notice"))

    def _spawn(self, name: str, line: Sequence[str], env: dict[str, str]) -> None:
        package, *args = line
        log_path = self.run_dir / f"{name}.log"
        try:
            log_file = log_path.open("wb")
        except OSError as exc:  # a read-only or full file system
            raise TeleopError(f"--out {self.run_dir}: cannot write {log_path.name} ({exc.strerror or exc}); "
                              f"choose a writable folder with --out") from exc
        with log_file:
            process = subprocess.Popen(  # -P: no working folder on sys.path (_ENTRY)
                [sys.executable, "-P", "-c", _ENTRY.format(root=str(package_root()), package=package), *args],
                stdin=subprocess.DEVNULL, stdout=log_file, stderr=subprocess.STDOUT, env=env,
                start_new_session=True, preexec_fn=_die_with_parent,
            )
        self.children[name] = _Child(name, process, log_path)

    def _wait_ready(self, timeout_s: float) -> None:
        deadline = time.monotonic() + timeout_s
        wanted = {"robot", "estimator", "renderer"}
        while missing := [*sorted(wanted - set(self.events.heartbeat.peers())), *self._deaf()]:
            self.check()
            if time.monotonic() >= deadline:
                raise TeleopError(f"live system not up within {timeout_s:g} s: nothing from "
                                  f"{', '.join(missing)}; logs in {self.run_dir}")
            self.events.recv(timeout_s=0.1)
        end = time.monotonic() + SETTLE_S
        while time.monotonic() < end:
            self.events.recv(timeout_s=end - time.monotonic())

    def _deaf(self) -> list[str]:
        """Who has not subscribed to :attr:`commands` yet: what is sent there before is lost to them (the
        first grasp's command to the node; to the recorder, the session's first messages)."""
        deaf = [] if all(self.commands.subscriptions(t) for t in NODE_COMMAND_TOPICS) else ["the node's commands"]
        # The recorder takes every topic; one that stopped recording is not waited for (check()).
        if self.record and self.recording_stopped is None and not self.commands.subscriptions(""):
            deaf.append("the recorder")
        return deaf

    def check(self) -> None:
        """Raise TeleopError, with the tail of its log, if a child has exited; a recorder that stopped
        recording on a write error is noted in :attr:`recording_stopped` (and said on stderr) instead:
        the session goes on without it."""
        for child in self.children.values():
            code = child.process.poll()
            if code is None:
                continue
            if child.name == "recorder" and code == RECORDING_STOPPED_STATUS:
                if self.recording_stopped is None:
                    # The recorder's last line says why (teleop.session.record_cli).
                    last = child.tail().splitlines()[-1:] or ["no reason in its log"]
                    self.recording_stopped = last[0].removeprefix(RECORDING_STOPPED)
                    print(f"recording stopped: {self.recording_stopped}; the session log holds what came before",
                          file=sys.stderr)
                continue
            tail = child.tail()
            raise TeleopError(f"{child.name} exited with status {code}; the end of {child.log_path}:\n{tail}"
                              if tail else f"{child.name} exited with status {code}; {child.why_silent()}")

    def stop(self) -> dict[str, int | None]:
        """Stop every child (node first, recorder last), killing one that does not stop in time.

        Returns each child's exit status; calling twice is fine.
        """
        codes: dict[str, int | None] = {}
        for name in reversed(CHILDREN):
            child = self.children.get(name)
            if child is None:
                continue
            process = child.process
            if process.poll() is None:
                process.send_signal(signal.SIGTERM)
            try:
                codes[name] = process.wait(timeout=STOP_TIMEOUT_S)
            except subprocess.TimeoutExpired:
                process.kill()
                codes[name] = process.wait()
        for sock in (self.commands, self.events, self.control):
            if sock is not None:
                sock.close()
        return codes

    def __enter__(self) -> LiveSystem:
        self.start()
        return self

    def __exit__(self, *exc: Any) -> None:
        with sigint_ignored(stop_signals=True):  # a second Ctrl-C, SIGTERM or SIGHUP must not cut the ordered stop short
            self.stop()

    # ------------------------------------------------------------------ operating

    def grasp(self, grasp_id: str, object_index: int, obj: ObjectSpec, *,
              on_update: Callable[[GraspOutcome], None] | None = None,
              on_message: Callable[[Message], None] | None = None,
              timeout_s: float | None = None) -> GraspOutcome:
        """Command one grasp of scene object ``object_index`` and follow it to the reports.

        ``on_update`` sees the outcome after each of the grasp's messages, ``on_message`` each
        of its messages. ``timeout_s`` None: the settings' :func:`grasp_timeout_s`.

        Raises
        ------
        TeleopError
            A child exits, or the grasp does not end within ``timeout_s``.
        InvalidCommandError
            ``timeout_s`` is not None or a finite number of seconds > 0; no grasp was commanded.
        """
        timeout_s = self.grasp_timeout_s if timeout_s is None else check_timeout(timeout_s)
        self.commands.send("command", t_capture_s=time.monotonic(), action="start_grasp", grasp_id=grasp_id,
                           params={"object_index": float(object_index)})
        return self._follow(GraspOutcome(grasp_id, obj, display_range=self.display_range), on_update=on_update,
                            on_message=on_message, timeout_s=timeout_s)

    def operated_grasp(self, obj: ObjectSpec, *, on_update: Callable[[GraspOutcome], None] | None = None,
                       on_message: Callable[[Message], None] | None = None,
                       timeout_s: float | None = None) -> GraspOutcome:
        """Follow the next grasp an operator makes (:mod:`teleop.system.seat`) to the reports: the first
        grasp the robot starts after those already followed; ``obj`` is the object it should grasp.
        Arguments and errors as :meth:`grasp`."""
        timeout_s = self.grasp_timeout_s if timeout_s is None else check_timeout(timeout_s)
        outcome = GraspOutcome(None, obj, style="operator", display_range=self.display_range)
        return self._follow(outcome, on_update=on_update, on_message=on_message, timeout_s=timeout_s)

    def load_model(self, path: str | Path, *, timeout_s: float = 30.0) -> ModelEventBody:
        """Switch the running estimator to the model in ``path``, as ``estimator reload`` does; the body
        of the service's ``model_event`` answer ("loaded" with the new id, or "refused" with the reason).

        Raises
        ------
        TeleopError
            A child exits, or no answer within ``timeout_s``.
        """
        from estimator.reload_cli import reload_model

        self.check()
        if self.control is None:  # bound at the first load, then kept: a closed socket frees its port late
            self.control = Publisher.from_settings(self.bus, self.bus.control, lossless=False, source="demo")
        with Subscriber.from_settings(self.bus, self.bus.estimate_pub, ("model_event",)) as answers:
            try:
                return reload_model(os.path.abspath(path), command=self.control, answers=answers, timeout_s=timeout_s)
            except TeleopError:
                self.check()  # a child that died is the better reason
                raise

    def _next_message(self, pending: list[Message], timeout_s: float) -> Message | None:
        """The next grasp message: one of ``pending`` (set aside for a later grasp) first, then the
        bus (a ``model_event`` is kept in :attr:`model_events`)."""
        while True:
            message = pending.pop(0) if pending else self.events.recv(timeout_s=timeout_s)
            if message is None or message.type != "model_event":
                return message
            self.model_events.append(message.fields)

    def _follow(self, outcome: GraspOutcome, *, on_update: Callable[[GraspOutcome], None] | None,
                on_message: Callable[[Message], None] | None, timeout_s: float) -> GraspOutcome:
        """Take the grasp's messages until the robot and the estimator ended it; then its reports."""
        # What earlier grasps set aside, taken once: one set aside again waits for the next grasp
        # rather than come back at once, before anything on the bus; what this grasp did not reach
        # waits for the next too, after what it set aside: that came before it (nothing was read from
        # the bus while some was left), and a grasp's end must not come back ahead of its start.
        pending, self._later = self._later, []
        try:
            self._take(outcome, pending, on_update=on_update, on_message=on_message,
                       deadline=time.monotonic() + timeout_s, timeout_s=timeout_s)
        finally:
            self._later += pending
        grasp_id = outcome.grasp_id
        self._followed.add(grasp_id)
        outcome.estimator_report = self.estimator_reports.find(grasp_id, timeout_s=REPORT_TIMEOUT_S)
        outcome.renderer_report = self.renderer_reports.find(
            grasp_id, timeout_s=REPORT_TIMEOUT_S if outcome.final is not None else 0.0)
        if on_update is not None:
            on_update(outcome)
        return outcome

    def _take(self, outcome: GraspOutcome, pending: list[Message], *,
              on_update: Callable[[GraspOutcome], None] | None, on_message: Callable[[Message], None] | None,
              deadline: float, timeout_s: float) -> None:
        """:meth:`_follow`'s messages of ``outcome``'s grasp, ``pending`` first, until it ended."""
        obj = outcome.obj
        while not outcome.done:
            self.check()
            if time.monotonic() >= deadline:
                raise TeleopError(f"grasp {outcome.grasp_id or '(not started)'} ({obj.name}) did not end within "
                                  f"{timeout_s:g} s; logs in {self.run_dir}")
            message = self._next_message(pending, timeout_s=0.05)
            if message is None:
                continue
            body = message.fields  # a grasp_event, estimate, force, display or robot_notice: each names its grasp
            grasp_id = body.grasp_id
            if (outcome.grasp_id is None and message.type == "grasp_event" and body.event == "start"
                    and message.source == "robot" and grasp_id not in self._followed):
                outcome.grasp_id = grasp_id  # the operator's next grasp
            if grasp_id != outcome.grasp_id:
                # The operator went on to the next object meanwhile. Of the notices only those that end
                # a grasp: another names a grasp not followed yet to refuse a stale follow of a grasp
                # that may never start.
                if (grasp_id is not None and outcome.grasp_id is not None and grasp_id not in self._followed
                        and (message.type != "robot_notice" or body.ended_grasp() is not None)):
                    self._later.append(message)
                continue
            if on_message is not None:
                on_message(message)
            if message.type in ("force", "display", "robot_notice"):  # a notice: what cut the grasp short
                outcome.observe(message)
            elif message.type == "estimate":
                outcome.estimates += 1
                outcome.latest = body
                if not body.provisional:
                    outcome.final = body
            elif body.event == "start":
                outcome.started = True
                if body.object_name not in (None, obj.name):
                    raise TeleopError(f"grasp {grasp_id}: the node grasped {body.object_name}, not {obj.name}")
            elif body.event != "end":  # loading_end: the grasp goes on
                pass
            elif message.source == "estimator":
                outcome.estimator_ended = True
            else:
                outcome.robot_ended = True
            if on_update is not None:
                on_update(outcome)
