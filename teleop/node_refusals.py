"""Which of the robot node's refusals are said on the bus and in the log, in bounded time and memory.

A command's values are the sender's: a sender that makes up a new object index, width or grasp id
with every command must not make the node log, nor say on the bus, one line per command. Refusals
therefore fall into *kinds*: the action, the error's class and its reason with the values taken out
(quoted strings and numbers), at most :data:`MAX_KINDS` kinds (any further ones share one kind per
action and class).

* The log: the first refusal of a kind is logged with its reason, then the 10th, 100th, ... with
  their count (:func:`~teleop.bus.pubsub.is_decade`).
* The bus: a ``robot_notice`` per refusal, except the same one (action, grasp and reason) again
  within :data:`REFUSAL_REPEAT_S`, and at most :data:`NOTICES_PER_KIND` of a kind in a
  :data:`REFUSAL_REPEAT_S` window: an operator's console hears its refusal unless that kind was
  flooded in the same second.

The bookkeeping takes O(1) per refusal and remembers at most :data:`MAX_RECENT` recent notices.
"""

from __future__ import annotations

import math
import re
from collections import OrderedDict
from dataclasses import dataclass

from teleop.bus.pubsub import is_decade

__all__ = ["MAX_KINDS", "MAX_RECENT", "NOTICES_PER_KIND", "REFUSAL_REPEAT_S", "Refusals"]

REFUSAL_REPEAT_S = 1.0  # the same refusal (action, grasp and reason) goes out at most this often
NOTICES_PER_KIND = 20  # robot_notices of one kind per REFUSAL_REPEAT_S window: above a console's bursts
MAX_KINDS = 64  # kinds of refusal told apart; further ones share one per action and error class
MAX_RECENT = 1024  # notices remembered to hold back their repeats (more within a window: the oldest forgotten)

# The values in a reason: quoted strings (reprs, grasp ids) and numbers (with sign, exponent, inf, nan).
_VALUES = re.compile(r"'(?:[^'\\]|\\.)*'|\"(?:[^\"\\]|\\.)*\"|[-+]?(?:\d+(?:\.\d*)?(?:[eE][-+]?\d+)?|inf|nan)")


@dataclass
class _Kind:
    count: int = 0  # refusals of this kind so far
    window_s: float = -math.inf  # when the current window of notices began
    sent: int = 0  # notices of this kind sent in that window


class Refusals:
    """The node's refusals so far: :meth:`refused` counts one and says whether to log it;
    :meth:`may_send` whether its notice goes out."""

    def __init__(self) -> None:
        self._kinds: dict[tuple[str, str, str], _Kind] = {}
        self._recent: OrderedDict[tuple[str, str | None, str], float] = OrderedDict()  # notice -> when sent

    def kind(self, action: str, exc: BaseException) -> tuple[str, str, str]:
        """The refusal's kind: the action, the error's class and its reason without its values."""
        key = (action, type(exc).__name__, _VALUES.sub("_", str(exc))[:200])
        if key not in self._kinds and len(self._kinds) >= MAX_KINDS:
            key = (action, type(exc).__name__, "")
        return key

    def refused(self, kind: tuple[str, str, str]) -> int:
        """Count a refusal of ``kind``; its count if it is to be logged (the 1st, 10th, ...), else 0."""
        entry = self._kinds.setdefault(kind, _Kind())
        entry.count += 1
        return entry.count if is_decade(entry.count) else 0

    def may_send(self, action: str, grasp_id: str | None, reason: str, now: float, *, repeat_s: float,
                 kind: tuple[str, str, str] | None = None) -> bool:
        """Whether a notice goes out now (module docstring), recorded as sent if so: not the same
        one within ``repeat_s``, and within its ``kind``'s share of notices (if given)."""
        recent = self._recent
        while recent and now - next(iter(recent.values())) >= REFUSAL_REPEAT_S:
            recent.popitem(last=False)  # sent in time order: the oldest first
        key = (action, grasp_id, reason)
        if now - recent.get(key, -math.inf) < repeat_s:
            return False
        if kind is not None:
            entry = self._kinds.setdefault(kind, _Kind())
            if now - entry.window_s >= REFUSAL_REPEAT_S:
                entry.window_s, entry.sent = now, 0
            if entry.sent >= NOTICES_PER_KIND:
                return False
            entry.sent += 1
        recent[key] = now
        recent.move_to_end(key)
        if len(recent) > MAX_RECENT:
            recent.popitem(last=False)
        return True
