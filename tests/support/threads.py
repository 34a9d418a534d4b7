"""A read blocked in one thread while another closes the device: the lifecycle contracts' check."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any


@dataclass(frozen=True)
class CloseDuringRead:
    outcome: Any  # what the read returned, or the error of ``errors`` it raised
    close_s: float  # how long close() took
    ended_s: float  # from the start of close() to the read's end


def close_during_read(read: Callable[[], Any], close: Callable[[], None], *,
                      errors: type[BaseException] | tuple[type[BaseException], ...],
                      waiting_s: float = 0.1) -> CloseDuringRead:
    """Start ``read`` in a thread, call ``close`` (or whatever should end the read: a cut link) once it
    waits (``waiting_s``), and say how both ended."""
    outcome: dict[str, Any] = {}

    def reader_thread() -> None:
        try:
            outcome["read"] = read()
        except errors as exc:
            outcome["read"] = exc
        outcome["ended"] = time.monotonic()

    reader = threading.Thread(target=reader_thread)
    reader.start()
    time.sleep(waiting_s)  # the read is waiting (a backend that never waits has returned)
    closing = time.monotonic()
    close()
    closed = time.monotonic()
    reader.join(timeout=5.0)
    assert not reader.is_alive(), "the read did not end within 5 s of close()"
    return CloseDuringRead(outcome["read"], closed - closing, outcome["ended"] - closing)
