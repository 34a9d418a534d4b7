"""The estimator service, from the robot's grasp streams to estimates on the bus.

It subscribes losslessly to the robot node's ``frame``, ``force``, ``width`` and
``grasp_event`` messages and publishes ``estimate`` messages (latest-value) on its own
endpoint. Per grasp (from a ``grasp_event`` *start* to its *end*):

* a PROVISIONAL estimate for every tactile frame of the estimator's finger from contact
  until the loading phase is over (:class:`~estimator.stream.GraspStream`: that frame is
  warped and reconstructed, the fits rerun over what has arrived);
* one FINAL estimate as soon as the loading phase is over
  (:meth:`~estimator.stream.GraspStream.loading_complete`): after the robot's
  ``grasp_event`` *loading_end* marker (the gripper's fingers stopped at the target force;
  everything captured before it came first), at the first frame captured after the force
  peak (the peak frame, which shows the object under the full force: a stiff object loads
  between two frames), at once if that frame came before the marker; without a marker, when
  the data show the end; or at the grasp's end if that comes first. A leader-follower grasp
  (:meth:`~teleop.bus.messages.RobotStateBody.followed_grasp`: an operator drives the fingers) gets
  provisional estimates for every frame while the operator squeezes, and its final one at the
  grasp's end (:meth:`~estimator.stream.GraspStream.mark_follow`); with a model loaded, its
  provisional estimates are the model's over the loading so far (the operator feels the answer
  while squeezing, not seconds later when letting go). With a model loaded the
  final one is the hybrid ``auto`` estimate of the grasp's stream
  (:meth:`~estimator.inference.hybrid.HybridEstimator.estimate_stream`: the one measurement path,
  so the grasp's exported record gives the same estimate offline when it holds the same data);
  for a depth model of the estimator's finger its input comes from the depths already computed
  for the provisional estimates and reduced to the model's input size after each of them,
  without measuring a frame again. Without a model it is the analytical one;
* the grasp's end event, forwarded on the estimate endpoint after the final estimate, so a
  renderer that listens to estimates alone knows when to let go.

Each estimate message carries its state, interval and reason; ``t_capture_s`` is the capture
time of the newest loading frame its fit used (for the final one: the last loading frame),
``latency_s`` the time from receiving the message that triggered it to publishing it. The
object's name in a start event is never read. The per-grasp report (one JSON line per grasp
to ``report``) says what ended the loading (``final_by``: ``loading_end``, ``settled`` or
``grasp_end``), the marker's time, when the final estimate was sent and how long it took to
compute. Its ``time_to_first_estimate_s`` is on the capture clock: the service's clock is mapped
onto it by the least receive delay seen up to the first estimate, so a replay (at any speed: its
capture clock runs at its own rate) or a node on another host reads right.

A *start* while another grasp is open closes that one (its final estimate, report and end go
out). A *start* of the grasp that is open (a robot node restarted mid-grasp names it again) drops
what the service had of it, publishing nothing more for it: the final estimate, end and report
that grasp id gets are the new grasp's. A grasp whose robot node, once heard, misses three of its
heartbeat periods is closed as by its end: no end would come, and a model switch waits for it. The
end of a grasp whose start the service never saw (it started mid-grasp) gets a refusal as its final
(``insufficient_data``, the reason saying so), a report and its end; that of a grasp it closed
already is logged and dropped.

A message that cannot be used (a frame that does not decode or declares the wrong size, samples
that are not finite, capture times that go backwards, repeat or jump more than
:data:`MAX_CLOCK_JUMP_S` ahead of the stream's last one, a topic's first capture times more than
that from the grasp's newest (its start's or another topic's), data for a grasp that is not open) is
counted and skipped, and the service carries on: the first of each kind (its message type, and the
error's reason or class) is logged, then a count at every power of ten. So are the refusals of the bus itself (:class:`~teleop.bus.pubsub.Subscriber`).

Models
------
Every estimate and grasp report names the learned model that made it; the model is pinned to a
grasp at its start and switched only between grasps, after a check in the background. How and
when (``load_model``, ``reload_model``, SIGHUP, a change of the served files) and what the service
says about it (``model_event``): :mod:`estimator.model_slot`.

The service is meant to run on one core: start it with ``OPENBLAS_NUM_THREADS=1`` (as
``teleop demo`` does), or BLAS threads fight for the cores and per-frame times jump.
"""

