"""The bus's message types: one frozen dataclass per type, its body.

Each type's class (:data:`BODIES`, by type name) is the one definition of the type: its body
fields in wire order, each with its check (:func:`~teleop.bus.field_checks.scalar`,
:func:`~teleop.bus.field_checks.array`), what they mean (its docstring), and the rule between
them (its ``cross_check``). Everything else is derived from the classes: :data:`SCHEMAS`, which
:mod:`teleop.bus.wire` checks every body against (and re-exports with these names), a message's
typed view (:attr:`teleop.bus.wire.Message.fields`, one of these classes), and the session log's
JSON Schemas (:mod:`teleop.session.foxglove`).

A field a sender may leave out is nil when it does (its default is None); a field marked
``added_later`` came after its type and reads as nil in a message without it. Array fields
travel as buffers beside the msgpack body (:mod:`teleop.bus.wire`).

Adding a message type changes no existing message, so it keeps the version: a receiver that
predates a type refuses its messages as ``unknown_type`` and goes on with the rest.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from typing import Any, ClassVar

import numpy as np

from teleop.bus.field_checks import (
    FLAG,
    INTERVAL,
    MAX_TIME_S,
    ArrayField,
    IntegerField,
    NumberField,
    NumberMapField,
    Schema,
    TextField,
    array,
    scalar,
)
from teleop.errors import MessageRejected
from teleop.labels import LABEL_SOURCES
from teleop.states import ESTIMATE_STATES

__all__ = [
    "BODIES",
    "COMMAND_ACTIONS",
    "DISPLAY_DEVICE_STATES",
    "DISPLAY_FAULTS",
    "DISPLAY_PHASES",
    "ENDING_NOTICES",
    "ESTIMATE_STATES",
    "INTERVAL_TOLERANCE",
    "MAX_MODEL_ID_CHARS",
    "MAX_PARAMS",
    "MAX_STR_CHARS",
    "MODEL_EVENTS",
    "ROBOT_MODES",
    "ROBOT_NOTICES",
    "SCHEMAS",
    "Body",
    "CommandBody",
    "DisplayBody",
    "EstimateBody",
    "FollowBody",
    "ForceBody",
    "FrameBody",
    "GraspEventBody",
    "HeartbeatBody",
    "LabelBody",
    "LoadModelBody",
    "ModelEventBody",
    "RobotNoticeBody",
    "RobotStateBody",
    "WidthBody",
]

MAX_STR_CHARS = 1024
MAX_PARAMS = 32

# The robot node carries out the first three; the estimator service the last.
COMMAND_ACTIONS = ("start_grasp", "stop", "release", "reload_model")

# The haptic renderer's phases (haptics.renderer.HapticRenderer.phase).
DISPLAY_PHASES = ("idle", "active", "stale", "fading")
# The softness display's own states and fault names, as its status reports give them
# (haptics/PROTOCOL.md, INPUT report 0x03: haptics.protocol.DEVICE_STATES and FAULT_BITS, in bit order).
DISPLAY_DEVICE_STATES = ("free", "rendering", "fault", "watchdog")
DISPLAY_FAULTS = ("over_temperature", "over_current", "position_error", "undervoltage", "bad_report")

# The robot node's modes (robot_state) and the notices it sends (robot_notice).
ROBOT_MODES = ("idle", "grasping", "holding", "releasing", "following", "stopped")
ROBOT_NOTICES = ("refused", "watchdog", "force_limit", "device")
# The notices that end the grasp they name: the watchdog's (the fingers stopped), and a device
# notice, which names a grasp only when the gripper's command failed and ended it (teleop.node);
# refused and force_limit leave the grasp running.
ENDING_NOTICES = ("watchdog", "device")
# What the estimator service says of its model: it serves another now, or it kept the one it had.
MODEL_EVENTS = ("loaded", "refused")
MAX_MODEL_ID_CHARS = 64

# Timestamps stay float64: float32 would round monotonic seconds (~1e5 s) to ~8 ms.
_TIMES = ArrayField(("<f8",), (1,), finite=True, max_abs=MAX_TIME_S)
_VALUES = ArrayField(("<f8", "<f4"), (1,), finite=True)
_GRASP = TextField(nullable=True)  # the grasp a message belongs to; nil: none
_MAGIC = {"jpeg": b"\xff\xd8", "png": b"\x89PNG"}

# Every body class: immutable, compact (slots), built with its fields named.
_body = dataclasses.dataclass(frozen=True, slots=True, kw_only=True)


class Body:
    """What the body dataclass of every message type shares.

    A body holds every field of its type, arrays included (numpy arrays; read-only views over
    the received frames after :func:`teleop.bus.wire.decode`).
    """

    __slots__ = ()
    kind: ClassVar[str]  # the message type

    def as_dict(self) -> dict[str, Any]:
        """The fields by name, values as they are (arrays neither copied nor converted): for a
        JSON report, not for reading a field."""
        return {item.name: getattr(self, item.name) for item in dataclasses.fields(self)}


def _one_length(t_s: np.ndarray, name: str, values: np.ndarray) -> None:
    if t_s.shape != values.shape or t_s.shape[0] == 0:
        raise MessageRejected("mistyped_field", f"t_s {t_s.shape} and {name} {values.shape} must be one length >= 1")


@_body
class FrameBody(Body):
    """``frame``: one image of a finger's tactile camera (topic ``frame/<finger>``).

    Attributes
    ----------
    finger : str
        Which finger's camera.
    grasp_id : str or None
    index : int
        The camera's frame number, >= 0.
    encoding : {"jpeg", "png", "raw"}
    data : numpy.ndarray
        The image as captured: for jpeg and png the file's bytes, uint8 1-D; for raw,
        H x W x 3 BGR (H, W >= 1), uint8 or uint16.
    """

    kind: ClassVar[str] = "frame"
    finger: str = scalar(TextField(max_chars=32))
    grasp_id: str | None = scalar(_GRASP)
    index: int = scalar(IntegerField())
    encoding: str = scalar(TextField(choices=("jpeg", "png", "raw")))
    data: np.ndarray = array(ArrayField(("|u1", "<u2"), (1, 3)))

    def cross_check(self) -> None:
        """Refuse data that is not what the encoding says, or an empty image."""
        data, encoding = self.data, self.encoding
        if encoding == "raw":
            if data.ndim != 3 or data.shape[2] != 3:
                raise MessageRejected("mistyped_field", f"raw frame data has shape {data.shape}: expected H x W x 3")
            if data.size == 0:
                raise MessageRejected("mistyped_field", f"frame.data is empty (shape {data.shape}): a raw image "
                                                        "needs H and W >= 1")
        elif data.ndim != 1 or data.dtype != np.uint8 or data[: len(_MAGIC[encoding])].tobytes() != _MAGIC[encoding]:
            raise MessageRejected("mistyped_field", f"frame data is not a 1-D {encoding} byte string")


@_body
class ForceBody(Body):
    """``force``: samples of the gripper's grasp force.

    Attributes
    ----------
    grasp_id : str or None
    t_s : numpy.ndarray
        Sample times (s, float64), 1-D, finite, as long as ``value_n`` (>= 1).
    value_n : numpy.ndarray
        Forces (N, float64 or float32), 1-D, finite.
    """

    kind: ClassVar[str] = "force"
    grasp_id: str | None = scalar(_GRASP)
    t_s: np.ndarray = array(_TIMES)
    value_n: np.ndarray = array(_VALUES)

    def cross_check(self) -> None:
        """Refuse times and values of different lengths, or none."""
        _one_length(self.t_s, "value_n", self.value_n)


@_body
class WidthBody(Body):
    """``width``: samples of the gripper's finger opening.

    Attributes
    ----------
    grasp_id : str or None
    t_s : numpy.ndarray
        Sample times (s), as :attr:`ForceBody.t_s`.
    value_m : numpy.ndarray
        Widths (m), as :attr:`ForceBody.value_n`.
    """

    kind: ClassVar[str] = "width"
    grasp_id: str | None = scalar(_GRASP)
    t_s: np.ndarray = array(_TIMES)
    value_m: np.ndarray = array(_VALUES)

    def cross_check(self) -> None:
        """Refuse times and values of different lengths, or none."""
        _one_length(self.t_s, "value_m", self.value_m)


@_body
class GraspEventBody(Body):
    """``grasp_event``: a grasp starts, has loaded, or ends.

    ``loading_end``: the gripper's grasp command completed (the fingers stopped at the target
    force) at the message's ``t_capture_s``; the width read then went out just before it as a
    ``width`` message.

    Attributes
    ----------
    event : {"start", "loading_end", "end"}
    grasp_id : str
    object_name : str or None
        The object grasped, when the sender knows it.
    """

    kind: ClassVar[str] = "grasp_event"
    event: str = scalar(TextField(choices=("start", "loading_end", "end")))
    grasp_id: str = scalar(TextField())
    object_name: str | None = scalar(TextField(nullable=True))


#: Relative tolerance of an estimate's "E_pa within its interval_pa": the estimator may round the bound
#: and the value differently. The renderer's (haptics.mapping.EstimateUpdate) is the same.
INTERVAL_TOLERANCE = 1e-9


@_body
class EstimateBody(Body):
    """``estimate``: the estimator's modulus for a grasp, provisional while it loads, then final.

    Attributes
    ----------
    grasp_id : str
    method : str
        The estimation method that made it.
    E_pa : float or None
        Young's modulus (Pa, > 0); given for ``ok``, nil for ``insufficient_data``.
    interval_pa : [low, high]
        Its uncertainty interval (Pa): each > 0, or nil for an open side; low <= high.
    state : {"ok", "lower_bound", "upper_bound", "insufficient_data"}
    reason : str
        Why the state is what it is, in words.
    provisional : bool
        Made while the squeeze was still loading.
    latency_s : float
        Computing time (s, >= 0).
    model : str or None
        The id of the learned model that made it; nil: none did. It came after the type: an
        estimate without it (an older sender, an older session log) reads as nil.
    """

    kind: ClassVar[str] = "estimate"
    grasp_id: str = scalar(TextField())
    method: str = scalar(TextField(max_chars=64))
    E_pa: float | None = scalar(NumberField(lo=0.0, lo_open=True, nullable=True), required=True)
    interval_pa: list[float | None] = scalar(INTERVAL)
    state: str = scalar(TextField(choices=ESTIMATE_STATES))
    reason: str = scalar(TextField(max_chars=MAX_STR_CHARS))
    provisional: bool = scalar(FLAG)
    latency_s: float = scalar(NumberField(lo=0.0))
    model: str | None = scalar(TextField(max_chars=MAX_MODEL_ID_CHARS, nullable=True), added_later=True)

    def cross_check(self) -> None:
        """Refuse an ``ok`` without a modulus, a bound state with neither a modulus nor its bound, an
        ``insufficient_data`` with a modulus, or a modulus outside its own interval (beyond a relative
        :data:`INTERVAL_TOLERANCE`): the renderer reads them so."""
        if self.state == "ok" and self.E_pa is None:
            raise MessageRejected("mistyped_field", "estimate with state 'ok' has no E_pa")
        bound_side = {"lower_bound": 0, "upper_bound": 1}.get(self.state)
        if bound_side is not None and self.E_pa is None and self.interval_pa[bound_side] is None:
            raise MessageRejected("mistyped_field", f"estimate with state {self.state!r} has neither E_pa nor "
                                                    f"its bound in interval_pa {self.interval_pa}")
        if self.state == "insufficient_data" and self.E_pa is not None:
            raise MessageRejected("mistyped_field", "estimate with state 'insufficient_data' carries an E_pa")
        e_pa, (low, high) = self.E_pa, self.interval_pa
        if e_pa is not None and ((low is not None and e_pa < low * (1 - INTERVAL_TOLERANCE)) or (
                high is not None and e_pa > high * (1 + INTERVAL_TOLERANCE))):
            raise MessageRejected("mistyped_field",
                                  f"estimate E_pa = {e_pa} lies outside its interval_pa [{low}, {high}]")


@_body
class LabelBody(Body):
    """``label``: what the grasped object is (operator -> all, on ``bus.command``; also written into
    a session log after the fact by ``teleop label``).

    Attributes
    ----------
    grasp_id : str
    object_name : str
    modulus_pa : float or None
        Its Young's modulus (Pa, > 0); nil: the catalogue's.
    source : str
        One of :data:`teleop.labels.LABEL_SOURCES`.
    detail : str
        E.g. the Shore hardness read and the conversion used.
    """

    kind: ClassVar[str] = "label"
    grasp_id: str = scalar(TextField())
    object_name: str = scalar(TextField(max_chars=128))
    modulus_pa: float | None = scalar(NumberField(lo=0.0, lo_open=True, nullable=True))
    source: str = scalar(TextField(choices=LABEL_SOURCES))
    detail: str = scalar(TextField(max_chars=MAX_STR_CHARS))


@_body
class LoadModelBody(Body):
    """``load_model``: switch the estimator service to another model (operator -> estimator, on
    ``bus.command``).

    Attributes
    ----------
    path : str
        The model folder on the estimator's host.
    request : str
        Echoed in the answer (:class:`ModelEventBody`).
    """

    kind: ClassVar[str] = "load_model"
    path: str = scalar(TextField(max_chars=MAX_STR_CHARS))
    request: str = scalar(TextField(max_chars=64))


@_body
class ModelEventBody(Body):
    """``model_event``: what the estimator service did with its model (estimator, on its
    ``estimate_pub``).

    Attributes
    ----------
    event : str
        One of :data:`MODEL_EVENTS`: ``loaded`` (it serves another model from now on) or
        ``refused`` (it kept the one it had).
    request : str or None
        The ``load_model`` it answers; nil for a reload of its own.
    model : str or None
        The id of the model it serves now.
    path : str or None
    reason : str
    """

    kind: ClassVar[str] = "model_event"
    event: str = scalar(TextField(choices=MODEL_EVENTS))
    request: str | None = scalar(TextField(max_chars=64, nullable=True))
    model: str | None = scalar(TextField(max_chars=MAX_MODEL_ID_CHARS, nullable=True))
    path: str | None = scalar(TextField(max_chars=MAX_STR_CHARS, nullable=True))
    reason: str = scalar(TextField(max_chars=MAX_STR_CHARS))


@_body
class CommandBody(Body):
    """``command``: a discrete operator command.

    Attributes
    ----------
    action : str
        One of :data:`COMMAND_ACTIONS`: ``start_grasp``, ``stop``, ``release`` (the robot node's)
        or ``reload_model`` (the estimator service's: read its learned model again between grasps).
    grasp_id : str or None
    params : dict of str to float
        Named finite numbers (e.g. ``target_force_n``), at most :data:`MAX_PARAMS`.
    """

    kind: ClassVar[str] = "command"
    action: str = scalar(TextField(choices=COMMAND_ACTIONS))
    grasp_id: str | None = scalar(_GRASP)
    params: Mapping[str, float] = scalar(NumberMapField(max_items=MAX_PARAMS))


@_body
class HeartbeatBody(Body):
    """``heartbeat``: the sender is alive.

    Attributes
    ----------
    interval_s : float
        The sender's heartbeat period (s, > 0).
    """

    kind: ClassVar[str] = "heartbeat"
    interval_s: float = scalar(NumberField(lo=0.0, lo_open=True))


@_body
class DisplayBody(Body):
    """``display``: what the haptic renderer wrote to the softness display, one per report written
    (``haptics serve``, on ``bus.display_pub``; ``t_capture_s`` is the write time on the
    renderer's clock).

    Attributes
    ----------
    grasp_id : str or None
        Nil when idle.
    phase : str
        One of :data:`DISPLAY_PHASES`.
    stiffness : float
        Fraction of the display's range in [0, 1]; 1 is the rigid end.
    uncertainty_decades : float
        >= 0.
    rigid, unknown : bool
        Not both.
    provisional : bool
    E_pa : float or None
        The modulus (Pa, > 0) the stiffness stands for on the display's range; nil exactly when
        the stiffness is 0 or ``unknown`` is set.
    level : int or None
        The quantised level written (>= 0, <= ``level_max``; needs ``level_max``).
    level_max : int or None
        The display's full scale (>= 1).
    device_state : str or None
        What the display itself said last in its status report (one of
        :data:`DISPLAY_DEVICE_STATES`): ``fault`` (its actuator disabled, level 0) or ``watchdog``
        (it went free) whatever ``level`` was written. Nil when no status was read from it since it
        connected. It came after the type: a message without it (an older session log) reads as nil.
    device_faults : str or None
        The faults that status set, names of :data:`DISPLAY_FAULTS` in that order, comma-separated;
        ``""`` for none. Nil exactly when ``device_state`` is (it came after the type too).
    """

    kind: ClassVar[str] = "display"
    grasp_id: str | None = scalar(_GRASP)
    phase: str = scalar(TextField(choices=DISPLAY_PHASES))
    stiffness: float = scalar(NumberField(lo=0.0))
    uncertainty_decades: float = scalar(NumberField(lo=0.0))
    rigid: bool = scalar(FLAG)
    unknown: bool = scalar(FLAG)
    provisional: bool = scalar(FLAG)
    E_pa: float | None = scalar(NumberField(lo=0.0, lo_open=True, nullable=True))
    level: int | None = scalar(IntegerField(lo=0, nullable=True))
    level_max: int | None = scalar(IntegerField(lo=1, nullable=True))
    device_state: str | None = scalar(TextField(choices=DISPLAY_DEVICE_STATES, nullable=True), added_later=True)
    device_faults: str | None = scalar(TextField(nullable=True, max_chars=128), added_later=True)

    def cross_check(self) -> None:
        """Refuse a stiffness above 1, rigid with unknown, a modulus that does not match the
        stiffness, a level without or above its full scale, or device faults without a device
        state (or the other way round) or naming no fault of :data:`DISPLAY_FAULTS`."""
        if self.stiffness > 1.0:
            raise MessageRejected("mistyped_field", f"display.stiffness = {self.stiffness}: expected <= 1")
        if self.rigid and self.unknown:
            raise MessageRejected("mistyped_field", "display with both rigid and unknown set")
        has_modulus = self.stiffness > 0 and not self.unknown
        if has_modulus != (self.E_pa is not None):
            raise MessageRejected(
                "mistyped_field",
                "display.E_pa must be given exactly when stiffness > 0 and not unknown "
                f"(stiffness {self.stiffness}, unknown {self.unknown}, E_pa {self.E_pa})",
            )
        level, level_max = self.level, self.level_max
        if level is not None and level_max is None:
            raise MessageRejected("mistyped_field", f"display.level = {level} without a level_max")
        if level is not None and level > level_max:
            raise MessageRejected("mistyped_field", f"display.level = {level}: above level_max = {level_max}")
        if (self.device_state is None) != (self.device_faults is None):
            raise MessageRejected("mistyped_field", "display.device_state and device_faults must be both given or "
                                                    f"both nil ({self.device_state!r}, {self.device_faults!r})")
        names = self.device_faults.split(",") if self.device_faults else []
        unknown = [name for name in names if name not in DISPLAY_FAULTS]
        if unknown:
            raise MessageRejected("mistyped_field", f"display.device_faults names {unknown}: expected names from "
                                                    f"{', '.join(DISPLAY_FAULTS)}, comma-separated")


@_body
class FollowBody(Body):
    """``follow``: the operator's continuous target for the fingers (operator -> robot node, on
    ``bus.command`` at :data:`teleop.operator.FOLLOW_RATE_HZ` while the operator drives).

    Attributes
    ----------
    grasp_id : str or None
    target_width_m : float
        The fingers' target opening (m, >= 0).
    enable : bool
        The dead-man is held; a follow without it only stops the fingers.
    """

    kind: ClassVar[str] = "follow"
    grasp_id: str | None = scalar(_GRASP)
    target_width_m: float = scalar(NumberField(lo=0.0))
    enable: bool = scalar(FLAG)


@_body
class RobotStateBody(Body):
    """``robot_state``: where the robot node stands (robot node, on ``bus.robot_pub``, on every
    change and at least once per heartbeat).

    Attributes
    ----------
    mode : str
        One of :data:`ROBOT_MODES`.
    grasp_id : str or None
    target_width_m : float or None
        The fingers' target while following (m, >= 0).
    enable : bool
        The last follow's enable.
    """

    kind: ClassVar[str] = "robot_state"
    mode: str = scalar(TextField(choices=ROBOT_MODES))
    grasp_id: str | None = scalar(_GRASP)
    target_width_m: float | None = scalar(NumberField(lo=0.0, nullable=True))
    enable: bool = scalar(FLAG)

    def followed_grasp(self) -> str | None:
        """The grasp an operator drives the fingers in, as this state says: the one place that
        tells a leader-follower grasp from a scripted one.

        Returns
        -------
        str or None
            :attr:`grasp_id` when :attr:`mode` is ``following``, else None (the node moves the
            fingers itself, or none).
        """
        return self.grasp_id if self.mode == "following" else None


@_body
class RobotNoticeBody(Body):
    """``robot_notice``: something the robot node did or refused on its own (robot node, on
    ``bus.robot_pub``).

    Attributes
    ----------
    event : str
        One of :data:`ROBOT_NOTICES`: ``refused`` (a command it cannot carry out), ``watchdog``
        (no follow came for :data:`teleop.operator.WATCHDOG_S`: the fingers stopped),
        ``force_limit`` (the fingers reached the settings' maximum force and close no further),
        ``device`` (a device's reads failed, or read again).
    action : str
        The command's action, ``follow``, or for ``device`` the device (``gripper``,
        ``load_cell``, ``camera/<finger>``).
    grasp_id : str or None
    reason : str
    """

    kind: ClassVar[str] = "robot_notice"
    event: str = scalar(TextField(choices=ROBOT_NOTICES))
    action: str = scalar(TextField(max_chars=64))
    grasp_id: str | None = scalar(_GRASP)
    reason: str = scalar(TextField(max_chars=MAX_STR_CHARS))

    def ended_grasp(self) -> str | None:
        """The grasp this notice says the robot node ended: the one place that tells a notice that
        ends a grasp from one that leaves it running.

        Returns
        -------
        str or None
            :attr:`grasp_id` when :attr:`event` is one of :data:`ENDING_NOTICES`, else None (and
            None for a device notice naming no grasp: a reader's failure ends none).
        """
        return self.grasp_id if self.event in ENDING_NOTICES else None


#: Each message type's body class, by type name.
BODIES: Mapping[str, type[Body]] = {
    body.kind: body
    for body in (FrameBody, ForceBody, WidthBody, GraspEventBody, EstimateBody, LabelBody, LoadModelBody,
                 ModelEventBody, CommandBody, HeartbeatBody, DisplayBody, FollowBody, RobotStateBody,
                 RobotNoticeBody)
}

#: Each message type's checks, derived from its body class.
SCHEMAS: Mapping[str, Schema] = {kind: Schema.of(body) for kind, body in BODIES.items()}
