"""One contract for every gripper backend: sim always, franky through franky-sim, real hand on request."""

from __future__ import annotations

import dataclasses
import math
import time

import numpy as np
import pytest
from support.contract import assert_every_backend_covered, param_names
from support.threads import close_during_read

from teleop.devices.gripper import BACKENDS, Gripper, make_gripper
from teleop.devices.live_sim import LiveGrasp
from teleop.devices.playback import GraspPlayback, SimulatedGripper
from teleop.errors import (
    BackendNotFoundError,
    DeviceError,
    DeviceNotConnectedError,
    InvalidCommandError,
)
from teleop.settings import GripperSettings, Settings

SPEED = 0.05  # m/s, franky-sim's finger speed limit
STEP_M = SPEED * 0.02  # one franky follow step at SPEED (teleop.devices.franky_gripper.FOLLOW_STEP_S), m


# A backend's name runs the suite on it; "hardware" runs it on a real Franka hand.
PARAMS = ["sim", pytest.param("franky", marks=pytest.mark.robot_sim),
          pytest.param("hardware", marks=pytest.mark.hardware)]


def test_every_backend_in_the_table_runs_the_suite():
    assert_every_backend_covered("gripper", BACKENDS, param_names(PARAMS), fixture="gripper",
                                 where="tests/teleop/devices/test_gripper_contract.py")


@pytest.fixture(params=PARAMS)
def gripper(request, hardware_env) -> Gripper:
    if request.param == "sim":
        settings = GripperSettings(backend="sim", width_read_hz=20.0)
    elif request.param == "franky":
        host = request.getfixturevalue("franky_sim_host")
        settings = GripperSettings(backend="franky", host=host, width_read_hz=20.0)
    else:
        settings = GripperSettings(backend="franky", host=hardware_env("COMPLIANCE_TELEOP_FRANKY_HOST"), width_read_hz=10.0)
    device = make_gripper(settings)
    yield device
    device.close()


def test_unconnected_and_closed_grippers_refuse_every_call(gripper):
    for call in (lambda: gripper.move(0.03), lambda: gripper.widths(), lambda: gripper.read_width(), lambda: gripper.max_width_m):
        with pytest.raises(DeviceNotConnectedError, match="connect"):
            call()
    with gripper:
        assert gripper.connected
    assert not gripper.connected
    with pytest.raises(DeviceNotConnectedError, match="closed"):
        gripper.read_width()
    gripper.close()  # closing twice is harmless


def test_move_reaches_the_width_and_the_reader_timestamps_it(gripper):
    with gripper:
        start = gripper.read_width()[1]
        target = start - 0.01 if start > 0.03 else start + 0.01
        gripper.widths()  # forget what was read before the move
        assert gripper.move(target, speed_m_s=SPEED)
        t_s, width = gripper.read_width()
        samples = gripper.widths(timeout_s=1.0)
        max_width = gripper.max_width_m
    assert width == pytest.approx(target, abs=2e-3)
    assert abs(t_s - time.monotonic()) < 1.0
    assert len(samples) >= 2
    assert np.all(np.diff(samples.t_s) > 0)
    assert np.all((samples.value >= 0) & (samples.value <= max_width + 1e-3))
    assert abs(samples.value[-1] - target) < abs(samples.value[0] - target) + 1e-4  # moving towards the target


def test_grasp_succeeds_where_the_fingers_stop(gripper):
    with gripper:
        assert gripper.move(0.04, speed_m_s=SPEED)
        assert gripper.grasp(0.03, speed_m_s=SPEED, force_n=10.0, epsilon_inner_m=0.005, epsilon_outer_m=0.005)
        assert gripper.is_grasped
        assert gripper.read_width()[1] == pytest.approx(0.03, abs=5e-3)


def test_async_commands_return_futures(gripper):
    with gripper:
        future = gripper.move_async(0.035, speed_m_s=SPEED)
        assert future.result(timeout=5.0)
        future = gripper.grasp_async(0.03, speed_m_s=SPEED, force_n=5.0, epsilon_inner_m=0.01, epsilon_outer_m=0.01)
        assert future.result(timeout=5.0)


