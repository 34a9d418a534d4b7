"""What a session log says of its grasps besides their data, read before them (:mod:`teleop.session.export`).

The last ``label`` per grasp id; the leader-follower grasps, those a ``robot_state`` follows
(:meth:`~teleop.bus.messages.RobotStateBody.followed_grasp`); and the ``robot_notice`` messages that
ended a grasp (:meth:`~teleop.bus.messages.RobotNoticeBody.ended_grasp`: the watchdog stopped the
fingers, or a device failed), by grasp id and event, at their capture time.
"""

from __future__ import annotations

from collections import defaultdict
from dataclasses import dataclass, field

from teleop.bus.messages import LabelBody
from teleop.session.logfile import LogReader

__all__ = ["LogNotes", "log_notes"]


@dataclass(frozen=True)
class LogNotes:
    """See the module notes."""

    labels: dict[str, LabelBody] = field(default_factory=dict)
    followed: frozenset[str] = frozenset()
    stops: dict[str, dict[str, list[float]]] = field(default_factory=dict)  # grasp id -> notice event -> times (s)


def log_notes(reader: LogReader) -> LogNotes:
    """The notes of the log ``reader`` reads (module notes)."""
    labels, followed, stops = {}, set(), defaultdict(lambda: defaultdict(list))
    for logged in reader.messages(("label", "robot_state", "robot_notice")):
        message = logged.message
        body = message.fields
        if message.type == "label":
            labels[body.grasp_id] = body
        elif message.type == "robot_state" and (grasp_id := body.followed_grasp()) is not None:
            followed.add(grasp_id)
        elif message.type == "robot_notice" and (grasp_id := body.ended_grasp()) is not None:
            stops[grasp_id][body.event].append(message.t_capture_s)
    return LogNotes(labels, frozenset(followed), {gid: dict(events) for gid, events in stops.items()})
