"""Replay a session log: back onto the bus at recorded or faster speed, or into this process.

Every stored message is decoded and checked by :func:`teleop.bus.wire.decode` first (a
message that fails is logged, counted and skipped, never sent). What goes back on the bus
is the decoded message re-published through :class:`~teleop.bus.pubsub.Publisher`: same
type, topic, capture time and body; the replaying publisher's own ``source``, sequence
numbers and send times (so receivers measure latency and gaps of the replay itself).
Recorded heartbeats are not replayed: the replaying publisher sends its own.
"""

from __future__ import annotations

import time
from collections import Counter
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from teleop.bus.pubsub import DEFAULT_MAX_BYTES, Publisher
from teleop.bus.wire import Message
from teleop.errors import SessionLogError
from teleop.progress import progress_bar
from teleop.session.logfile import LogReader

__all__ = ["ReplayStats", "replay", "replay_messages"]


def replay_messages(
    path: str | Path, *, topics: Iterable[str] | None = None, max_bytes: int = DEFAULT_MAX_BYTES
) -> Iterator[Message]:
    """The recorded bus messages of a session log, decoded and checked, in receive order.

    For in-process use (tests, estimating on a recorded session). Heartbeats included;
    ``topics`` keeps only topics starting with one of the given prefixes. A log cut short
    by a crash yields every message up to its last complete chunk.

    Raises
    ------
    SessionLogError
        The file cannot be read or is not an MCAP file.
    """
    for logged in LogReader(Path(path), max_bytes=max_bytes).messages(topics):
        yield logged.message


@dataclass
class ReplayStats:
    """What a replay sent."""

    sent: int = 0
    topics: Counter[str] = field(default_factory=Counter)
    heartbeats_skipped: int = 0
    other_sources: Counter[str] = field(default_factory=Counter)  # by publisher: those not asked for
    refused: Counter[str] = field(default_factory=Counter)  # stored messages that did not decode
    log_span_s: float = 0.0  # receive-time span of what was sent
    wall_s: float = 0.0
    damage: str | None = None  # what was damaged or cut short in the log, skipped, or lost before recovery
    stopped: bool = False  # reading stopped there: nothing after it was replayed

    def as_dict(self) -> dict[str, Any]:
        return {
            "sent": self.sent,
            "topics": dict(sorted(self.topics.items())),
            "heartbeats_skipped": self.heartbeats_skipped,
            "other_sources": dict(sorted(self.other_sources.items())),
            "refused": dict(self.refused),
            "log_span_s": self.log_span_s,
            "wall_s": self.wall_s,
            "damage": self.damage,
            "stopped": self.stopped,
        }


def replay(
    path: str | Path,
    publisher: Publisher,
    *,
    speed: float | None = 1.0,
    topics: Iterable[str] | None = None,
    recorded_from: Iterable[str] | None = None,
    clock: Callable[[], float] = time.monotonic,
    sleep: Callable[[float], None] = time.sleep,
    progress: bool = False,
) -> ReplayStats:
    """Publish the messages of a session log on ``publisher``, paced by their receive times.

    Messages go out in file order, which is receive order (``teleop label`` writes each
    label right after its grasp); one stored out of order goes out at once.

    Parameters
    ----------
    path : str or Path
        The session log.
    publisher : Publisher
        Where to send (lossless, so a slow subscriber delays the replay rather than losing data).
    speed : float or None
        Replay speed relative to the recording (2.0: twice as fast); None: as fast as possible.
    topics : iterable of str, optional
        Topic prefixes to replay; default all (heartbeats never).
    recorded_from : iterable of str, optional
        Replay only messages recorded from these publishers (their ``source``: ``robot``,
        ``estimator``, ...); default every one.
    clock, sleep : callable
        Monotonic seconds and a sleep; replaceable for tests.
    progress : bool
        Show a tqdm bar on stderr.

    Raises
    ------
    SessionLogError
        ``speed`` is not positive, or the log cannot be read.
    BusTimeoutError
        A lossless send found no room in time (a subscriber stopped reading).
    """
    if speed is not None and not speed > 0:
        raise SessionLogError(
            f"replay speed {speed}: expected a number > 0 (or None: as fast as possible)"
        )
    sources = None if recorded_from is None else frozenset(recorded_from)
    reader = LogReader(Path(path), max_bytes=publisher.max_bytes)
    stats = ReplayStats()
    first_ns = None
    low_ns = high_ns = 0  # span of the log times sent
    start_s = clock()
    with progress_bar(desc=f"replay {path}", unit="msg", enabled=progress) as bar:
        for logged in reader.messages(topics):
            message = logged.message
            if message.type == "heartbeat":
                stats.heartbeats_skipped += 1
                continue
            if sources is not None and message.source not in sources:
                stats.other_sources[message.source or "?"] += 1
                continue
            if first_ns is None:
                first_ns, start_s = logged.log_time_ns, clock()
                low_ns = high_ns = first_ns
            # The span from the extremes: a message stored out of receive order (labels written
            # by an older `teleop label` at the end of the file) does not shorten it.
            low_ns, high_ns = min(low_ns, logged.log_time_ns), max(high_ns, logged.log_time_ns)
            if speed is not None:
                _wait_until(
                    start_s + (logged.log_time_ns - first_ns) / 1e9 / speed, publisher, clock, sleep
                )
            publisher.publish(message)
            publisher.heartbeat_if_due(clock())
            stats.sent += 1
            stats.topics[message.topic] += 1
            bar.update()
    stats.wall_s = clock() - start_s
    stats.log_span_s = (high_ns - low_ns) / 1e9
    stats.refused = Counter(reader.refused)
    stats.damage, stats.stopped = reader.damage, reader.stopped
    return stats


def _wait_until(
    due_s: float, publisher: Publisher, clock: Callable[[], float], sleep: Callable[[float], None]
) -> None:
    """Sleep until ``due_s``, keeping the publisher's heartbeat going meanwhile."""
    while (remaining := due_s - clock()) > 0:
        sleep(min(remaining, publisher.heartbeat_s))
        publisher.heartbeat_if_due(clock())