def test_stop_when_idle_holds_the_width(gripper):
    with gripper:
        before = gripper.read_width()[1]
        assert gripper.stop()
        time.sleep(0.1)
        assert gripper.read_width()[1] == pytest.approx(before, abs=1e-3)


@pytest.mark.parametrize(
    "command, name",
    [
        (lambda g: g.move(1.0), "width_m"),
        (lambda g: g.move(-0.01), "width_m"),
        (lambda g: g.move(0.02, speed_m_s=0.0), "speed_m_s"),
        (lambda g: g.move(0.02, speed_m_s=math.nan), "speed_m_s"),
        (lambda g: g.grasp(0.02, force_n=500.0), "force_n"),
        (lambda g: g.grasp(0.02, epsilon_inner_m=-1.0), "epsilon_inner_m"),
        (lambda g: g.grasp(0.02, epsilon_outer_m=-1.0), "epsilon_outer_m"),
        (lambda g: g.move_async(math.inf), "width_m"),
        (lambda g: g.grasp_async(0.02, force_n=0.0), "force_n"),
        (lambda g: g.follow(0.5), "width_m"),
        (lambda g: g.follow(math.nan), "width_m"),
        (lambda g: g.follow(0.02, speed_m_s=1.0), "speed_m_s"),
    ],
)
def test_bad_commands_are_refused_before_anything_moves(gripper, command, name):
    with gripper:
        before = gripper.read_width()[1]
        with pytest.raises(InvalidCommandError, match=name):
            command(gripper)
        assert gripper.read_width()[1] == pytest.approx(before, abs=1e-3)


def _still(gripper: Gripper, *, timeout_s: float = 5.0, still_m: float = 1e-4) -> float:
    """The width once two reads 0.15 s apart agree within ``still_m`` (m)."""
    deadline = time.monotonic() + timeout_s
    last = gripper.read_width()[1]
    while time.monotonic() < deadline:
        time.sleep(0.15)
        now = gripper.read_width()[1]
        if abs(now - last) < still_m:
            return now
        last = now
    raise AssertionError(f"the fingers did not settle within {timeout_s} s")


def _settle(gripper: Gripper, target: float, *, near_m: float = 2e-3, timeout_s: float = 5.0,
            still_m: float = 1e-4) -> float:
    """The width once it is within ``near_m`` of ``target`` and two reads 0.15 s apart agree within
    ``still_m``; the last width read if that does not happen within ``timeout_s``.

    Stillness alone is not enough: on a loaded machine franky-sim's thread stalls for longer than
    0.15 s, and fingers still on their way look settled.
    """
    deadline = time.monotonic() + timeout_s
    now = gripper.read_width()[1]
    while time.monotonic() < deadline:
        if abs(now - target) <= near_m:
            time.sleep(0.15)
            last, now = now, gripper.read_width()[1]
            if abs(now - last) < still_m and abs(now - target) <= near_m:
                return now
        else:
            time.sleep(0.01)
            now = gripper.read_width()[1]
    return now  # the caller's assertion shows where the fingers went instead


def test_follow_returns_at_once_and_the_fingers_go_to_the_latest_target(gripper):
    with gripper:
        start = gripper.read_width()[1]
        first = start - 0.01 if start > 0.03 else start + 0.01
        gripper.follow(first, speed_m_s=SPEED)
        # Non-blocking: it returned long before the 10 mm move at SPEED (0.2 s) ended.
        assert abs(gripper.read_width()[1] - first) > 2e-3
        gripper.follow(first + 0.004, speed_m_s=SPEED)  # a new target supersedes the last
        assert _settle(gripper, first + 0.004) == pytest.approx(first + 0.004, abs=2e-3)
        gripper.follow(first - 0.004, speed_m_s=SPEED)
        assert _settle(gripper, first - 0.004) == pytest.approx(first - 0.004, abs=2e-3)
        assert gripper.stop()


