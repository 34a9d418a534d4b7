"""Capture times a grasp's messages must keep: the estimator service's check of each message."""

from __future__ import annotations

import itertools
from typing import Any

from estimator.errors import PerceptionError
from teleop.bus.wire import Message

__all__ = ["MAX_CLOCK_JUMP_S", "check_times"]

# Capture clocks are monotonic: a time this far past the stream's last one is a broken clock.
MAX_CLOCK_JUMP_S = 10.0


class _ClockError(PerceptionError):
    """Capture times no clock gives; ``reason`` (``out_of_order``, ``clock_jump`` or
    ``far_from_grasp``) keys the log's counts."""

    def __init__(self, reason: str, text: str):
        super().__init__(text)
        self.reason = reason


def check_times(grasp: Any, message: Message) -> None:
    """Raise _ClockError (a PerceptionError) unless the message's capture times go strictly forward
    from the topic's last ones without a jump of more than MAX_CLOCK_JUMP_S, or, for the topic's
    first, lie within MAX_CLOCK_JUMP_S of the grasp's newest capture time (its start's or another
    topic's last); then remember the newest in ``grasp.last_t_s`` (the estimator service's open grasp:
    its ``grasp_id``, ``t_start_s`` and ``last_t_s`` are read)."""
    times = [message.t_capture_s] if message.type == "frame" else message.fields.t_s.tolist()
    last = grasp.last_t_s.get(message.topic)
    where = f"grasp {grasp.grasp_id!r} {message.topic} capture times {times[0]:.6f}..{times[-1]:.6f} s"
    if last is None:
        # One clock stamps a grasp's start and data: a first time far from them is a broken stamp, and
        # taken as the topic's last it would make every genuine one after it look broken.
        newest = max([grasp.t_start_s, *grasp.last_t_s.values()])
        if abs(times[0] - newest) > MAX_CLOCK_JUMP_S:
            raise _ClockError("far_from_grasp", f"{where}: {times[0] - newest:+.3g} s from the grasp's newest "
                                                f"capture time ({newest:.6f} s: its start or another topic's), "
                                                f"more than {MAX_CLOCK_JUMP_S:g} s: the capture clock is broken")
    previous = [] if last is None else [last]
    steps = [b - a for a, b in itertools.pairwise([*previous, *times])]
    after = "" if last is None else f" ({last:.6f} s)"
    if steps and min(steps) <= 0:
        raise _ClockError("out_of_order", f"{where}: not after the previous one{after}: out of order or repeated")
    if steps and max(steps) > MAX_CLOCK_JUMP_S:
        raise _ClockError("clock_jump", f"{where}: jump {max(steps):.3g} s past the previous one{after}, "
                                        f"more than {MAX_CLOCK_JUMP_S:g} s: the capture clock is broken")
    grasp.last_t_s[message.topic] = times[-1]
