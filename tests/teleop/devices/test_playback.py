"""GraspPlayback: what a replayed record makes due, and when, on an injected clock; the sim devices
reading it."""

from __future__ import annotations

import dataclasses
import time

import numpy as np
import pytest

from teleop.devices.camera import make_camera
from teleop.devices.loadcell import make_load_cell
from teleop.devices.playback import GraspPlayback
from teleop.errors import DeviceError, DeviceTimeoutError
from teleop.record import GraspRecord, Provenance, Samples
from teleop.settings import LoadCellSettings, SensorSettings


class FakeClock:
    def __init__(self, now: float = 1000.0):
        self.now = now

    def __call__(self) -> float:
        return self.now


def test_nothing_is_due_before_the_start(make_record):
    playback = GraspPlayback(make_record(), clock=FakeClock())
    assert not playback.started and not playback.done()
    index, due = playback.forces_due(0)
    assert index == 0 and len(due) == 0
    assert playback.frame_due("left") is None
    with pytest.raises(DeviceError, match="not started"):
        playback.live_time(2.0)


def test_samples_fall_due_at_their_shifted_timestamps(make_record):
    record = make_record(duration_s=0.5)
    clock = FakeClock()
    playback = GraspPlayback(record, clock=clock)
    playback.start()
    assert playback.origin_s == record.force_n.t_s[0] == 2.0  # no command event: the earliest sample
    index, due = playback.forces_due(0)
    assert index == 1 and due.value[0] == record.force_n.value[0] and due.t_s[0] == 1000.0
    clock.now = 1000.1
    index, due = playback.forces_due(index)
    expected = record.force_n.t_s[(record.force_n.t_s > 2.0) & (record.force_n.t_s <= 2.1 + 1e-12)]
    np.testing.assert_array_equal(due.t_s, expected - 2.0 + 1000.0)
    assert index == 1 + expected.size
    again, due = playback.forces_due(index)
    assert again == index and len(due) == 0  # nothing new at the same time
    frames = record.stream("left").t_s
    assert playback.frame_due("left") == int(np.sum(frames <= 2.1 + 1e-12)) - 1
    assert playback.frame_due_s("left", 0) == pytest.approx(frames[0] - 2.0 + 1000.0)
    assert not playback.done()
    clock.now = 1000.0 + playback.duration_s
    assert playback.done()
    index, due = playback.widths_due(0)
    np.testing.assert_array_equal(due.value, record.width_m.value)


def test_the_first_frame_is_due_from_its_own_time_on(make_record):
    clock = FakeClock()
    playback = GraspPlayback(make_record(), clock=clock)
    playback.start()
    first = playback.frame_due_s("left", 0)
    clock.now = first - 1e-6
    assert playback.frame_due("left") is None
    clock.now = first
    assert playback.frame_due("left") == 0
    clock.now = playback.frame_due_s("left", 1)
    assert playback.frame_due("left") == 1


def test_the_grasp_command_event_anchors_the_replay(make_record):
    record = make_record(command_grasp_s=1.9)
    playback = GraspPlayback(record, clock=FakeClock(50.0))
    playback.start(t0_s=60.0)
    assert playback.live_time(1.9) == 60.0
    assert playback.live_time(record.force_n.t_s[0]) == pytest.approx(60.1)
    assert playback.grasp_settled_s() == pytest.approx(60.0 + record.width_m.t_s[np.argmin(record.width_m.value)] - 1.9)


def test_without_widths_the_grasp_settles_at_the_records_end(make_record):
    record = dataclasses.replace(make_record(command_grasp_s=1.9), width_m=Samples(np.zeros(0), np.zeros(0)))
    playback = GraspPlayback(record, clock=FakeClock())
    playback.start(t0_s=60.0)
    assert playback.grasp_settled_s() == pytest.approx(60.0 + playback.duration_s)
    assert np.isnan(playback.hold_width_m())