def _moved(gripper: Gripper, start: float, *, by_m: float, timeout_s: float = 5.0) -> None:
    """Wait until the width is ``by_m`` (m) away from ``start``."""
    deadline = time.monotonic() + timeout_s
    while abs(gripper.read_width()[1] - start) <= by_m:
        assert time.monotonic() < deadline, f"the fingers did not move {by_m} m in {timeout_s} s"
        time.sleep(0.01)


def test_stop_ends_a_follow_within_one_step_and_a_move_works_after(gripper):
    with gripper:
        start = gripper.read_width()[1]
        target = 0.005 if start > 0.04 else 0.075
        gripper.follow(target, speed_m_s=SPEED)
        _moved(gripper, start, by_m=3e-3)  # stop on the way, however slowly this machine runs
        assert gripper.stop()
        held = _still(gripper)  # a step in flight ends, however slowly this machine runs
        time.sleep(0.3)
        # Stopped: franky-sim's fingers creep on toward the last step's goal, within one step.
        assert gripper.read_width()[1] == pytest.approx(held, abs=STEP_M)
        assert abs(held - start) > 2e-3 and abs(held - target) > 5e-3  # ... on its way
        assert gripper.move(0.04, speed_m_s=SPEED)  # the gripper takes commands again
        assert gripper.read_width()[1] == pytest.approx(0.04, abs=2e-3)


# --------------------------------------------------------------------------- family and sim specifics


def test_unknown_backend_lists_the_names():
    with pytest.raises(BackendNotFoundError, match="sim") as info:
        make_gripper(GripperSettings(), backend="robotiq")
    assert all(name in str(info.value) for name in BACKENDS)


def test_franky_backend_wraps_connection_errors():
    gripper = make_gripper(GripperSettings(backend="franky", host="127.255.255.254"))
    # nothing serves libfranka there (franky-sim takes the first free loopback address)
    # the error says what to do itself: every command opening the gripper shows it
    with pytest.raises(DeviceError, match=r"127\.255\.255\.254: connect failed: .*: check the robot is on with FCI "
                                          r"enabled and `gripper\.host`$"):
        gripper.connect()
    assert not gripper.connected


def test_sim_grasp_stalls_on_an_object_and_judges_the_tolerance():
    settings = GripperSettings(width_read_hz=50.0)
    with SimulatedGripper(settings, object_width_m=0.07) as gripper:
        assert gripper.grasp(0.07, speed_m_s=0.2, epsilon_inner_m=0.002, epsilon_outer_m=0.002)
        assert gripper.read_width()[1] == pytest.approx(0.07)
        assert not gripper.grasp(0.05, speed_m_s=0.2)  # stalls at 0.07, outside 0.05 +- 5 mm
        assert not gripper.is_grasped


def test_sim_stop_interrupts_a_move():
    with SimulatedGripper(GripperSettings(max_width_m=0.08)) as gripper:
        future = gripper.move_async(0.0, speed_m_s=0.01)  # 8 s of travel
        _moved(gripper, 0.08, by_m=1e-3)  # on its way
        assert gripper.stop()
        assert future.result(timeout=5.0) is False
        held = gripper.read_width()[1]
        time.sleep(0.1)
        assert gripper.read_width()[1] == held
        # Stopped on the way: a loaded machine may take a few seconds to stop it, not the 8 s to the end.
        assert 0.02 < held < 0.08 - 1e-3


