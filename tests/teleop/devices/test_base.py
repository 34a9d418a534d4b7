"""The shared device machinery: backend tables, lifecycle, sample queues."""

from __future__ import annotations

import threading
import time

import pytest

from teleop.devices.base import Device, SampleQueue, check_timeout, load_backend
from teleop.errors import BackendNotFoundError, DeviceError, InvalidCommandError


class Counting(Device):
    def __init__(self):
        super().__init__()
        self.opened = self.closed = 0

    def _connect(self):
        self.opened += 1

    def _close(self):
        self.closed += 1


def test_lifecycle_runs_each_hook_once():
    device = Counting()
    with device, pytest.raises(DeviceError, match="already connected"):
        device.connect()
    device.close()
    assert (device.opened, device.closed) == (1, 1)
    device.connect()  # a closed device may be opened again
    assert device.connected and device.opened == 2


def test_backend_tables_import_on_use_and_name_what_failed():
    table = {"here": "teleop.devices.base:SampleQueue", "gone": "teleop.devices.not_a_module:Thing"}
    assert load_backend("widget", table, "here") is SampleQueue
    with pytest.raises(BackendNotFoundError, match="no widget backend named 'nope'; available: gone, here"):
        load_backend("widget", table, "nope")
    with pytest.raises(BackendNotFoundError, match="widget backend 'gone' cannot be loaded"):
        load_backend("widget", table, "gone")


def test_sample_queue_hands_out_batches_and_counts_what_it_dropped():
    queue = SampleQueue(maxlen=3)
    assert len(queue.take()) == 0
    for i in range(5):
        queue.put(float(i), 10.0 * i)
    batch = queue.take()
    assert batch.t_s.tolist() == [2.0, 3.0, 4.0] and batch.value.tolist() == [20.0, 30.0, 40.0]
    assert queue.dropped == 2
    threading.Timer(0.05, queue.put, args=(5.0, 50.0)).start()
    started = time.monotonic()
    assert queue.take(timeout_s=2.0).value.tolist() == [50.0]  # woken by the put, not the timeout
    assert time.monotonic() - started < 1.0


def test_closing_a_sample_queue_wakes_a_waiting_take_and_later_takes_do_not_wait():
    queue = SampleQueue()
    threading.Timer(0.1, queue.close).start()
    started = time.monotonic()
    assert len(queue.take(timeout_s=3.0)) == 0
    assert time.monotonic() - started < 2.0  # woken by the close (0.1 s), not the 3 s timeout; room for load
    queue.put(1.0, 10.0)  # what was queued still comes out
    assert queue.take(timeout_s=3.0).value.tolist() == [10.0]
    started = time.monotonic()
    # Closed: no wait at all. Bounded well below the 3 s a wait would take, as a loaded machine is slow.
    assert len(queue.take(timeout_s=3.0)) == 0 and time.monotonic() - started < 2.0


@pytest.mark.parametrize("timeout", [-1.0, float("nan"), float("inf"), True, "1"])
def test_timeouts_must_be_finite_non_negative_numbers(timeout):
    with pytest.raises(InvalidCommandError, match="timeout_s"):
        SampleQueue().take(timeout_s=timeout)
    with pytest.raises(InvalidCommandError, match="timeout_s"):
        check_timeout(timeout)
    with pytest.raises(InvalidCommandError, match="timeout_s = 0"):
        check_timeout(0)
    assert check_timeout(0, poll=True) == 0.0 and check_timeout(2) == 2.0