def test_a_playback_runs_once_and_needs_data(make_record):
    playback = GraspPlayback(make_record(), clock=FakeClock())
    playback.start()
    with pytest.raises(DeviceError, match="already started"):
        playback.start()
    empty = make_record()
    empty = GraspRecord(
        sensors=empty.sensors, frames=(), force_n=Samples([], []), width_m=Samples([], []),
        provenance=Provenance(source="simulated"),
    )
    with pytest.raises(DeviceError, match="without any samples"):
        GraspPlayback(empty)


def test_the_fingers_stop_at_the_grasp_done_event_and_hold_the_width_read_before_release(make_record):
    record = make_record(command_grasp_s=1.9)
    marked = dataclasses.replace(record, events={"command_grasp": 1.9, "grasp_done": 2.25, "command_release": 2.32})
    playback = GraspPlayback(marked, clock=FakeClock(50.0))
    playback.start(t0_s=60.0)
    assert playback.grasp_settled_s() == pytest.approx(60.0 + 2.25 - 1.9)
    held = record.width_m.value[record.width_m.t_s <= 2.32][-1]
    assert playback.hold_width_m() == held and held != record.width_m.value.min()
    # Without the events: where the recorded width is smallest.
    assert GraspPlayback(record).hold_width_m() == record.width_m.value.min()


def test_a_replay_switched_while_a_reader_holds_the_last_one_serves_the_new_one_from_its_start(make_record):
    # The robot node switches its devices to the next grasp from its main thread while their
    # reader threads may be inside a read of the last replay, right after taking it. That read
    # must not hand out the last replay's samples again nor skip the new replay's first ones
    # (a live grasp once got no force at all this way).
    last, new_record = make_record(seed=0), make_record(seed=1)
    cell = make_load_cell(LoadCellSettings(), backend="sim").connect()
    camera = make_camera(SensorSettings(finger="left"), backend="sim").connect()
    for device in (cell, camera):
        finished = GraspPlayback(last)
        finished.start(time.monotonic() - 10.0)  # all of it due
        device.replay(finished)
        new = GraspPlayback(new_record)

        def switch_now(timeout_s, device=device, new=new):
            device.replay(new)  # the node's switch, between the reader taking the replay and reading it
            return True

        finished.wait_started = switch_now
        with pytest.raises(DeviceTimeoutError):
            device.read(timeout_s=0.05)
        new.start(time.monotonic() - 0.2)
        if device is cell:
            forces = cell.read(timeout_s=0.5)
            assert forces.t_s[0] == new.live_time(new_record.force_n.t_s[0])
            np.testing.assert_array_equal(forces.value, new_record.force_n.value[: forces.t_s.size])
        else:
            frame = camera.read(timeout_s=0.5)
            assert frame.index == 0 and frame.encoded == new_record.stream("left").encoded[0]


def test_a_camera_told_to_replay_again_from_the_start_while_reading_starts_over(make_record):
    playback = GraspPlayback(make_record())
    playback.start(time.monotonic() - 10.0)  # every frame due
    with make_camera(SensorSettings(finger="left"), playback=playback) as camera:
        assert [camera.read(timeout_s=0.5).index for _ in range(5)] == list(range(5))

        def restart(timeout_s):
            camera.replay(playback)  # from its start on, between the reader taking frame 5 and reading it
            return True

        playback.wait_started = restart
        with pytest.raises(DeviceTimeoutError):
            camera.read(timeout_s=0.05)
        del playback.wait_started
        assert camera.read(timeout_s=0.5).index == 0


def test_sim_devices_do_not_wait_past_their_timeout_for_data_due_later(make_record):
    playback = GraspPlayback(make_record())
    camera = make_camera(SensorSettings(finger="left"), playback=playback)
    cell = make_load_cell(LoadCellSettings(), playback=playback)
    playback.start(t0_s=time.monotonic() + 2.0)  # nothing is due for 2 s
    with camera, cell:
        with pytest.raises(DeviceTimeoutError):
            camera.read(timeout_s=0.1)
        with pytest.raises(DeviceTimeoutError):
            cell.read(timeout_s=0.1)
