"""The estimator service's model slot: the learned model it serves, swapped only between grasps.

:class:`ModelSlot` loads and checks candidate models in a background thread and
:class:`ModelEvent` says what it did with each; the service (:mod:`estimator.service`) polls the
slot from its loop and publishes the events.

Every estimate names the learned model that made it (``model``: its
:func:`~estimator.inference.infer.model_id`, ``"<folder>-<hash>"``; nil for an analytical estimate),
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
inference on the shipped reference grasp, :mod:`estimator.inference.reference`), then switched to
between grasps. A candidate that fails any check is refused and the model in use stays. Either
way the service says so in a ``model_event`` on its estimate endpoint ("loaded" with the new id,
or "refused" with the reason; ``request`` echoes the ``load_model``'s) and in its log, at INFO
for a switch and WARNING for a refusal (``estimator serve`` shows both at its default level).
Other command actions are the robot node's and are ignored here.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from estimator.errors import EstimatorError, ModelError
from estimator.perception.calibration import Calibration
from teleop.bus.wire import MAX_STR_CHARS
from teleop.errors import TeleopError
from teleop.settings import Settings

__all__ = ["ModelEvent", "ModelSlot"]

# The service's loggers, named as before the slot had its own module (log configuration and
# `estimator serve` address them by these names).
log = logging.getLogger("estimator.service")
# Model switches and refusals: `estimator serve` shows this logger at INFO at least, whatever its -v.
model_log = logging.getLogger("estimator.service.model")


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
        Directory with ``model.onnx`` and ``metadata.json`` (see :mod:`estimator.inference.infer`),
        or None: no model yet (until a :meth:`request_load`).
    settings : Settings
    calibration : Calibration
        The estimator finger's calibration, handed to the hybrid estimator.
    mode : {"auto", "model"}
        How :class:`~estimator.inference.hybrid.HybridEstimator` answers.
    check_interval_s : float
        How often :meth:`poll` looks at the served folder's files.
    check_reference : bool
        Check each model with one inference on the shipped reference grasp before serving it.

    Attributes
    ----------
    estimator : HybridEstimator or None
        The model served now.
    model_id : str or None
        Its :func:`~estimator.inference.infer.model_id`.

    Raises
    ------
    ModelError
        The model cannot be loaded at start, or fails its checks.
    """

    def __init__(self, model_dir: str | Path | None, *, settings: Settings, calibration: Calibration,
                 mode: str = "auto", check_interval_s: float = 1.0, check_reference: bool = True,
                 clock: Callable[[], float] = time.monotonic):
        from estimator.inference.hybrid import MODES

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
        from estimator.inference.infer import model_id

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
        from estimator.inference.hybrid import HybridEstimator
        from estimator.inference.infer import CompliancePredictor

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

    from estimator.inference.reference import REFERENCE_RECORD, reference_inputs

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
