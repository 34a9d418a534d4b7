"""The bus's message types: each type's body fields, their checks and what they mean.

:data:`SCHEMAS` maps each type to its :class:`~teleop.bus.field_checks.Schema`; the envelope,
the encoder and the decoder are :mod:`teleop.bus.wire`'s, which checks every body against it
and re-exports the names here.

Message types and body schemas
------------------------------
``frame``        finger: str, grasp_id: str|nil, index: int >= 0 (frame number of the
                 camera), encoding: "jpeg"|"png"|"raw"; array ``data``: the image as
                 captured, uint8 1-D (jpeg, png), or for "raw" H x W x 3 BGR, uint8 or
                 uint16.
``force``        grasp_id: str|nil; arrays ``t_s`` (float64) and ``value_n`` (float64 or
                 float32), 1-D, one length >= 1, finite (seconds; newtons).
``width``        grasp_id: str|nil; arrays ``t_s`` and ``value_m``: as ``force`` (metres).
``grasp_event``  event: "start"|"loading_end"|"end", grasp_id: str, object_name: str|nil.
                 ``loading_end``: the gripper's grasp command completed (the fingers stopped
                 at the target force) at ``t_capture_s``; the width read then went out just
                 before it as a ``width`` message.
``estimate``     grasp_id: str, method: str, E_pa: float > 0 | nil,
                 interval_pa: [low, high] with each float > 0 or nil (nil: open side),
                 state: "ok"|"lower_bound"|"upper_bound"|"insufficient_data",
                 reason: str, provisional: bool, latency_s: float >= 0,
                 model: str|nil (the id of the learned model that made it; nil: none did).
                 ``ok`` needs E_pa; ``insufficient_data`` has none; low <= high. ``model`` came
                 after the type: a receiver reads an estimate without it (an older sender, an
                 older session log) as nil.
``command``      action: "start_grasp"|"stop"|"release" (robot node) | "reload_model"
                 (estimator service: reload its learned model between grasps),
                 grasp_id: str|nil, params: {str: finite float} (e.g. ``target_force_n``).
``heartbeat``    interval_s: float > 0, the sender's heartbeat period.
``display``      what the haptic renderer wrote to the softness display, one per report written
                 (``haptics serve``, on ``bus.display_pub``; ``t_capture_s`` is the write time
                 on the renderer's clock): grasp_id: str|nil (nil when idle),
                 phase: "idle"|"active"|"stale"|"fading", stiffness: float in [0, 1] (fraction
                 of the display's range, 1 = the rigid end), uncertainty_decades: float >= 0,
                 rigid: bool, unknown: bool (not both), provisional: bool,
                 E_pa: float > 0 | nil (the modulus the stiffness stands for on the display's
                 range; nil exactly when stiffness is 0 or unknown is set),
                 level: int >= 0 | nil and level_max: int >= 1 | nil (the quantised level
                 written and the display's full scale; level <= level_max, level needs level_max).
``follow``       the operator's continuous target for the fingers (operator -> robot node, on
                 ``bus.command`` at :data:`teleop.operator.FOLLOW_RATE_HZ` while the operator
                 drives): grasp_id: str|nil, target_width_m: float >= 0 (m),
                 enable: bool (the dead-man is held; a follow without it only stops the fingers).
``robot_state``  where the robot node stands (robot node, on ``bus.robot_pub``, on every change
                 and at least once per heartbeat): mode: one of :data:`ROBOT_MODES`,
                 grasp_id: str|nil, target_width_m: float >= 0 | nil (the fingers' target while
                 following), enable: bool (the last follow's enable).
``robot_notice`` something the robot node did or refused on its own (robot node, on
                 ``bus.robot_pub``): event: one of :data:`ROBOT_NOTICES` ("refused": a command it
                 cannot carry out; "watchdog": no follow came for
                 :data:`teleop.operator.WATCHDOG_S`, the fingers stopped; "force_limit": the
                 fingers reached the settings' maximum force and close no further),
                 action: str (the command's action, or "follow"), grasp_id: str|nil, reason: str.
``label``        what the grasped object is (operator -> all, on ``bus.command``; also written
                 into a session log after the fact by ``teleop label``): grasp_id: str,
                 object_name: str, modulus_pa: float > 0 | nil (nil: the catalogue's),
                 source: one of :data:`teleop.labels.LABEL_SOURCES`, detail: str (e.g. the
                 Shore hardness read and the conversion used).
``load_model``   switch the estimator service to another model (operator -> estimator, on
                 ``bus.command``): path: str (the model folder on the estimator's host),
                 request: str (echoed in the answer).
``model_event``  what the estimator service did with its model (estimator, on its
                 ``estimate_pub``): event: one of :data:`MODEL_EVENTS` ("loaded": it serves
                 another model from now on; "refused": it kept the one it had),
                 request: str|nil (the ``load_model`` it answers; nil for a reload of its own),
                 model: str|nil (the id of the model it serves now), path: str|nil, reason: str.

Adding a message type changes no existing message, so it keeps the version: a receiver that
predates a type refuses its messages as ``unknown_type`` and goes on with the rest.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any

import numpy as np

from teleop.bus.field_checks import (
    FLAG,
    INTERVAL,
    ArrayField,
    IntegerField,
    NumberField,
    NumberMapField,
    Schema,
    TextField,
)
from teleop.errors import MessageRejected
from teleop.labels import LABEL_SOURCES
from teleop.states import ESTIMATE_STATES

__all__ = [
    "COMMAND_ACTIONS",
    "DISPLAY_PHASES",
    "ESTIMATE_STATES",
    "MAX_MODEL_ID_CHARS",
    "MAX_PARAMS",
    "MAX_STR_CHARS",
    "MODEL_EVENTS",
    "ROBOT_MODES",
    "ROBOT_NOTICES",
    "SCHEMAS",
]

MAX_STR_CHARS = 1024
MAX_PARAMS = 32

# The robot node carries out the first three; the estimator service the last.
COMMAND_ACTIONS = ("start_grasp", "stop", "release", "reload_model")

# The haptic renderer's phases (haptics.renderer.HapticRenderer.phase).
DISPLAY_PHASES = ("idle", "active", "stale", "fading")

# The robot node's modes (robot_state) and the notices it sends (robot_notice).
ROBOT_MODES = ("idle", "grasping", "holding", "releasing", "following", "stopped")
ROBOT_NOTICES = ("refused", "watchdog", "force_limit")
# What the estimator service says of its model: it serves another now, or it kept the one it had.
MODEL_EVENTS = ("loaded", "refused")
MAX_MODEL_ID_CHARS = 64


def _samples_rule(value_name: str) -> Callable[[dict[str, Any]], None]:
    def rule(body: dict[str, Any]) -> None:
        t, v = body["t_s"], body[value_name]
        if t.shape != v.shape or t.shape[0] == 0:
            raise MessageRejected("mistyped_field", f"t_s {t.shape} and {value_name} {v.shape} must be one length >= 1")

    return rule


_MAGIC = {"jpeg": b"\xff\xd8", "png": b"\x89PNG"}


def _frame_rule(body: dict[str, Any]) -> None:
    data, encoding = body["data"], body["encoding"]
    if encoding == "raw":
        if data.ndim != 3 or data.shape[2] != 3:
            raise MessageRejected("mistyped_field", f"raw frame data has shape {data.shape}: expected H x W x 3")
    elif data.ndim != 1 or data.dtype != np.uint8 or data[: len(_MAGIC[encoding])].tobytes() != _MAGIC[encoding]:
        raise MessageRejected("mistyped_field", f"frame data is not a 1-D {encoding} byte string")


def _estimate_rule(body: dict[str, Any]) -> None:
    if body["state"] == "ok" and body["E_pa"] is None:
        raise MessageRejected("mistyped_field", "estimate with state 'ok' has no E_pa")
    if body["state"] == "insufficient_data" and body["E_pa"] is not None:
        raise MessageRejected("mistyped_field", "estimate with state 'insufficient_data' carries an E_pa")


def _display_rule(body: dict[str, Any]) -> None:
    if body["stiffness"] > 1.0:
        raise MessageRejected("mistyped_field", f"display.stiffness = {body['stiffness']}: expected <= 1")
    if body["rigid"] and body["unknown"]:
        raise MessageRejected("mistyped_field", "display with both rigid and unknown set")
    has_modulus = body["stiffness"] > 0 and not body["unknown"]
    if has_modulus != (body["E_pa"] is not None):
        raise MessageRejected(
            "mistyped_field",
            "display.E_pa must be given exactly when stiffness > 0 and not unknown "
            f"(stiffness {body['stiffness']}, unknown {body['unknown']}, E_pa {body['E_pa']})",
        )
    level, level_max = body["level"], body["level_max"]
    if level is not None and level_max is None:
        raise MessageRejected("mistyped_field", f"display.level = {level} without a level_max")
    if level is not None and level > level_max:
        raise MessageRejected("mistyped_field", f"display.level = {level}: above level_max = {level_max}")


# Timestamps stay float64: float32 would round monotonic seconds (~1e5 s) to ~8 ms.
_TIMES = ArrayField(("<f8",), (1,), finite=True)
_VALUES = ArrayField(("<f8", "<f4"), (1,), finite=True)

SCHEMAS: Mapping[str, Schema] = {
    "frame": Schema(
        fields={
            "finger": TextField(max_chars=32),
            "grasp_id": TextField(nullable=True),
            "index": IntegerField(),
            "encoding": TextField(choices=("jpeg", "png", "raw")),
        },
        arrays={"data": ArrayField(("|u1", "<u2"), (1, 3))},
        nullable=frozenset({"grasp_id"}),
        rule=_frame_rule,
    ),
    "force": Schema(
        fields={"grasp_id": TextField(nullable=True)},
        arrays={"t_s": _TIMES, "value_n": _VALUES},
        nullable=frozenset({"grasp_id"}),
        rule=_samples_rule("value_n"),
    ),
    "width": Schema(
        fields={"grasp_id": TextField(nullable=True)},
        arrays={"t_s": _TIMES, "value_m": _VALUES},
        nullable=frozenset({"grasp_id"}),
        rule=_samples_rule("value_m"),
    ),
    "grasp_event": Schema(
        fields={
            "event": TextField(choices=("start", "loading_end", "end")),
            "grasp_id": TextField(),
            "object_name": TextField(nullable=True),
        },
        nullable=frozenset({"object_name"}),
    ),
    "estimate": Schema(
        fields={
            "grasp_id": TextField(),
            "method": TextField(max_chars=64),
            "E_pa": NumberField(lo=0.0, lo_open=True, nullable=True),
            "interval_pa": INTERVAL,
            "state": TextField(choices=ESTIMATE_STATES),
            "reason": TextField(max_chars=MAX_STR_CHARS),
            "provisional": FLAG,
            "latency_s": NumberField(lo=0.0),
            "model": TextField(max_chars=MAX_MODEL_ID_CHARS, nullable=True),
        },
        nullable=frozenset({"model"}),
        optional=frozenset({"model"}),
        rule=_estimate_rule,
    ),
    "label": Schema(
        fields={
            "grasp_id": TextField(),
            "object_name": TextField(max_chars=128),
            "modulus_pa": NumberField(lo=0.0, lo_open=True, nullable=True),
            "source": TextField(choices=LABEL_SOURCES),
            "detail": TextField(max_chars=MAX_STR_CHARS),
        },
        nullable=frozenset({"modulus_pa"}),
    ),
    "load_model": Schema(
        fields={"path": TextField(max_chars=MAX_STR_CHARS), "request": TextField(max_chars=64)},
    ),
    "model_event": Schema(
        fields={
            "event": TextField(choices=MODEL_EVENTS),
            "request": TextField(max_chars=64, nullable=True),
            "model": TextField(max_chars=MAX_MODEL_ID_CHARS, nullable=True),
            "path": TextField(max_chars=MAX_STR_CHARS, nullable=True),
            "reason": TextField(max_chars=MAX_STR_CHARS),
        },
        nullable=frozenset({"request", "model", "path"}),
    ),
    "command": Schema(
        fields={
            "action": TextField(choices=COMMAND_ACTIONS),
            "grasp_id": TextField(nullable=True),
            "params": NumberMapField(max_items=MAX_PARAMS),
        },
        nullable=frozenset({"grasp_id"}),
    ),
    "heartbeat": Schema(fields={"interval_s": NumberField(lo=0.0, lo_open=True)}),
    "display": Schema(
        fields={
            "grasp_id": TextField(nullable=True),
            "phase": TextField(choices=DISPLAY_PHASES),
            "stiffness": NumberField(lo=0.0),
            "uncertainty_decades": NumberField(lo=0.0),
            "rigid": FLAG,
            "unknown": FLAG,
            "provisional": FLAG,
            "E_pa": NumberField(lo=0.0, lo_open=True, nullable=True),
            "level": IntegerField(lo=0, nullable=True),
            "level_max": IntegerField(lo=1, nullable=True),
        },
        nullable=frozenset({"grasp_id", "E_pa", "level", "level_max"}),
        rule=_display_rule,
    ),
    "follow": Schema(
        fields={
            "grasp_id": TextField(nullable=True),
            "target_width_m": NumberField(lo=0.0),
            "enable": FLAG,
        },
        nullable=frozenset({"grasp_id"}),
    ),
    "robot_state": Schema(
        fields={
            "mode": TextField(choices=ROBOT_MODES),
            "grasp_id": TextField(nullable=True),
            "target_width_m": NumberField(lo=0.0, nullable=True),
            "enable": FLAG,
        },
        nullable=frozenset({"grasp_id", "target_width_m"}),
    ),
    "robot_notice": Schema(
        fields={
            "event": TextField(choices=ROBOT_NOTICES),
            "action": TextField(max_chars=64),
            "grasp_id": TextField(nullable=True),
            "reason": TextField(max_chars=MAX_STR_CHARS),
        },
        nullable=frozenset({"grasp_id"}),
    ),
}