from __future__ import annotations

import logging
import math
import time
from collections import OrderedDict, deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2

from estimator.capture_times import MAX_CLOCK_JUMP_S, check_times
from estimator.errors import EstimatorError, ModelError, PerceptionError
from estimator.estimate import Estimate
from estimator.model_slot import ModelEvent, ModelSlot, _cut, model_log
from estimator.perception.calibration import Calibration
from estimator.received import MAX_GRASP_FRAMES
from estimator.segment import Segment
from estimator.settings import estimator_settings
from estimator.stream import DEFAULT_METHODS, LOADING_SETTLED_S, GraspStream
from teleop.bus.peers import Recent
from teleop.bus.pubsub import Publisher, Subscriber, is_decade
from teleop.bus.wire import Message
from teleop.errors import BusError, TeleopError
from teleop.live import JsonLines, ServiceLoop
from teleop.settings import Settings, resolve_path

__all__ = ["COMMAND_TOPICS", "INPUT_TOPICS", "MAX_CLOCK_JUMP_S", "EstimatorService", "ServiceStats",
           "resolve_model_dir"]

log = logging.getLogger(__name__)

INPUT_TOPICS = ("frame", "force", "width", "grasp_event", "robot_state")
# What the service takes from bus.command: reload_model (a command action) and load_model.
COMMAND_TOPICS = ("command", "load_model")
# load_model requests remembered, so a repeated one is answered again and not loaded twice.
REMEMBERED_REQUESTS = 64
# Grasps closed, remembered so that a late or repeated end is not taken for one of a grasp never seen.
REMEMBERED_GRASPS = 16
# A force batch reaching this share of the contact force may show the contact: segment then.
CONTACT_HINT = 0.5
# A bad message is one of these; anything else is a bug and ends the service.
_BAD_INPUT = (EstimatorError, TeleopError, ValueError, cv2.error)


def resolve_model_dir(option: str | None, settings: Settings) -> Path | None:
    """The model directory to serve: ``option`` ("none": no model; an empty name is refused), else
    ``estimator.model_path`` (relative to ``configs/``; a ``model.onnx`` names its directory), else
    the shipped default model when it exists, else None."""
    from estimator.inference.infer import default_model_dir

    if option == "none":
        return None
    if option is not None and not option.strip():
        raise ModelError(f"--model {option!r}: expected a model folder (or none), got an empty name")
    if option:
        path = Path(option)
    elif estimator_settings(settings).model_path:
        path = resolve_path(estimator_settings(settings).model_path)
    else:
        path = default_model_dir()
        if not (path / "model.onnx").is_file():
            return None
    return path.parent if path.suffix == ".onnx" else path


@dataclass
class ServiceStats:
    """What the estimator service did."""

    messages: int = 0
    bad_messages: int = 0
    ignored: int = 0  # data of no open grasp
    grasps: int = 0
    provisional: int = 0
    final: int = 0
    reloads: int = 0  # switches to another model (or the same folder read again)
    reload_requests: int = 0  # reload_model commands taken (with no model: logged, nothing to do)
    load_requests: int = 0  # load_model messages taken (a repeated request counts once)
    model_refusals: int = 0  # candidate models refused (the one in use stayed)

    def as_dict(self) -> dict[str, Any]:
        return {"messages": self.messages, "bad_messages": self.bad_messages, "ignored": self.ignored,
                "grasps": self.grasps, "provisional": self.provisional, "final": self.final,
                "reloads": self.reloads, "reload_requests": self.reload_requests,
                "load_requests": self.load_requests, "model_refusals": self.model_refusals}


