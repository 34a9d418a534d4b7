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
  (the robot's ``robot_state`` says ``following`` for it: an operator drives the fingers) gets
  provisional estimates for every frame while the operator squeezes, and its final one at the
  grasp's end (:meth:`~estimator.stream.GraspStream.mark_follow`); with a model loaded, its
  provisional estimates are the model's over the loading so far (the operator feels the answer
  while squeezing, not seconds later when letting go). With a model loaded the
  final one is the hybrid ``auto`` estimate (:class:`~estimator.learned.hybrid.HybridEstimator`);
  for a depth model of the estimator's finger its input comes from the depths already computed
  for the provisional estimates and reduced to the model's input size after each of them
  (:meth:`~estimator.stream.GraspStream.sampled_grasp`: the same input the model would measure
  from the grasp record, without measuring a frame again), else the model measures the grasp
  as received. Without a model it is the analytical one;
* the grasp's end event, forwarded on the estimate endpoint after the final estimate, so a
  renderer that listens to estimates alone knows when to let go.

Each estimate message carries its state, interval and reason; ``t_capture_s`` is the capture
time of the newest loading frame its fit used (for the final one: the last loading frame),
``latency_s`` the time from receiving the message that triggered it to publishing it. The
object's name in a start event is never read. The per-grasp report (one JSON line per grasp
to ``report``) says what ended the loading (``final_by``: ``loading_end``, ``settled`` or
``grasp_end``), the marker's time, when the final estimate was sent and how long it took to
compute.

