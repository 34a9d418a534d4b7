"""The recorder's flush timing: a chunk reaches the file ``flush_interval_s`` after its first message.

The recorder's clock (``time.monotonic`` as :mod:`teleop.session.recorder` reads it) is a fake
the tests move by hand, so no assert depends on how fast the machine runs.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from contextlib import contextmanager
from types import SimpleNamespace

import pytest

from teleop.bus import Publisher
from teleop.session import LogReader, SessionRecorder
from teleop.session import recorder as recorder_module

FLUSH_S = 1.0  # on the fake clock
CHUNK_BYTES = 16 * 1024  # more than the schemas and channels of a force message
BIG_SAMPLES = 1500  # a force batch this long is a bus message larger than CHUNK_BYTES


class FakeClock:
    """``time.monotonic`` for the recorder module: stands still until moved."""

    def __init__(self) -> None:
        self.now_s = 1000.0

    def monotonic(self) -> float:
        return self.now_s


@pytest.fixture
def clock(monkeypatch) -> FakeClock:
    fake = FakeClock()
    monkeypatch.setattr(recorder_module, "time", SimpleNamespace(monotonic=fake.monotonic, time_ns=time.time_ns))
    return fake


@contextmanager
def _recording(path, settings, chunk_bytes: int) -> Iterator[SimpleNamespace]:
    """A lossless publisher and an open recorder of it, closed when the block ends."""
    with (
        Publisher("tcp://127.0.0.1:*", lossless=True, source="robot") as pub,
        SessionRecorder(path, [pub.endpoint], settings=settings, chunk_bytes=chunk_bytes,
                        flush_interval_s=FLUSH_S) as recorder,
    ):
        pub.wait_for_subscriber("", timeout_s=5.0)
        yield SimpleNamespace(pub=pub, recorder=recorder, path=path)


@pytest.fixture
def bus(tmp_path, clock, session_settings) -> Iterator[SimpleNamespace]:
    """A recording (fake clock) whose schemas and channels are in the file and no chunk open."""
    with _recording(tmp_path / "flush.mcap", session_settings, CHUNK_BYTES) as ready:
        _send(ready)
        clock.now_s += 3 * FLUSH_S  # long past due, whatever the interval is taken to be
        ready.recorder.poll(0)
        assert ready.recorder.stats.saved_messages == 1 and _in_file(ready.path) == 1
        yield ready


def _send(bus, samples: int = 1) -> None:
    """Publish one force message and poll (fake clock standing still) until the recorder stored it."""
    expected = bus.recorder.stats.messages + 1
    t = [float(k) for k in range(samples)]
    bus.pub.send("force", t_capture_s=float(samples), t_s=t, value_n=t)
    deadline = time.monotonic() + 10.0  # only against a hang: nothing here is timed
    while bus.recorder.stats.messages < expected:
        if time.monotonic() > deadline:
            raise AssertionError("the recorder never stored the message")
        bus.recorder.poll(0.05)


def _in_file(path) -> int:
    """How many bus messages a reader finds in the log as it is on disk now (not closed)."""
    return len(list(LogReader(path).messages(["force"])))


def test_a_message_is_in_the_file_once_its_chunk_is_flush_interval_old_without_closing(bus, clock):
    _send(bus)
    assert bus.recorder.stats.saved_messages == 1 and _in_file(bus.path) == 1  # its chunk is open

    clock.now_s += 0.9 * FLUSH_S
    bus.recorder.poll(0)
    assert bus.recorder.stats.saved_messages == 1 and _in_file(bus.path) == 1  # not yet due

    clock.now_s += 0.1 * FLUSH_S  # exactly flush_interval_s after the message
    bus.recorder.poll(0)
    assert bus.recorder.stats.saved_messages == 2
    assert _in_file(bus.path) == 2  # what a killed recorder leaves for `teleop recover`


def test_a_long_poll_returns_when_the_open_chunk_is_due_and_flushes_it(bus, clock, monkeypatch):
    _send(bus)
    waited: list[float] = []

    def recv(timeout_s: float | None = None) -> None:  # nothing arrives; waiting moves the fake clock as far
        waited.append(timeout_s)
        clock.now_s += timeout_s

    monkeypatch.setattr(bus.recorder._subscriber, "recv", recv)
    clock.now_s += 0.25 * FLUSH_S
    bus.recorder.poll(60.0)
    assert waited == [pytest.approx(0.75 * FLUSH_S)]  # woke when the chunk fell due, not after 60 s
    assert bus.recorder.stats.saved_messages == 2 and _in_file(bus.path) == 2


def test_the_chunk_after_a_full_one_is_timed_from_its_own_first_message(bus, clock):
    _send(bus)  # opens a chunk
    clock.now_s += 0.2 * FLUSH_S
    _send(bus, samples=BIG_SAMPLES)  # fills it: written at once, with the first
    assert bus.recorder.stats.saved_messages == 3 and _in_file(bus.path) == 3

    clock.now_s += 0.3 * FLUSH_S
    _send(bus)  # opens the next chunk, at 0.5 flush intervals
    clock.now_s += 0.5 * FLUSH_S  # one interval after the first chunk opened, half of one after this
    bus.recorder.poll(0)
    assert bus.recorder.stats.saved_messages == 3 and _in_file(bus.path) == 3  # not due yet

    clock.now_s += 0.5 * FLUSH_S
    bus.recorder.poll(0)
    assert bus.recorder.stats.saved_messages == 4 and _in_file(bus.path) == 4


def test_a_message_whose_registration_fills_the_chunk_is_flushed_in_time(tmp_path, clock, session_settings):
    # Registering a new topic's schema and channel wrote the open chunk (mcap, a full chunk): the
    # message went into the next one, which was taken as written, so no flush was timed for it.
    with _recording(tmp_path / "small.mcap", session_settings, 1024) as small:  # less than a force schema
        _send(small)
        clock.now_s += FLUSH_S
        small.recorder.poll(0)
        assert _in_file(small.path) == small.recorder.stats.saved_messages == 1
