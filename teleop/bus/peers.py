"""What a subscriber remembers of its peers: when each was last heard from, in bounded tables.

:class:`Heartbeat` keeps each peer's last-heard time and announced heartbeat period and says
whether it is alive; :class:`Recent` is the bounded map it (and a subscriber's per-topic
tables, :mod:`teleop.bus.pubsub`) are kept in, so a sender that makes up a name per message
cannot fill the memory.
"""

from __future__ import annotations

import logging
import time
from collections import OrderedDict
from collections.abc import Callable
from typing import Any

from teleop.errors import BusError

__all__ = ["MAX_TRACKED", "Heartbeat", "Recent"]

log = logging.getLogger(__name__)

# Sources, (source, topic) pairs or topics a subscriber remembers (see teleop.bus.pubsub, Memory):
# a real bus has a handful of nodes sending a few dozen topics.
MAX_TRACKED = 1024


class Recent(OrderedDict):
    """A map of the :data:`MAX_TRACKED` keys set most recently; setting one more forgets the oldest.

    ``what`` names the keys in the warning logged when the first is forgotten.
    """

    def __init__(self, what: str):
        super().__init__()
        self._what = what
        self._forgetting = False

    def __setitem__(self, key: Any, value: Any) -> None:
        super().__setitem__(key, value)
        self.move_to_end(key)
        if len(self) > MAX_TRACKED:
            oldest, _ = self.popitem(last=False)
            if not self._forgetting:
                self._forgetting = True
                log.warning("more than %d %s: forgetting the longest unheard from now on, first %r "
                            "(a sender that makes up names?)", MAX_TRACKED, self._what, oldest)


class Heartbeat:
    """When each peer was last heard from, on this process's monotonic clock.

    It remembers the :data:`MAX_TRACKED` peers heard from most recently.

    Parameters
    ----------
    clock : callable, optional
        Seconds on a monotonic clock; ``time.monotonic`` by default.
    """

    def __init__(self, *, clock: Callable[[], float] = time.monotonic):
        self._clock = clock
        # source -> (clock time last heard from, the period it last announced or None)
        self._peers: Recent = Recent("peers heard from")

    def saw(self, source: str, *, interval_s: float | None = None, now_s: float | None = None) -> None:
        """Record that ``source`` was heard from (``interval_s``: the period it announced)."""
        if interval_s is None and source in self._peers:
            interval_s = self._peers[source][1]
        self._peers[source] = (self._clock() if now_s is None else now_s, interval_s)

    def last_seen_s(self, source: str) -> float | None:
        """Clock time ``source`` was last heard from, or None if never."""
        seen = self._peers.get(source)
        return None if seen is None else seen[0]

    def peers(self) -> list[str]:
        """Every source heard from so far (the :data:`MAX_TRACKED` most recent)."""
        return sorted(self._peers)

    def is_alive(self, source: str, *, timeout_s: float | None = None, now_s: float | None = None) -> bool:
        """Whether ``source`` was heard from within ``timeout_s``.

        The default timeout is three of the peer's announced heartbeat periods; a peer
        never heard from, or heard from without announcing a period, needs ``timeout_s``.
        """
        if source not in self._peers:
            return False
        last, interval_s = self._peers[source]
        if timeout_s is None:
            if interval_s is None:
                raise BusError(f"peer {source!r} announced no heartbeat period: pass timeout_s")
            timeout_s = 3.0 * interval_s
        now = self._clock() if now_s is None else now_s
        return now - last <= timeout_s