A message that cannot be used (a frame that does not decode or has the wrong size, samples
that are not finite, capture times that go backwards, repeat or jump more than
:data:`MAX_CLOCK_JUMP_S` ahead of the stream's last one, data for a grasp that is not open) is
logged and counted, and the service carries on; so are the refusals of the bus itself (:class:`~teleop.bus.pubsub.Subscriber`).

Models
------
Every estimate names the learned model that made it (``model``: its
:func:`~estimator.learned.infer.model_id`, ``"<folder>-<hash>"``; nil for an analytical estimate),
and so does the per-grasp report. The model is pinned to a grasp at its start: a switch takes
effect from the next grasp on, never during one. The service switches models:

* on a ``load_model`` message on ``bus.command`` (``estimator reload``): the folder it names;
* on SIGHUP, a ``command`` with action ``reload_model``, or :meth:`ModelSlot.request_reload`:
  the folder it serves, read again;
* when the served folder's files change (``model.onnx``, ``metadata.json``): once the id over
  both has stayed the same over two looks :attr:`ModelSlot.check_interval_s` apart, so a folder
  being copied over is never loaded half old, half new.

Each candidate is loaded and checked in a background thread while grasps go on (the metadata,
the ONNX session and its inputs against the metadata, the settings' depth binning, and one
inference on the shipped reference grasp, :mod:`estimator.learned.reference`), then switched to
between grasps. A candidate that fails any check is refused and the model in use stays. Either
way the service says so in a ``model_event`` on its estimate endpoint ("loaded" with the new id,
or "refused" with the reason; ``request`` echoes the ``load_model``'s) and in its log, at INFO
for a switch and WARNING for a refusal (``estimator serve`` shows both at its default level).
Other command actions are the robot node's and are ignored here.

The service is meant to run on one core: start it with ``OPENBLAS_NUM_THREADS=1`` (as
``teleop demo`` does), or BLAS threads fight for the cores and per-frame times jump.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections import OrderedDict, deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2

from estimator.errors import EstimatorError, ModelError, PerceptionError
from estimator.estimate import Estimate
from estimator.perception.calibration import Calibration
from estimator.segment import Segment
from estimator.settings import estimator_settings
from estimator.stream import DEFAULT_METHODS, LOADING_SETTLED_S, GraspStream
from teleop.bus.pubsub import Publisher, Subscriber
from teleop.bus.wire import MAX_STR_CHARS, Message
from teleop.errors import TeleopError
from teleop.live import JsonLines
from teleop.settings import Settings, resolve_path

__all__ = ["COMMAND_TOPICS", "INPUT_TOPICS", "MAX_CLOCK_JUMP_S", "EstimatorService", "ModelEvent", "ModelSlot",
           "ServiceStats", "resolve_model_dir"]

log = logging.getLogger(__name__)
# Model switches and refusals: `estimator serve` shows this logger at INFO at least, whatever its -v.
model_log = logging.getLogger(__name__ + ".model")

INPUT_TOPICS = ("frame", "force", "width", "grasp_event", "robot_state")
# What the service takes from bus.command: reload_model (a command action) and load_model.
COMMAND_TOPICS = ("command", "load_model")
# load_model requests remembered, so a repeated one is answered again and not loaded twice.
REMEMBERED_REQUESTS = 64
# A force batch reaching this share of the contact force may show the contact: segment then.
CONTACT_HINT = 0.5
# Capture clocks are monotonic: a time this far past the stream's last one is a broken clock.
MAX_CLOCK_JUMP_S = 10.0
# A bad message is one of these; anything else is a bug and ends the service.
_BAD_INPUT = (EstimatorError, TeleopError, ValueError, cv2.error)


def resolve_model_dir(option: str | None, settings: Settings) -> Path | None:
    """The model directory to serve: ``option`` ("none": no model), else ``estimator.model_path``
    (relative to ``configs/``; a ``model.onnx`` names its directory), else the shipped default
    model when it exists, else None."""
    from estimator.learned.infer import default_model_dir

    if option == "none":
        return None
    if option:
        path = Path(option)
    elif estimator_settings(settings).model_path:
        path = resolve_path(estimator_settings(settings).model_path)
    else:
        path = default_model_dir()
        if not (path / "model.onnx").is_file():
            return None
    return path.parent if path.suffix == ".onnx" else path


@dataclass(frozen=True)
class ModelEvent:
    """What a :class:`ModelSlot` did with a candidate model: the body of a ``model_event`` message.

    ``event`` is "loaded" (served from the next grasp on) or "refused" (the model in use stays);
    ``request`` the ``load_model`` request it answers (None for a reload of the slot's own);
    ``model`` the id served now (None: none); ``path`` the candidate's folder.
    """

    event: str
    request: str | None
    model: str | None
    path: str | None
    reason: str

    def body(self) -> dict[str, Any]:
        """The ``model_event`` body (reason and path cut to what the bus carries)."""
        return {"event": self.event, "request": self.request, "model": self.model,
                "path": None if self.path is None else _cut(self.path), "reason": _cut(self.reason)}


@dataclass
class _Candidate:
    """A model folder being loaded and checked in the background."""

    path: Path
    request: str | None  # the load_model request, None for a reload of the slot's own
    expect_id: str | None = None  # a file-watch reload: the id that stayed the same over two looks
    done: threading.Event = field(default_factory=threading.Event)
    estimator: Any = None
    model_id: str | None = None
    stamp: Any = None
    error: str | None = None


def _model_folder(path: str | Path) -> Path:
    """A model folder from a path to it or to its ``model.onnx``."""
    path = Path(path)
    return path.parent if path.suffix == ".onnx" else path


class ModelSlot:
    """The learned model a service uses, swapped for a new one only between grasps.

    Candidates (:meth:`request_load`, :meth:`request_reload`, a change of the served files: see
    the module notes) are loaded and checked one at a time in a background thread;
    :meth:`poll`, called by the service's loop, starts them and switches to one that checked out
    only when no grasp is open.

    Parameters
    ----------
    model_dir : path or None
        Directory with ``model.onnx`` and ``metadata.json`` (see :mod:`estimator.learned.infer`),
        or None: no model yet (until a :meth:`request_load`).
    settings : Settings
    calibration : Calibration
        The estimator finger's calibration, handed to the hybrid estimator.
    mode : {"auto", "model"}
        How :class:`~estimator.learned.hybrid.HybridEstimator` answers.
    check_interval_s : float
        How often :meth:`poll` looks at the served folder's files.
    check_reference : bool
        Check each model with one inference on the shipped reference grasp before serving it.

    Attributes
    ----------
    estimator : HybridEstimator or None
        The model served now.
    model_id : str or None
        Its :func:`~estimator.learned.infer.model_id`.

    Raises
    ------
    ModelError
        The model cannot be loaded at start, or fails its checks.
    """

    def __init__(self, model_dir: str | Path | None, *, settings: Settings, calibration: Calibration,
                 mode: str = "auto", check_interval_s: float = 1.0, check_reference: bool = True,
                 clock: Callable[[], float] = time.monotonic):
        from estimator.learned.hybrid import MODES

        if mode not in MODES:
            raise ModelError(f"model mode {mode!r}: expected one of {', '.join(MODES)}")
        self.settings = settings
        self.calibration = calibration
        self.mode = mode
        self.check_interval_s = check_interval_s
        self.check_reference = check_reference
        self.clock = clock
        self.loads = 0
        self.failures = 0
        self.model_dir: Path | None = None
        self.estimator: Any = None
        self.model_id: str | None = None
        self._requested = threading.Event()
        self._queue: deque[_Candidate] = deque()
        self._candidate: _Candidate | None = None  # being loaded, or loaded and waiting for the grasp's end
        self._stamp: Any = None  # the served files' stamp last looked at
        self._watched_id: str | None = None  # the id the files had at the last look, while it differs
        self._refused_id: str | None = None  # files the watch tried and refused: not tried again
        self._checked_s = clock()
        if model_dir is not None:
            loaded = _Candidate(_model_folder(model_dir), None)
            self._build(loaded)
            if loaded.error is not None:
                raise ModelError(loaded.error)
            self._install(loaded)
            model_log.info("serving model %s (%s, %s)", self.model_id, self.model_dir,
                           self.estimator.predictor.variant.name)

    # ------------------------------------------------------------------ requests (any thread)

    def request_reload(self) -> None:
        """Read the served folder again, and switch to it at the next :meth:`poll` between grasps
        once it checks out (thread- and signal-safe)."""
        self._requested.set()

    def request_load(self, path: str | Path, request: str | None = None) -> None:
        """Load the model in ``path`` (a folder, or its ``model.onnx``) and switch to it between
        grasps once it checks out; ``request`` is echoed in the :class:`ModelEvent`."""
        self._queue.append(_Candidate(_model_folder(path), request))

    @property
    def busy(self) -> bool:
        """Whether a candidate is being loaded or waits to be switched to, or requests wait."""
        return self._candidate is not None or bool(self._queue) or self._requested.is_set()

    @property
    def switch_pending(self) -> bool:
        """Whether a candidate checked out and waits for the open grasp's end to be switched to."""
        candidate = self._candidate
        return candidate is not None and candidate.done.is_set() and candidate.error is None

    def wait(self, timeout_s: float) -> bool:
        """Wait up to ``timeout_s`` for the candidate being loaded to be checked; True when none is
        loading now (a test's or a tool's convenience: :meth:`poll` never waits)."""
        candidate = self._candidate
        return candidate is None or candidate.done.wait(timeout_s)

    # ------------------------------------------------------------------ the service's loop

    def poll(self, *, idle: bool) -> ModelEvent | None:
        """Advance the candidates: switch to one that checked out when ``idle`` (no grasp open),
        report one that failed, start the next (a request, or the served files changed and
        then stayed the same over two looks). Returns what happened, if anything."""
        candidate = self._candidate
        if candidate is not None:
            if not candidate.done.is_set() or (candidate.error is None and not idle):
                return None  # still loading, or a grasp is open: never swapped mid-grasp
            self._candidate = None
            return self._settle(candidate)
        if self._queue:
            self._start(self._queue.popleft())
        elif self._requested.is_set():
            self._requested.clear()
            if self.model_dir is None:
                model_log.warning("a reload was asked for, but no model is served: nothing to reload")
            else:
                self._start(_Candidate(self.model_dir, None))
        else:
            self._watch()
        return None

    def _watch(self) -> None:
        """Start a reload of the served folder once its files changed and kept one id over two looks."""
        from estimator.learned.infer import model_id

        now = self.clock()
        if self.model_dir is None or now - self._checked_s < self.check_interval_s:
            return
        self._checked_s = now
        stamp = _file_stamp(self.model_dir)
        if stamp == self._stamp and self._watched_id is None:
            return  # nothing new
        self._stamp = stamp
        try:
            current = model_id(self.model_dir)
        except ModelError:
            current = None  # a file missing: being copied, or gone
        if current in (None, self.model_id, self._refused_id):
            self._watched_id = None
        elif current != self._watched_id:
            self._watched_id = current
            model_log.info("model files in %s changed (now %s): switching once they stay the same",
                           self.model_dir, current)
        else:
            self._watched_id = None
            self._start(_Candidate(self.model_dir, None, expect_id=current))

    def _start(self, candidate: _Candidate) -> None:
        self._candidate = candidate
        threading.Thread(target=self._build, args=(candidate,), name="model-load", daemon=True).start()

    def _build(self, candidate: _Candidate) -> None:
        """Load and check ``candidate`` (in the loader thread); sets its estimator or its error."""
        from estimator.learned.hybrid import HybridEstimator
        from estimator.learned.infer import CompliancePredictor

        try:
            if candidate.path == self.model_dir:
                self._requested.clear()  # this load reads the files after any reload asked so far
            candidate.stamp = _file_stamp(candidate.path)
            predictor = CompliancePredictor(candidate.path)
            candidate.model_id = predictor.model_id
            estimator = HybridEstimator(predictor, settings=self.settings, calibration=self.calibration)
            if self.check_reference:
                _check_on_reference(predictor, self.settings)
            candidate.estimator = estimator
        except ModelError as exc:
            candidate.error = str(exc)
        except Exception as exc:  # a model that breaks the loader in another way is refused all the same
            log.exception("loading model %s failed unexpectedly", candidate.path)
            candidate.error = f"{candidate.path}: loading failed ({type(exc).__name__}: {exc})"
        finally:
            candidate.done.set()

    def _settle(self, candidate: _Candidate) -> ModelEvent | None:
        """Switch to a checked candidate, or refuse a failed one."""
        path = str(candidate.path)
        if candidate.error is not None:
            self.failures += 1
            if candidate.expect_id is not None:
                self._refused_id = candidate.expect_id
            model_log.warning("model %s refused, still serving %s: %s", path, self.model_id or "no model",
                              candidate.error)
            return ModelEvent("refused", candidate.request, self.model_id, path, candidate.error)
        if candidate.expect_id is not None and candidate.model_id != candidate.expect_id:
            model_log.info("model files in %s changed again while loading: waiting for them to stay the same", path)
            self._stamp = None  # look again
            return None
        previous = self.model_id
        self._install(candidate)
        model_log.info("model %s (%s) serves from the next grasp on, in place of %s", self.model_id, path,
                       previous or "no model")
        reason = "switched" if previous != self.model_id else "reloaded (the same files)"
        return ModelEvent("loaded", candidate.request, self.model_id, path,
                          f"{reason}; was {previous or 'no model'}")

    def _install(self, candidate: _Candidate) -> None:
        self.estimator, self.model_id, self.model_dir = candidate.estimator, candidate.model_id, candidate.path
        self._stamp, self._watched_id, self._refused_id = candidate.stamp, None, None
        self.loads += 1


def _file_stamp(folder: Path) -> tuple[tuple[str, int, int], ...] | None:
    """Names, modification times and sizes of a model folder's files (None: the folder is unreadable)."""
    try:
        paths = [folder / "metadata.json", *sorted(folder.glob("*.onnx"))]
        return tuple((p.name, p.stat().st_mtime_ns, p.stat().st_size) for p in paths)
    except OSError:
        return None


def _check_on_reference(predictor: Any, settings: Settings) -> None:
    """One inference on the shipped reference grasp, measured with ``settings``: ModelError unless the
    model gives finite logits. Where the reference cannot be measured with these settings (a rig
    unlike the simulated one), the inference runs on zero inputs of the model's shapes instead: that
    is the code's limit, not the model's."""
    import numpy as np

    from estimator.learned.reference import REFERENCE_RECORD, reference_inputs

    where = f"the reference grasp {REFERENCE_RECORD.name}"
    try:
        batch = reference_inputs(predictor.variant, settings=settings)
    except (EstimatorError, TeleopError, ValueError, OSError) as exc:
        log.warning("the reference grasp cannot be measured with these settings (%s): checking model %s on zero "
                    "inputs instead", exc, predictor.model_dir)
        batch = {name: np.zeros((1, *shape), np.float32) for name, shape in predictor.variant.input_shapes.items()}
        where = "zero inputs"
    try:
        predictor.predict_logits(batch)
    except ModelError as exc:
        raise ModelError(f"model {predictor.model_dir} fails on {where}: {exc}") from exc
    except Exception as exc:  # onnxruntime raises its own untyped errors
        raise ModelError(f"model {predictor.model_dir}: onnxruntime fails on {where} "
                         f"({type(exc).__name__}: {exc})") from exc


def _cut(text: str, limit: int = MAX_STR_CHARS) -> str:
    """``text`` cut to ``limit`` characters (an ellipsis marks the cut)."""
    return text if len(text) <= limit else text[: limit - 1] + "…"


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
    model: Any  # the HybridEstimator pinned at the grasp's start, or None
    model_id: str | None = None  # its id
    model_dir: str | None = None  # its folder
    seen_contact: bool = False
    t_peak_s: float = math.inf  # of the last segmentation with contact
    t_contact_s: float | None = None
    first_estimate_s: float | None = None  # clock time the first non-refusal estimate went out
    provisional_s: list[float] = field(default_factory=list)
    final: Estimate | None = None
    final_s: float | None = None
    final_t_data_s: float | None = None
    final_by: str | None = None  # what ended the loading: loading_end, settled or grasp_end
    final_compute_s: float | None = None
    final_by_model: bool = False  # the grasp's model made the final estimate
    loading_frames: int = 0
    last_t_s: dict[str, float] = field(default_factory=dict)  # newest capture time per topic


class EstimatorService:
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
    """

    def __init__(self, settings: Settings, *, calibration: Calibration, subscriber: Subscriber,
                 publisher: Publisher, methods: Sequence[str] = DEFAULT_METHODS,
                 model: ModelSlot | None = None, report: JsonLines | None = None,
                 commands: Subscriber | None = None, clock: Callable[[], float] = time.monotonic):
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
        self.stats = ServiceStats()
        self._grasp: _Grasp | None = None
        self._following: str | None = None  # the grasp the robot last said it follows an operator in
        # load_model requests taken: None while the candidate is being checked, then its answer.
        self._requests: OrderedDict[str, ModelEvent | None] = OrderedDict()

    # ------------------------------------------------------------------ loop

    def run(self, stop: Any, *, duration_s: float | None = None, poll_s: float = 0.05) -> ServiceStats:
        """Serve until ``stop.is_set()`` or ``duration_s`` passed."""
        deadline = None if duration_s is None else self.clock() + duration_s
        while not stop.is_set() and (deadline is None or self.clock() < deadline):
            self.step(poll_s)
        return self.stats

    def step(self, timeout_s: float = 0.05) -> Message | None:
        """Take commands; receive and handle at most one message (waiting up to ``timeout_s``);
        heartbeat; reload."""
        self.publisher.heartbeat_if_due(self.clock())
        while self.commands is not None and (command := self.commands.recv(timeout_s=0)) is not None:
            self.handle_command(command)
        message = self.subscriber.recv(timeout_s=timeout_s)
        if message is not None:
            self.handle(message, received_s=self.clock())
        if self.model is not None:
            event = self.model.poll(idle=self._grasp is None)
            if event is not None:
                self._model_event(event)
        return message

    def handle(self, message: Message, *, received_s: float) -> None:
        """Handle one message; a message that cannot be used is logged and counted."""
        self.stats.messages += 1
        try:
            self._dispatch(message, received_s)
        except _BAD_INPUT as exc:
            self.stats.bad_messages += 1
            log.warning("bad %s message from %s (seq %d), skipped: %s", message.topic, message.source or "?",
                        message.seq, exc)

    def handle_command(self, message: Message) -> None:
        """Take one operator message: ``load_model`` asks for another model, a ``command`` with
        action ``reload_model`` for the served one read again; both switch between grasps."""
        if message.type == "load_model":
            self._load_model(message)
            return
        if message.type != "command" or message.body["action"] != "reload_model":
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
        path, request = message.body["path"], message.body["request"]
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
        body = message.body
        if message.type == "grasp_event":
            if body["event"] == "start":
                self._open(body["grasp_id"], message.t_capture_s, received_s)
            elif body["event"] == "loading_end":
                self._loading_end(body["grasp_id"], message.t_capture_s, received_s)
            else:
                self._close(body["grasp_id"], message.t_capture_s, received_s)
            return
        if message.type == "robot_state":
            self._following = body["grasp_id"] if body["mode"] == "following" else self._following
            if self._grasp is not None and self._following == self._grasp.grasp_id:
                self._grasp.stream.mark_follow()
            return
        if message.type not in ("frame", "force", "width"):
            self.stats.ignored += 1
            return
        grasp = self._grasp
        if grasp is None or body["grasp_id"] != grasp.grasp_id:
            self.stats.ignored += 1
            log.debug("%s of grasp %r: no such grasp open", message.topic, body["grasp_id"])
            return
        if grasp.final is not None:
            return  # the hold and the release: nothing more to estimate
        _check_times(grasp, message)
        stream = grasp.stream
        if message.type == "frame":
            if stream.add_frame(body["finger"], message.t_capture_s, body["data"], body["encoding"]):
                self._on_frame(grasp, received_s)
            return
        if message.type == "force":
            stream.add_force(body["t_s"], body["value_n"])
            if not grasp.seen_contact and float(body["value_n"].max()) >= CONTACT_HINT * estimator_settings(self.settings).contact_force_n:
                # Contact may show in the force only after the first frames in contact came: measure
                # them now, not in the final estimate (a stiff object loads within a frame or two).
                segment = stream.segment()
                self._remember(grasp, segment)
                if segment:
                    stream.measure_frames(segment)
        else:
            stream.add_width(body["t_s"], body["value_m"])
        # Segmenting is cheap, but not at 80 Hz for nothing: only once the force may have settled, or
        # after the loading-end marker (the force may show the contact only now).
        if stream.loading_end_s is not None or (
                grasp.seen_contact and stream.newest_force_s >= grasp.t_peak_s + LOADING_SETTLED_S):
            segment = stream.segment()
            self._remember(grasp, segment)
            if stream.loading_complete(segment):
                self._finish(grasp, received_s, segment=segment, by=_ended_by(stream))

    def _open(self, grasp_id: str, t_s: float, received_s: float) -> None:
        if self._grasp is not None:
            log.warning("grasp %r starts while %r is open: closing that one", grasp_id, self._grasp.grasp_id)
            self._close(self._grasp.grasp_id, t_s, received_s)
        stream = GraspStream(settings=self.settings, calibration=self.calibration, methods=self.methods,
                             grasp_id=grasp_id)
        slot = self.model
        model = None if slot is None else slot.estimator
        self._grasp = _Grasp(grasp_id=grasp_id, stream=stream, model=model,
                             model_id=None if model is None else slot.model_id,
                             model_dir=None if model is None else str(slot.model_dir))
        if self._following is not None and self._following == grasp_id:
            stream.mark_follow()  # the robot said so before the start reached us
        self.stats.grasps += 1

    def _close(self, grasp_id: str, t_s: float, received_s: float) -> None:
        grasp = self._grasp
        if grasp is None or grasp.grasp_id != grasp_id:
            self.stats.ignored += 1
            log.warning("end of grasp %r, which is not open", grasp_id)
            return
        if grasp.final is None:
            self._finish(grasp, received_s, by="grasp_end")
        self.report.write(self._summary(grasp))  # before the end goes out: readers of both find it
        self.publisher.send("grasp_event", t_capture_s=t_s, event="end", grasp_id=grasp_id)
        self._grasp = None

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

    def _finish(self, grasp: _Grasp, received_s: float, *, by: str, segment: Segment | None = None) -> None:
        """The final estimate: the model's when one is pinned to the grasp, else (or when the
        model fails) the analytical one."""
        started = time.perf_counter()
        stream = grasp.stream
        segment = stream.segment() if segment is None else segment
        estimate, by_model = self._best_estimate(grasp, segment)
        grasp.final, grasp.final_by, grasp.final_by_model = estimate, by, by_model
        grasp.final_t_data_s, grasp.loading_frames = stream.last_loading_frame_s(segment), int(segment.frame_t_s.size)
        grasp.final_compute_s = time.perf_counter() - started
        grasp.final_s = self._publish(grasp, estimate, grasp.final_t_data_s, received_s, provisional=False,
                                      by_model=by_model)

    def _best_estimate(self, grasp: _Grasp, segment: Segment) -> tuple[Estimate, bool]:
        """The model's estimate when one is pinned to the grasp, else (or when the model fails) the
        analytical one; and whether the model made it."""
        failure = None
        if grasp.model is not None:
            try:
                return self._model_estimate(grasp, segment), True
            except _BAD_INPUT as exc:
                log.warning("grasp %r: the model gives no estimate (%s); publishing the analytical one",
                            grasp.grasp_id, exc)
                failure = exc
        estimate = grasp.stream.estimate(segment).estimate
        return (estimate if failure is None else estimate.with_note(f"model failed: {failure}")), False

    def _model_estimate(self, grasp: _Grasp, segment: Segment) -> Estimate:
        """The pinned model's estimate; a depth model of the estimator's finger reads the cached depths."""
        model, mode = grasp.model, self.model.mode
        variant = model.predictor.variant
        if _reads_stream_depths(variant):
            started = time.perf_counter()
            sampled = grasp.stream.sampled_grasp(n_frames=variant.n_frames, size_px=variant.size_px, segment=segment,
                                                 window_m=variant.window_m)
            if sampled:  # else the model's own answer without a tactile sample, from the record
                return model.estimate_sampled(sampled, mode=mode).with_latency(time.perf_counter() - started)
        return model.estimate(grasp.stream.to_record(), mode=mode)

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
            grasp.first_estimate_s = now
        if provisional:
            grasp.provisional_s.append(now)
            self.stats.provisional += 1
        else:
            self.stats.final += 1
        return now

    def _summary(self, grasp: _Grasp) -> dict[str, Any]:
        """The grasp's report line; times are seconds on the service's (= the capture) clock."""
        sent = grasp.provisional_s
        contact = grasp.t_contact_s
        return {
            "grasp_id": grasp.grasp_id,
            "t_contact_s": contact,
            "time_to_first_estimate_s": (None if contact is None or grasp.first_estimate_s is None
                                         else grasp.first_estimate_s - contact),
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


def _check_times(grasp: _Grasp, message: Message) -> None:
    """Raise PerceptionError unless the message's capture times go strictly forward from the
    topic's last ones without a jump of more than MAX_CLOCK_JUMP_S; then remember the newest."""
    times = [message.t_capture_s] if message.type == "frame" else message.body["t_s"].tolist()
    last = grasp.last_t_s.get(message.topic, -math.inf)
    steps = [b - a for a, b in zip([last, *times], times, strict=False)]
    where = f"grasp {grasp.grasp_id!r} {message.topic} capture times {times[0]:.6f}..{times[-1]:.6f} s"
    if min(steps) <= 0:
        raise PerceptionError(f"{where}: not after the previous one ({last:.6f} s): out of order or repeated")
    if math.isfinite(last) and max(steps) > MAX_CLOCK_JUMP_S:
        raise PerceptionError(f"{where}: jump {max(steps):.3g} s past the previous one ({last:.6f} s), "
                              f"more than {MAX_CLOCK_JUMP_S:g} s: the capture clock is broken")
    grasp.last_t_s[message.topic] = times[-1]
