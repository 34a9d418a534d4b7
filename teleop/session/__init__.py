"""Session logs: record every bus message of a session into MCAP, replay it, export its grasps
as grasp records, and recover logs cut short by a crash or a full disk.

:mod:`teleop.session.logfile` documents the log's layout and reads it back;
:mod:`~teleop.session.recorder`, :mod:`~teleop.session.replay`, :mod:`~teleop.session.export`
and :mod:`~teleop.session.recover` do the rest. Commands: ``teleop record``, ``teleop replay``,
``teleop export``, ``teleop recover``.
"""

from teleop.session.export import GraspExport, SessionExport, export_session, session_grasps
from teleop.session.logfile import LoggedMessage, LogInfo, LogReader
from teleop.session.recorder import RecorderStats, SessionRecorder, session_source
from teleop.session.recover import RecoveryReport, recover
from teleop.session.replay import ReplayStats, replay, replay_messages

__all__ = [
    "GraspExport",
    "LogInfo",
    "LogReader",
    "LoggedMessage",
    "RecorderStats",
    "RecoveryReport",
    "ReplayStats",
    "SessionExport",
    "SessionRecorder",
    "export_session",
    "recover",
    "replay",
    "replay_messages",
    "session_grasps",
    "session_source",
]
