"""Bus helpers for tests: publish until a subscriber hears."""

from __future__ import annotations

import time

from teleop.bus import Message, Publisher, Subscriber


def force(pub: Publisher, i: int) -> None:
    pub.send("force", t_capture_s=float(i), t_s=[float(i)], value_n=[float(i)])


def delivered(pub: Publisher, *subs: Subscriber, within_s: float) -> Message | None:
    """Publish while ``subs`` listen, until one of them gets a message: that message, or
    None after ``within_s``. The subscribers are polled throughout: libzmq hands a SUB's
    subscriptions to a new or reconnected peer only while its socket is being used."""
    deadline = time.monotonic() + within_s
    i = 0
    while time.monotonic() < deadline:
        force(pub, i)
        i += 1
        for sub in subs:
            if (message := sub.recv(timeout_s=0.01)) is not None:
                return message
    return None