@dataclass
class _Grasp:
    """One open grasp and what has been published for it."""

    grasp_id: str
    stream: GraspStream
    t_start_s: float  # the start event's capture time
    source: str | None  # the robot node that started it (its heartbeat says whether it lives)
    model: Any  # the HybridEstimator pinned at the grasp's start, or None
    model_id: str | None = None  # its id
    model_dir: str | None = None  # its folder
    seen_contact: bool = False
    t_peak_s: float = math.inf  # of the last segmentation with contact
    t_contact_s: float | None = None
    first_estimate_s: float | None = None  # clock time the first non-refusal estimate went out ...
    first_offset_s: float = math.inf  # ... and clock_offset_s then (a replay's clock runs at its own speed)
    clock_offset_s: float = math.inf  # least (receive - capture) time seen: the clocks' offset
    provisional_s: list[float] = field(default_factory=list)
    final: Estimate | None = None
    final_s: float | None = None
    final_t_data_s: float | None = None
    final_by: str | None = None  # what ended the loading: loading_end, settled or grasp_end
    final_compute_s: float | None = None
    final_by_model: bool = False  # the grasp's model made the final estimate
    loading_frames: int = 0
    last_t_s: dict[str, float] = field(default_factory=dict)  # newest capture time per topic


class EstimatorService(ServiceLoop):
    """Estimates grasps from a bus subscription and publishes them (see the module docstring).

    Parameters
    ----------
    settings : Settings
    calibration : Calibration
        The estimator finger's colour-to-gradient calibration.
    subscriber : Subscriber
        Lossless subscription to the robot node's :data:`INPUT_TOPICS`.
    publisher : Publisher
        Latest-value publisher of estimates (``source`` should be ``"estimator"``).
    methods : sequence of str
        Analytical methods, in order of preference.
    model : ModelSlot, optional
        The learned model for final estimates.
    report : JsonLines, optional
        Receives one JSON object per grasp when it ends.
    commands : Subscriber, optional
        Subscription to :data:`COMMAND_TOPICS` on ``bus.command`` (``reload_model``, ``load_model``);
        None: none taken.
    clock : callable
        Monotonic seconds; must be the clock the robot stamps captures with (one host).
    poll_s : float
        How long each :meth:`step` of :meth:`~teleop.live.ServiceLoop.run` waits for a message (s).
    """

    def __init__(self, settings: Settings, *, calibration: Calibration, subscriber: Subscriber,
                 publisher: Publisher, methods: Sequence[str] = DEFAULT_METHODS,
                 model: ModelSlot | None = None, report: JsonLines | None = None,
                 commands: Subscriber | None = None, clock: Callable[[], float] = time.monotonic,
                 poll_s: float = 0.05):
        self.settings = settings
        self.calibration = calibration
        self.subscriber = subscriber
        self.publisher = publisher
        self.methods = tuple(methods)
        # Checks the methods and the calibration now, and keeps the first grasp from paying for the caches.
        GraspStream(settings=settings, calibration=calibration, methods=self.methods).warm_up()
        self.model = model
        self.report = report or JsonLines(None)
        self.commands = commands
        self.clock = clock
        self.poll_s = poll_s
        self.stats = ServiceStats()
        self._grasp: _Grasp | None = None
        self._closed: deque[str] = deque(maxlen=REMEMBERED_GRASPS)
        self._following: str | None = None  # the grasp the robot last said it follows an operator in
        # load_model requests taken: None while the candidate is being checked, then its answer.
        self._requests: OrderedDict[str, ModelEvent | None] = OrderedDict()
        # Bad messages by type and reason (never the topic: the sender's to choose), the most recent kept.
        self._bad: Recent = Recent("kinds of bad message")

    # ------------------------------------------------------------------ loop

    def step(self, timeout_s: float | None = None) -> Message | None:
        """Take commands; receive and handle at most one message (waiting up to ``timeout_s``, by
        default :attr:`poll_s`); heartbeat; reload."""
        timeout_s = self.poll_s if timeout_s is None else timeout_s
        self.publisher.heartbeat_if_due(self.clock())
        while self.commands is not None and (command := self.commands.recv(timeout_s=0)) is not None:
            self.handle_command(command)
        message = self.subscriber.recv(timeout_s=timeout_s)
        if message is not None:
            self.handle(message, received_s=self.clock())
        grasp = self._grasp
        # Only with nothing queued: heard-from times are when messages were taken, so a slow step
        # (a final estimate, a model's first run) would make a node that is sending look silent.
        if message is None and grasp is not None and self._robot_silent(grasp):
            # No end will come: closed on what came, its final and end go out, and a model switch
            # waiting for the grasp to end can take place.
            log.warning("grasp %r: its robot node %r has gone silent: closing it on what came",
                        grasp.grasp_id, grasp.source)
            self._close(grasp.grasp_id, max([grasp.t_start_s, *grasp.last_t_s.values()]), self.clock())
        if self.model is not None:
            event = self.model.poll(idle=self._grasp is None)
            if event is not None:
                self._model_event(event)
        return message

    def _robot_silent(self, grasp: _Grasp) -> bool:
        """Whether the robot node that started ``grasp``, once heard, has missed three of its
        heartbeat periods."""
        heartbeat = self.subscriber.heartbeat
        if grasp.source is None or heartbeat.last_seen_s(grasp.source) is None:
            return False
        try:
            return not heartbeat.is_alive(grasp.source)
        except BusError:  # it announced no heartbeat period
            return False

    def handle(self, message: Message, *, received_s: float) -> None:
        """Handle one message; a message that cannot be used is counted, and logged as the module
        docstring says."""
        self.stats.messages += 1
        try:
            self._dispatch(message, received_s)
        except _BAD_INPUT as exc:
            self.stats.bad_messages += 1
            self._log_bad(message, exc)

    def _log_bad(self, message: Message, exc: Exception) -> None:
        """Log the first bad message of its type and reason, then a count at every power of ten: one
        broken sender must not flood the log with a line per message."""
        reason = getattr(exc, "reason", None) or type(exc).__name__
        key = (message.type, reason)
        count = self._bad[key] = self._bad.get(key, 0) + 1
        sender = f"{message.source or '?'} (seq {message.seq})"
        if count == 1:
            log.warning("bad %s message from %s, skipped: %s; further ones of %s are counted, not each logged",
                        message.topic, sender, exc, reason)
        elif is_decade(count):  # the 10th, 100th, ... as the bus logs its refusals
            log.warning("%d bad %s messages of %s skipped so far, the last from %s: %s", count, message.type,
                        reason, sender, exc)

    def handle_command(self, message: Message) -> None:
        """Take one operator message: ``load_model`` asks for another model, a ``command`` with
        action ``reload_model`` for the served one read again; both switch between grasps."""
        if message.type == "load_model":
            self._load_model(message)
            return
        if message.type != "command" or message.fields.action != "reload_model":
            return  # the robot node's
        self.stats.reload_requests += 1
        if self.model is None:
            log.warning("reload_model from %s: this service runs without a model", message.source or "?")
            return
        model_log.info("reload_model from %s: reading %s again, switching between grasps", message.source or "?",
                       self.model.model_dir)
        self.model.request_reload()

    def _load_model(self, message: Message) -> None:
        """A ``load_model``: check the folder in the background, switch between grasps, answer with a
        ``model_event``. A request already taken is not loaded again; one already answered is
        answered again (the sender may have missed it)."""
        load = message.fields
        path, request = load.path, load.request
        if request in self._requests:
            answer = self._requests[request]
            if answer is not None:
                self._send_model_event(answer)
            return
        self.stats.load_requests += 1
        self._requests[request] = None
        while len(self._requests) > REMEMBERED_REQUESTS:
            self._requests.popitem(last=False)
        model_log.info("load_model %s from %s (request %s): checking it, switching between grasps", path,
                       message.source or "?", request)
        if self.model is None:  # serving without a model so far: a slot for the first one
            self.model = ModelSlot(None, settings=self.settings, calibration=self.calibration)
        self.model.request_load(path, request)

    def _model_event(self, event: ModelEvent) -> None:
        """Count, remember and publish what the model slot did."""
        if event.event == "loaded":
            self.stats.reloads += 1
        else:
            self.stats.model_refusals += 1
        if event.request is not None and event.request in self._requests:
            self._requests[event.request] = event
        self._send_model_event(event)

    def _send_model_event(self, event: ModelEvent) -> None:
        self.publisher.send("model_event", t_capture_s=self.clock(), **event.body())

    # ------------------------------------------------------------------ messages

    def _dispatch(self, message: Message, received_s: float) -> None:
        body = message.fields
        if message.type == "grasp_event":
            if body.event == "start":
                self._open(body.grasp_id, message.t_capture_s, received_s, source=message.source)
            elif body.event == "loading_end":
                self._loading_end(body.grasp_id, message.t_capture_s, received_s)
            else:
                self._close(body.grasp_id, message.t_capture_s, received_s)
            return
        if message.type == "robot_state":
            self._following = body.followed_grasp() or self._following  # kept over other modes
            if self._grasp is not None and self._following == self._grasp.grasp_id:
                self._grasp.stream.mark_follow()
            return
        if message.type not in ("frame", "force", "width"):
            self.stats.ignored += 1
            return
        grasp = self._grasp
        if grasp is None or body.grasp_id != grasp.grasp_id:
            self.stats.ignored += 1
            log.debug("%s of grasp %r: no such grasp open", message.topic, body.grasp_id)
            return
        if grasp.final is not None:
            return  # the hold and the release: nothing more to estimate
        if message.type == "frame" and body.finger not in {s.finger for s in grasp.stream.sensors}:
            # Before the capture times are remembered by topic: a made-up finger must not add one.
            exc = PerceptionError(f"grasp {grasp.grasp_id!r} {message.topic}: no sensor on finger {body.finger!r}: "
                                  f"the rig has {[s.finger for s in grasp.stream.sensors]}")
            exc.reason = "unknown_finger"  # a kind of its own in the log's counts
            raise exc
        check_times(grasp, message)
        grasp.clock_offset_s = min(grasp.clock_offset_s, received_s - message.t_capture_s)
        stream = grasp.stream
        if message.type == "frame":
            if stream.add_frame(body.finger, message.t_capture_s, body.data, body.encoding):
                self._on_frame(grasp, received_s)
            elif stream.frames_not_kept(body.finger) == 1:  # once per grasp and finger, not per frame
                log.warning("grasp %r: frames of finger %r past the %d kept are counted, not kept: its estimates "
                            "rest on those", grasp.grasp_id, body.finger, MAX_GRASP_FRAMES)
            return
        if message.type == "force":
            stream.add_force(body.t_s, body.value_n)
            if not grasp.seen_contact and float(body.value_n.max()) >= CONTACT_HINT * estimator_settings(self.settings).contact_force_n:
                # Contact may show in the force only after the first frames in contact came: measure
                # them now, not in the final estimate (a stiff object loads within a frame or two).
                segment = stream.segment()
                self._remember(grasp, segment)
                if segment:
                    stream.measure_frames(segment)
        else:
            stream.add_width(body.t_s, body.value_m)
        # Segmenting is cheap, but not at 80 Hz for nothing: only once the force may have settled, or
        # after the loading-end marker (the force may show the contact only now).
        if stream.loading_end_s is not None or (
                grasp.seen_contact and stream.newest_force_s >= grasp.t_peak_s + LOADING_SETTLED_S):
            segment = stream.segment()
            self._remember(grasp, segment)
            if stream.loading_complete(segment):
                self._finish(grasp, received_s, segment=segment, by=_ended_by(stream))

    def _open(self, grasp_id: str, t_s: float, received_s: float, *, source: str | None) -> None:
        if self._grasp is not None and self._grasp.grasp_id == grasp_id:
            # A robot node restarted mid-grasp starts it again: a final estimate, an end or a report
            # under this id would be taken for the new grasp's (a renderer would ignore its estimates).
            log.warning("grasp %r starts again while open (the robot node restarted?): dropping what it had, "
                        "with no final estimate, end or report for it", grasp_id)
            self._grasp = None
        elif self._grasp is not None:
            log.warning("grasp %r starts while %r is open: closing that one", grasp_id, self._grasp.grasp_id)
            self._close(self._grasp.grasp_id, t_s, received_s)
        stream = GraspStream(settings=self.settings, calibration=self.calibration, methods=self.methods,
                             grasp_id=grasp_id)
        slot = self.model
        model = None if slot is None else slot.estimator
        self._grasp = _Grasp(grasp_id=grasp_id, stream=stream, t_start_s=t_s, source=source, model=model,
                             model_id=None if model is None else slot.model_id,
                             model_dir=None if model is None else str(slot.model_dir))
        if self._following is not None and self._following == grasp_id:
            stream.mark_follow()  # the robot said so before the start reached us
        self.stats.grasps += 1

    def _close(self, grasp_id: str, t_s: float, received_s: float) -> None:
        grasp = self._grasp
        if grasp is None or grasp.grasp_id != grasp_id:
            self.stats.ignored += 1
            if grasp_id in self._closed:  # its final and end went out already
                log.warning("end of grasp %r, which was closed already", grasp_id)
            else:
                self._end_unseen(grasp_id, t_s, received_s)
            return
        try:
            if grasp.final is None:
                self._finish(grasp, received_s, by="grasp_end", end_s=t_s)
            self._send_end(grasp, t_s)
        finally:  # whatever failed, the next grasp finds none open
            self._grasp = None
            self._closed.append(grasp_id)

    def _end_unseen(self, grasp_id: str, t_s: float, received_s: float) -> None:
        """The end of a grasp whose start this service never saw (it started mid-grasp): a refusal
        as its final, then its report and end, or the renderer, which learns of ends only from
        here, would hold the grasp's last estimate from the service before."""
        log.warning("end of grasp %r, whose start this service never saw (it started after the grasp "
                    "began): refusing an estimate", grasp_id)
        stream = GraspStream(settings=self.settings, calibration=self.calibration, methods=self.methods,
                             grasp_id=grasp_id)
        grasp = _Grasp(grasp_id=grasp_id, stream=stream, t_start_s=t_s, source=None, model=None)
        grasp.final = Estimate.refuse(self.methods[0], "the estimator service started after this grasp "
                                                       "began: it has none of the grasp's data")
        grasp.final_by, grasp.final_t_data_s = "grasp_end", t_s
        grasp.final_s = self._publish(grasp, grasp.final, t_s, received_s, provisional=False, by_model=False)
        self._closed.append(grasp_id)
        self._send_end(grasp, t_s)

    def _send_end(self, grasp: _Grasp, t_s: float) -> None:
        self.report.write(self._summary(grasp))  # before the end goes out: readers of both find it
        self.publisher.send("grasp_event", t_capture_s=t_s, event="end", grasp_id=grasp.grasp_id)

    def _loading_end(self, grasp_id: str, t_s: float, received_s: float) -> None:
        grasp = self._grasp
        if grasp is None or grasp.grasp_id != grasp_id:
            self.stats.ignored += 1
            log.warning("loading end of grasp %r, which is not open", grasp_id)
            return
        grasp.stream.mark_loading_end(t_s)
        if grasp.final is None and grasp.stream.loading_complete():  # else at the peak frame
            self._finish(grasp, received_s, by="loading_end")

    def _remember(self, grasp: _Grasp, segment: Segment) -> None:
        if segment:
            grasp.seen_contact = True
            grasp.t_peak_s = segment.t_peak_s
            grasp.t_contact_s = segment.t_contact_s

    def _on_frame(self, grasp: _Grasp, received_s: float) -> None:
        stream = grasp.stream
        segment = stream.segment()
        self._remember(grasp, segment)
        if not segment:
            return  # no contact yet: the grasp is not loading
        if stream.loading_complete(segment):
            self._finish(grasp, received_s, segment=segment, by=_ended_by(stream))
            return
        if stream.follow and grasp.model is not None:
            # An operator's grasp has its final only when the operator lets go: meanwhile the display
            # follows the model's answer over the loading so far, which the final will be.
            stream.measure_frames(segment)
            started = time.perf_counter()
            estimate, by_model = self._best_estimate(grasp, segment)
            estimate = estimate.with_latency(time.perf_counter() - started)
            self._publish(grasp, estimate, stream.last_loading_frame_s(segment), received_s, provisional=True,
                          by_model=by_model)
        else:
            result = stream.estimate(segment)
            self._publish(grasp, result.estimate, result.t_data_s, received_s, provisional=True, by_model=False)
        if grasp.model is not None and _reads_stream_depths(grasp.model.predictor.variant):
            # Ahead of the final estimate, which then reduces only the peak frame's depth.
            stream.reduce_depths(grasp.model.predictor.variant.size_px, grasp.model.predictor.variant.window_m)

    def _finish(self, grasp: _Grasp, received_s: float, *, by: str, segment: Segment | None = None,
                end_s: float | None = None) -> None:
        """The final estimate: the model's when one is pinned to the grasp, else (or when the
        model fails) the analytical one; stamped with the newest data's time, or for a grasp that
        sent none the time of its end (``end_s``)."""
        started = time.perf_counter()
        stream = grasp.stream
        segment = stream.segment() if segment is None else segment
        estimate, by_model = self._best_estimate(grasp, segment)
        grasp.final, grasp.final_by, grasp.final_by_model = estimate, by, by_model
        t_data_s = stream.last_loading_frame_s(segment)
        if not math.isfinite(t_data_s) and end_s is not None:
            t_data_s = end_s
        grasp.final_t_data_s, grasp.loading_frames = t_data_s, int(segment.frame_t_s.size)
        grasp.final_compute_s = time.perf_counter() - started
        grasp.final_s = self._publish(grasp, estimate, grasp.final_t_data_s, received_s, provisional=False,
                                      by_model=by_model)

    def _best_estimate(self, grasp: _Grasp, segment: Segment) -> tuple[Estimate, bool]:
        """The model's estimate when one is pinned to the grasp, else (or when the model fails) the
        analytical one; and whether the model made it."""
        failure = None
        if grasp.model is not None:
            try:
                # The one measurement path: a depth model reads the depths cached for the provisional estimates.
                return grasp.model.estimate_stream(grasp.stream, mode=self.model.mode), True
            except _BAD_INPUT as exc:
                log.warning("grasp %r: the model gives no estimate (%s); publishing the analytical one",
                            grasp.grasp_id, exc)
                failure = exc
        estimate = grasp.stream.estimate(segment).estimate
        return (estimate if failure is None else estimate.with_note(f"model failed: {failure}")), False

    def _publish(self, grasp: _Grasp, estimate: Estimate, t_data_s: float, received_s: float, *,
                 provisional: bool, by_model: bool) -> float:
        """Send an estimate (``by_model``: the grasp's model made it, and the estimate names it);
        returns the clock time it went out."""
        reason = _cut(estimate.reason)
        low, high = estimate.interval_pa
        now = self.clock()
        self.publisher.send(
            "estimate", t_capture_s=t_data_s, grasp_id=grasp.grasp_id, method=estimate.method,
            E_pa=estimate.e_pa, interval_pa=[low, high], state=estimate.state, reason=reason,
            provisional=provisional, latency_s=max(0.0, now - received_s),
            model=grasp.model_id if by_model else None,
        )
        if estimate and grasp.first_estimate_s is None:
            grasp.first_estimate_s, grasp.first_offset_s = now, grasp.clock_offset_s
        if provisional:
            grasp.provisional_s.append(now)
            self.stats.provisional += 1
        else:
            self.stats.final += 1
        return now

    def _summary(self, grasp: _Grasp) -> dict[str, Any]:
        """The grasp's report line: ``t_*`` on the capture clock, ``*_sent_s`` on the service's."""
        sent = grasp.provisional_s
        contact = grasp.t_contact_s
        return {
            "grasp_id": grasp.grasp_id,
            "t_contact_s": contact,
            "time_to_first_estimate_s": (None if contact is None or grasp.first_estimate_s is None
                                         else grasp.first_estimate_s - grasp.first_offset_s - contact),
            "provisional": len(sent),
            "provisional_span_s": sent[-1] - sent[0] if len(sent) > 1 else None,
            "final": None if grasp.final is None else grasp.final.to_json(),
            "t_last_loading_frame_s": grasp.final_t_data_s,
            "t_loading_end_s": grasp.stream.loading_end_s,
            "final_by": grasp.final_by,
            "final_compute_s": grasp.final_compute_s,
            "final_sent_s": grasp.final_s,
            "loading_frames": grasp.loading_frames,
            "model": grasp.model_id if grasp.final_by_model else None,  # the final estimate's
            "model_served": grasp.model_id,  # pinned at the grasp's start
            "model_path": grasp.model_dir,
        }


def _reads_stream_depths(variant: Any) -> bool:
    """Whether a model variant's input is the estimator finger's depths the stream caches."""
    return variant.image == "depth" and not variant.markers


def _ended_by(stream: GraspStream) -> str:
    """What told the loading is over: the robot's marker, or the data alone (module docstring)."""
    return "loading_end" if stream.loading_end_s is not None else "settled"