def test_sim_stop_cancels_the_commands_given_before_it_that_have_not_started():
    # A grasp queued behind a move, then a stop: the stop must not be spent on the move alone. Sim only:
    # franky-sim drops the answer to a move it stops, so its move never returns (test_franky_stop.py
    # takes the franky backend with a stand-in hand).
    with make_gripper(GripperSettings(backend="sim", width_read_hz=20.0)) as gripper:
        start = gripper.read_width()[1]
        far = 0.005 if start > 0.04 else 0.075
        gripper.move_async(far, speed_m_s=SPEED)
        queued = gripper.move_async(start, speed_m_s=SPEED)  # back where it began, were it to run
        grasp = gripper.grasp_async(start, speed_m_s=SPEED)
        _moved(gripper, start, by_m=3e-3)
        assert gripper.stop()
        assert queued.result(timeout=10.0) is False and grasp.result(timeout=10.0) is False
        assert gripper.last_stop is None  # the grasp never began: no stop to mark a loading end by
        held = _still(gripper)
        time.sleep(0.3)
        assert gripper.read_width()[1] == pytest.approx(held, abs=STEP_M)
        assert abs(held - start) > 2e-3  # it did not go back
        assert gripper.move(start, speed_m_s=SPEED)  # a command given after the stop runs


def test_sim_follow_stalls_on_an_object_and_supersedes_a_move():
    with SimulatedGripper(GripperSettings(max_width_m=0.08), object_width_m=0.05) as gripper:
        moving = gripper.move_async(0.07, speed_m_s=0.01)
        time.sleep(0.05)
        gripper.follow(0.03, speed_m_s=0.2)
        assert moving.result(timeout=5.0) is False  # interrupted by the follow
        deadline = time.monotonic() + 5.0  # 0.1 s of travel at 0.2 m/s, on a loaded machine seconds
        while gripper.read_width()[1] > 0.05 + 1e-6 and time.monotonic() < deadline:
            time.sleep(0.01)
        time.sleep(0.1)  # had the object not stopped them, the fingers would go on to 0.03
        assert gripper.read_width()[1] == pytest.approx(0.05)  # the object stops the fingers


def test_sim_grasp_replays_the_recorded_widths(make_record):
    record = make_record(duration_s=0.5)
    playback = GraspPlayback(record)
    with SimulatedGripper(GripperSettings(width_read_hz=5.0), playback=playback) as gripper:
        gripper.widths()  # the open gripper before the grasp command
        started = time.monotonic()
        assert gripper.grasp(0.03, epsilon_inner_m=0.01, epsilon_outer_m=0.01)
        settled = time.monotonic()
        # a replay cannot react: the move waits for its end, then the kinematics take over
        assert gripper.move(0.06, speed_m_s=0.2)
        moved = time.monotonic()
        final = gripper.read_width()[1]
        samples = gripper.widths(timeout_s=0.5)
    assert settled - started == pytest.approx(playback.grasp_settled_s() - playback.live_time(playback.origin_s), abs=0.1)
    assert moved - started == pytest.approx(playback.duration_s + (0.06 - record.width_m.value[-1]) / 0.2, abs=0.1)
    assert final == pytest.approx(0.06)
    n = len(record.width_m)
    np.testing.assert_array_equal(samples.value[:n], record.width_m.value)
    shift = samples.t_s[:n] - record.width_m.t_s
    assert np.ptp(shift) < 1e-9  # the record's own timestamps, moved by one constant
    assert np.all(np.diff(samples.t_s) > 0)
    assert np.all(samples.value[n:] >= record.width_m.value[-1])  # then opening kinematically


def test_a_replayed_grasp_stopped_before_the_fingers_settle_is_not_held(make_record):
    # the grasp did not finish, whatever width the fingers read when it was stopped
    playback = GraspPlayback(make_record(duration_s=5.0))
    with SimulatedGripper(GripperSettings(width_read_hz=5.0), playback=playback) as gripper:
        future = gripper.grasp_async(0.04, epsilon_inner_m=0.05, epsilon_outer_m=0.05)  # any width is in range
        deadline_s = time.monotonic() + 10.0
        while not playback.started:  # the grasp starts the replay
            assert time.monotonic() < deadline_s, "the grasp never started the replay"
            time.sleep(0.005)
        assert gripper.stop()
        assert future.result(timeout=5.0) is False and not gripper.is_grasped
        assert not playback.done()  # stopped during the replay


def test_a_grasp_remembers_where_it_stopped_and_queues_that_width_in_order(gripper):
    with gripper:
        assert gripper.move(0.04, speed_m_s=SPEED)
        assert gripper.last_stop is None  # no grasp yet
        gripper.widths()
        before = time.monotonic()
        held = gripper.grasp(0.03, speed_m_s=SPEED, force_n=10.0, epsilon_inner_m=0.005, epsilon_outer_m=0.005)
        stop = gripper.last_stop
        samples = gripper.widths(timeout_s=0.5)
    assert stop is not None and stop.held == held
    assert before < stop.stopped_s <= stop.width_t_s <= time.monotonic()
    assert stop.width_m == pytest.approx(0.03, abs=5e-3)
    assert stop.width_t_s in samples.t_s.tolist() and np.all(np.diff(samples.t_s) > 0)


def test_sim_grasp_stops_where_the_replayed_fingers_do(make_record):
    record = make_record(duration_s=0.5, command_grasp_s=2.0)
    record = dataclasses.replace(record, events={"command_grasp": 2.0, "grasp_done": 2.2, "command_release": 2.4})
    with SimulatedGripper(GripperSettings(width_read_hz=20.0)) as gripper:
        playback = GraspPlayback(record)
        gripper.replay(playback)
        assert gripper.grasp(0.0, epsilon_outer_m=0.08)
        stop = gripper.last_stop
        samples = gripper.widths(timeout_s=0.5)
    assert stop.stopped_s == pytest.approx(playback.grasp_settled_s(), abs=0.02)
    # The stop's read is the record's next read, handed out at the stop with its recorded stamp, after
    # the recorded widths due by then: the live widths are the recorded ones, in time order.
    recorded = playback.live_time(record.width_m.t_s)
    after_stop = int(np.searchsorted(recorded, stop.stopped_s))
    assert stop.width_t_s == recorded[after_stop] > stop.stopped_s
    assert stop.width_m == record.width_m.value[after_stop]
    replayed = samples.t_s[samples.t_s >= playback.live_time(playback.origin_s)]  # not the reads before the start
    assert np.all(np.diff(samples.t_s) > 0)
    assert replayed[-1] == stop.width_t_s and np.allclose(replayed, recorded[: after_stop + 1])


def test_sim_widths_of_a_replay_that_ended_between_two_reads_are_all_handed_out(make_record):
    record = make_record(duration_s=0.5)
    playback = GraspPlayback(record)
    playback.start(t0_s=time.monotonic() - 10.0)  # ended before the reader's first read
    with SimulatedGripper(GripperSettings(width_read_hz=5.0), playback=playback) as gripper:
        samples = gripper.widths(timeout_s=1.0)
    n = len(record.width_m)
    np.testing.assert_array_equal(samples.value[:n], record.width_m.value)
    np.testing.assert_allclose(samples.t_s[:n], playback.live_time(record.width_m.t_s), rtol=0, atol=1e-9)


def test_sim_the_read_handed_out_at_a_grasp_stop_is_not_handed_out_again(make_record):
    record = make_record(duration_s=0.5, command_grasp_s=2.0)
    record = dataclasses.replace(record, events={"command_grasp": 2.0, "grasp_done": 2.2, "command_release": 2.4})
    playback = GraspPlayback(record)
    with SimulatedGripper(GripperSettings(width_read_hz=20.0), playback=playback) as gripper:
        assert gripper.grasp(0.0, epsilon_outer_m=0.08)
        stop = gripper.last_stop
        t = list(gripper.widths().t_s)
        deadline = time.monotonic() + 5.0
        while not playback.done() and time.monotonic() < deadline:  # the rest of the replay
            t.extend(gripper.widths(timeout_s=0.2).t_s)
        t.extend(gripper.widths(timeout_s=0.3).t_s)  # and a read or two after it
    recorded = playback.live_time(record.width_m.t_s)
    assert t.count(stop.width_t_s) == 1
    replayed = [s for s in t if s >= playback.live_time(playback.origin_s) and s in set(recorded.tolist())]
    assert replayed == recorded.tolist()  # every recorded read, once, in order
    assert np.all(np.diff(t) > 0)


def test_sim_kinematic_grasp_short_of_the_object_stops_at_its_width():
    with SimulatedGripper(GripperSettings(max_width_m=0.08, width_read_hz=50.0), object_width_m=0.03) as gripper:
        assert gripper.grasp(0.05, speed_m_s=0.2, epsilon_inner_m=0.002, epsilon_outer_m=0.002)
        assert gripper.read_width()[1] == pytest.approx(0.05)


class _NoObject:
    """A stand-in for :class:`~teleop.sim.live.LiveObject`: nothing between the fingers."""

    stall_width_m = 0.0

    def force_at(self, width_m: float) -> float:
        return 0.0

    def frame(self, finger: str, force_n: float) -> bytes:
        return b"jpeg"


def test_sim_leaving_live_mode_keeps_the_fingers_where_the_live_motor_left_them():
    with SimulatedGripper(GripperSettings(max_width_m=0.08, width_read_hz=50.0)) as gripper:
        assert gripper.read_width()[1] == pytest.approx(0.08)
        grasp = LiveGrasp(_NoObject(), settings=Settings(), rng=np.random.default_rng(0), width_m=0.08)
        gripper.live(grasp)
        assert gripper.move(0.05, speed_m_s=0.2)
        gripper.live(None)
        assert gripper.read_width()[1] == pytest.approx(0.05, abs=1e-3)  # not back at 0.08


def test_sim_gripper_replaying_a_grasp_refuses_to_follow(make_record):
    playback = GraspPlayback(make_record(duration_s=5.0))
    with SimulatedGripper(GripperSettings(), playback=playback) as gripper:
        playback.start()
        with pytest.raises(DeviceError, match="replays a recorded grasp"):
            gripper.follow(0.03)


def test_a_width_read_is_stamped_when_it_returns_as_the_training_records_are():
    # A Franka hand's read takes about 0.1 s. The simulated records the model learned from, the live
    # simulation and the estimator's lag model all stamp a read when it returns: so does every backend.
    class SlowRead(SimulatedGripper):
        def _read_width(self) -> float:
            time.sleep(0.05)
            return super()._read_width()

    with SlowRead(GripperSettings(max_width_m=0.08)) as gripper:
        before = time.monotonic()
        t_s, _ = gripper.read_width()
        after = time.monotonic()
    assert before + 0.05 <= t_s <= after


def test_close_wakes_a_widths_call_waiting_in_another_thread(gripper):
    # A slow reader: after its first read at connect, the queue stays empty for 3 s.
    with make_gripper(dataclasses.replace(gripper.settings, width_read_hz=0.3)) as slow:
        slow.widths(timeout_s=1.0)
        ended = close_during_read(lambda: slow.widths(timeout_s=3.0), slow.close, errors=DeviceError, waiting_s=0.2)
    # Woken by close(), not by the 3 s timeout: bounded well below it, as a loaded machine is slow.
    assert isinstance(ended.outcome, DeviceNotConnectedError) and ended.ended_s < 2.0


@pytest.mark.parametrize("timeout", [-1.0, math.inf, math.nan, True])
def test_bad_widths_timeouts_are_refused(gripper, timeout):
    with gripper:
        started = time.monotonic()
        with pytest.raises(InvalidCommandError, match="timeout_s"):
            gripper.widths(timeout_s=timeout)
        assert time.monotonic() - started < 0.5
        assert isinstance(gripper.widths(timeout_s=0), type(gripper.widths()))  # 0 polls


def test_a_reconnected_gripper_forgets_the_last_connections_widths_and_stop(gripper):
    with gripper:
        assert gripper.move(0.04, speed_m_s=SPEED)
        gripper.grasp(0.03, speed_m_s=SPEED, force_n=10.0)
        assert gripper.last_stop is not None
        time.sleep(0.1)  # the reader queues a few more
    reopened = time.monotonic()
    with gripper:
        assert gripper.last_stop is None
        samples = gripper.widths(timeout_s=1.0)
    assert len(samples) and samples.t_s.min() >= reopened
