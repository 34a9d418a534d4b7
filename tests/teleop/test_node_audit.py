"""Audit of the robot node's loop outside command handling (:mod:`teleop.node`): what a stop does to a
grasp under way, what goes out of the readers' captures and with which grasp, the loading-end
marker's conditions, device notices, the gripper failing, and robot_state. On an unconnected node
(no reader threads) with a publisher that keeps what is sent and a fake clock: nothing here waits."""

from __future__ import annotations

import dataclasses
from concurrent.futures import Future

import numpy as np
import pytest
from support.bus import KeptPublisher

from teleop.devices.camera import CameraFrame
from teleop.devices.gripper import GraspStop
from teleop.errors import DeviceError
from teleop.grasp_data import Samples
from teleop.node import RobotNode, _Grasp
from teleop.scene import load_scene


class _Clock:
    def __init__(self):
        self.t = 100.0

    def __call__(self) -> float:
        return self.t


@pytest.fixture
def rig():
    """An unconnected simulated node: ``(node, publisher, clock)``."""
    scene = load_scene("quick")
    clock, publisher = _Clock(), KeptPublisher()
    node = RobotNode(scene.settings, publisher=publisher, scene=scene, clock=clock)
    yield node, publisher, clock
    node.close()


def _events(publisher: KeptPublisher) -> list[str]:
    return [body["event"] for body in publisher.of("grasp_event")]


def _started(node: RobotNode, grasp_id: str = "g1") -> _Grasp:
    """A grasp under way: its start went out at the clock's time."""
    node._grasp = _Grasp(grasp_id, "obj", phase="tail")
    node._announce("start")
    return node._grasp


def _samples(*t_s: float, value: float = 1.0) -> Samples:
    return Samples(np.array(t_s), np.full(len(t_s), value))


def _frame(t_s: float, index: int = 0) -> CameraFrame:
    return CameraFrame(finger="left", index=index, t_s=t_s, encoded=b"\xff\xd8jpeg", encoding="jpeg")


def _done(exception: BaseException | None = None) -> Future:
    future: Future = Future()
    if exception is None:
        future.set_result(True)
    else:
        future.set_exception(exception)
    return future


# --------------------------------------------------------------------------- stopping


def test_stopping_while_a_grasp_is_only_prepared_sends_no_end_for_it(rig):
    node, publisher, _ = rig
    node._grasp = _Grasp("g1", "obj")  # simulating: no start went out
    node.finish()
    assert _events(publisher) == [] and node.stats.grasps == 0


def test_stopping_mid_grasp_publishes_what_was_captured_then_its_end(rig):
    node, publisher, clock = rig
    _started(node)
    clock.t += 0.1
    node._captured.put(("force", _samples(100.05, 100.06, value=2.5)))
    node._captured.put(("frame", _frame(100.07)))
    node.finish()
    kinds = [kind for kind, body in publisher.sent]
    assert kinds == ["grasp_event", "force", "frame", "grasp_event"]  # nothing captured is lost behind the end
    assert _events(publisher) == ["start", "end"] and node.stats.grasps == 1 and not node.busy
    assert publisher.of("force")[0]["grasp_id"] == publisher.of("frame")[0]["grasp_id"] == "g1"
    assert (node.stats.force_batches, node.stats.frames) == (1, 1)


def test_stopping_mid_grasp_stops_the_fingers_before_its_end_goes_out(rig, monkeypatch):
    node, publisher, _ = rig
    _started(node)
    stops = []
    monkeypatch.setattr(node.gripper, "stop", lambda: stops.append(_events(publisher)) or True)
    node.finish()
    assert stops == [["start"]] and _events(publisher) == ["start", "end"]


def test_fingers_that_cannot_be_stopped_still_let_the_grasp_end_on_the_bus(rig, caplog):
    node, publisher, _ = rig
    _started(node)
    node.finish()  # the node is not connected: its gripper refuses the stop
    assert _events(publisher) == ["start", "end"] and not node.busy
    assert "the fingers could not be stopped" in caplog.text


def test_stopping_between_grasps_leaves_the_fingers_alone(rig, monkeypatch):
    node, _, _ = rig
    monkeypatch.setattr(node.gripper, "stop", lambda: pytest.fail("stopped fingers no grasp moved"))
    node.finish()


class _LetGo:
    """A live object the fingers no longer press."""

    def force_at(self, t_s: float) -> float:
        return 0.0


def test_a_grasp_that_ends_lets_go_of_the_object_the_fingers_no_longer_press(rig):
    node, publisher, _ = rig
    _started(node)
    node._follower.live = _LetGo()
    node._end()
    assert _events(publisher) == ["start", "end"] and node._follower.live is None
    assert "g1" in node._follower.ended and node._next_live is not None  # the next object is prepared


def test_stopping_counts_the_frames_every_camera_dropped(rig):
    node, _, _ = rig
    for dropped, camera in zip((3, 4), node.cameras, strict=True):
        camera.dropped = dropped
    node.finish()
    assert node.stats.frames_dropped == 7


# --------------------------------------------------------------------------- captures on the bus


def test_a_batch_is_the_grasps_from_its_first_sample_captured_at_or_after_the_start(rig):
    node, publisher, clock = rig
    node._publish("width", _samples(99.9, 100.0))  # before any grasp
    _started(node)  # at 100.0
    node._publish("width", _samples(99.99, 100.01))  # straddles the start: not the grasp's
    node._publish("width", _samples(100.0, 100.02, value=0.03))  # from the start on
    node._publish("frame", _frame(99.995))
    node._publish("frame", _frame(100.0, index=1))
    widths, frames = publisher.of("width"), publisher.of("frame")
    assert [w["grasp_id"] for w in widths] == [None, None, "g1"]
    assert [f["grasp_id"] for f in frames] == [None, "g1"]
    assert [w["t_capture_s"] for w in widths] == [100.0, 100.01, 100.02]  # stamped with the newest sample
    assert widths[-1]["value_m"].tolist() == [0.03, 0.03]
    assert (node.stats.width_batches, node.stats.frames, node.stats.force_batches) == (3, 2, 0)


def test_the_force_cap_and_the_closing_check_read_the_newest_sample_of_a_batch(rig):
    # teleop.follow caps a follow grasp's force, and tells closing from opening, on these values.
    node, _, _ = rig
    node._publish("force", Samples(np.array([100.0, 100.01, 100.02]), np.array([1.0, 9.0, 30.0])))
    node._publish("width", Samples(np.array([100.0, 100.01]), np.array([0.05, 0.02])))
    assert node._latest == {"force": 30.0, "width": 0.02}


def test_a_device_that_fails_again_is_said_again_and_reading_again_is_no_error(rig):
    node, publisher, _ = rig
    for reason in ("link lost; opening it again", "reading again", "link lost; opening it again"):
        node._publish("device_error", ("camera/left", reason))
    notices = publisher.of("robot_notice")
    assert [(n["event"], n["action"], n["reason"]) for n in notices] == [
        ("device", "camera/left", "link lost; opening it again"), ("device", "camera/left", "reading again"),
        ("device", "camera/left", "link lost; opening it again")]
    assert node.stats.device_errors == 2


# --------------------------------------------------------------------------- the loading-end marker


def _stopped_grasp(node: RobotNode, monkeypatch, stop: GraspStop) -> _Grasp:
    grasp = _started(node)
    grasp.grasp_command = command = _done()
    monkeypatch.setattr(type(node.gripper), "last_stop", property(lambda self: stop))
    node._publish("grasp_stopped", command)
    return grasp


def test_the_marker_waits_for_the_width_read_at_the_stop_and_a_force_at_or_after_it(rig, monkeypatch):
    node, publisher, _ = rig
    _stopped_grasp(node, monkeypatch, GraspStop(stopped_s=100.5, width_t_s=100.52, width_m=0.02, held=True))
    node._publish("force", _samples(100.1, 100.4))  # the load cell delivers during the grasp
    node._publish("width", _samples(100.3, 100.5))
    assert _events(publisher) == ["start"]  # the width read at the stop is not out yet
    node._publish("width", _samples(100.52))
    assert _events(publisher) == ["start"]  # nor a force captured at or after the stop
    node._publish("force", _samples(100.45, 100.5))  # at the stop itself: enough
    assert _events(publisher) == ["start", "loading_end"]
    assert publisher.of("grasp_event")[-1]["t_capture_s"] == 100.5  # stamped when the fingers stopped
    node._publish("width", _samples(100.6))
    node._publish("force", _samples(100.6))
    assert _events(publisher) == ["start", "loading_end"]  # once


def test_the_marker_waits_for_the_width_read_at_the_stop_when_the_forces_are_ahead(rig, monkeypatch):
    node, publisher, _ = rig
    _stopped_grasp(node, monkeypatch, GraspStop(stopped_s=100.5, width_t_s=100.52, width_m=0.02, held=True))
    node._publish("force", _samples(100.3, 100.6))  # a force captured after the stop is out
    node._publish("width", _samples(100.4, 100.51))
    assert _events(publisher) == ["start"]  # widths up to the stop precede the marker
    node._publish("width", _samples(100.52))
    assert _events(publisher) == ["start", "loading_end"]


def test_a_load_cell_silent_since_the_grasp_began_does_not_hold_the_marker(rig, monkeypatch):
    node, publisher, _ = rig
    node._publish("force", _samples(99.5))  # before the grasp: then silent
    _stopped_grasp(node, monkeypatch, GraspStop(stopped_s=100.5, width_t_s=100.52, width_m=0.02, held=True))
    node._publish("width", _samples(100.52))
    assert _events(publisher) == ["start", "loading_end"]


def test_an_older_width_batch_does_not_take_back_the_width_already_out(rig, monkeypatch):
    node, publisher, _ = rig
    node._publish("force", _samples(99.5))
    grasp = _started(node)
    node._publish("width", _samples(100.6))
    node._publish("width", _samples(100.2))  # a batch of older samples, published later
    grasp.grasp_command = command = _done()
    stop = GraspStop(stopped_s=100.5, width_t_s=100.55, width_m=0.02, held=True)
    monkeypatch.setattr(type(node.gripper), "last_stop", property(lambda self: stop))
    node._publish("grasp_stopped", command)
    assert _events(publisher) == ["start", "loading_end"]


def test_the_wake_up_of_an_earlier_grasp_command_marks_nothing(rig, monkeypatch):
    node, publisher, _ = rig
    grasp = _started(node)
    grasp.grasp_command = _done()
    stop = GraspStop(stopped_s=100.5, width_t_s=100.5, width_m=0.02, held=True)
    monkeypatch.setattr(type(node.gripper), "last_stop", property(lambda self: stop))
    node._publish("width", _samples(100.6))
    node._publish("grasp_stopped", _done())  # not this grasp's command
    assert _events(publisher) == ["start"] and grasp.stop is None


def test_a_replays_failed_grasp_command_leaves_the_replay_running(rig):
    node, publisher, _ = rig
    grasp = _started(node)  # simulated, not a follow grasp: a replay
    grasp.grasp_command = command = _done(DeviceError("halted"))
    node._publish("grasp_stopped", command)
    assert node.busy and _events(publisher) == ["start"] and not publisher.of("robot_notice")
    assert node.stats.device_errors == 0


# --------------------------------------------------------------------------- the gripper failing


def test_a_gripper_failing_mid_grasp_is_said_counted_and_ends_the_grasp(rig):
    node, publisher, _ = rig
    _started(node)
    node._gripper_failed(DeviceError("link down"))
    (notice,) = publisher.of("robot_notice")
    assert (notice["event"], notice["action"], notice["grasp_id"]) == ("device", "gripper", "g1")
    assert "link down" in notice["reason"]
    assert _events(publisher) == ["start", "end"] and node.stats.device_errors == 1 and not node.busy


def test_a_gripper_failing_before_the_grasp_started_sends_no_end_and_keeps_it_from_starting_again(rig):
    node, publisher, _ = rig
    node._grasp = _Grasp("g1", None, phase="grasping")  # its command refused before the start went out
    node._gripper_failed(DeviceError("link down"))
    assert _events(publisher) == [] and not node.busy and node.stats.device_errors == 1
    assert "g1" in node._follower.ended  # a console's follows naming it do not start it again


def test_a_failing_gripper_command_in_the_grasps_progress_does_not_stop_the_node(rig, monkeypatch):
    node, publisher, _ = rig
    grasp = _started(node)

    def failing(*args, **kwargs):
        raise DeviceError("link down")

    monkeypatch.setattr(node.gripper, "move_async", failing)
    grasp.phase_until_s = 0.0  # the replay is over: its opening move fails
    node.step(timeout_s=0.0)
    assert _events(publisher) == ["start", "end"] and node.stats.device_errors == 1
    assert publisher.of("robot_state")[-1]["mode"] == "idle"


# --------------------------------------------------------------------------- robot_state


class _QueuedCommands:
    def __init__(self, count: int):
        self.left = count

    def recv(self, timeout_s=None):
        if not self.left:
            return None
        self.left -= 1
        return object()


def test_a_flood_of_commands_holds_a_step_for_about_5_ms_of_refusals_at_most(rig, monkeypatch):
    # 50 commands a step (about 5 ms of refused follows): more would hold off the watchdog that long.
    node, _, _ = rig
    node.commands = commands = _QueuedCommands(1000)
    taken: list[object] = []
    monkeypatch.setattr(node, "handle_command", taken.append)
    node.step(timeout_s=0.0)
    assert len(taken) == 50 and commands.left == 950
    node.step(timeout_s=0.0)
    assert len(taken) == 100


def test_a_robot_state_goes_out_on_a_change_and_with_every_heartbeat_only(rig):
    node, publisher, _ = rig
    for _ in range(3):
        node.step(timeout_s=0.0)
    assert [s["mode"] for s in publisher.of("robot_state")] == ["idle"]
    publisher.beat = True
    node.step(timeout_s=0.0)
    node.step(timeout_s=0.0)
    assert [s["mode"] for s in publisher.of("robot_state")] == ["idle", "idle"]
    node._follower.stopped = True  # the watchdog stopped the fingers
    node.step(timeout_s=0.0)
    assert publisher.of("robot_state")[-1]["mode"] == "stopped"


def test_a_robot_state_carries_a_follow_grasps_target_width_only(rig):
    node, publisher, _ = rig
    node._grasp = _Grasp("g1", "obj", phase="following", follow=True, target_width_m=0.031)
    node._send_state()
    node._grasp = _Grasp("g2", "obj", phase="tail", target_width_m=0.02)  # a replay's: no target of the operator
    node._send_state()
    assert [(s["mode"], s["grasp_id"], s["target_width_m"]) for s in publisher.of("robot_state")] == [
        ("following", "g1", 0.031), ("grasping", "g2", None)]


def _hardware(settings):
    return dataclasses.replace(settings, gripper=dataclasses.replace(settings.gripper, backend="franky",
                                                                     host="127.0.0.1"))


@pytest.mark.parametrize("phase, mode", [("grasping", "grasping"), ("holding", "holding"),
                                         ("releasing", "releasing"), ("tail", "releasing")])
def test_a_hardware_grasps_phases_are_its_modes(phase, mode):
    scene = load_scene("quick")
    publisher = KeptPublisher()
    node = RobotNode(_hardware(scene.settings), publisher=publisher, clock=_Clock())
    try:
        assert not node.simulated
        node._grasp = _Grasp("g1", None, phase=phase)
        node._send_state()
        assert publisher.of("robot_state")[-1]["mode"] == mode
    finally:
        node.close()


def test_closing_stops_every_reader_before_the_devices_go(rig):
    # A reader left running would find its device closed and open it again.
    node, _, _ = rig
    node.connect()
    assert node._next_live is not None  # the first live object is prepared from the start
    readers = list(node._io._threads)
    assert {thread.name for thread in readers} == {"camera-left", "camera-right", "load-cell", "gripper"}
    node.close()
    assert [thread.name for thread in readers if thread.is_alive()] == []
    assert not node.gripper.connected and not node.load_cell.connected
    assert not any(camera.connected for camera in node.cameras)


def test_a_hardware_grasp_holds_for_hold_s_then_opens_fully_and_ends_after_its_tail(monkeypatch):
    from teleop.node import TAIL_S

    scene = load_scene("quick")
    clock, publisher = _Clock(), KeptPublisher()
    node = RobotNode(_hardware(scene.settings), publisher=publisher, clock=clock)
    try:
        gripper = node.settings.gripper
        opening: Future = Future()
        moves: list[float] = []
        monkeypatch.setattr(node.gripper, "move_async", lambda width_m: moves.append(width_m) or opening)
        node._grasp = grasp = _Grasp("g1", None, phase="grasping")
        grasp.motion = _done()  # the fingers closed on the object
        node._announce("start")
        node._advance()
        assert grasp.phase == "holding"
        clock.t += gripper.hold_s * 0.99
        node._advance()
        assert grasp.phase == "holding" and moves == []
        clock.t = 100.0 + gripper.hold_s
        node._advance()
        assert grasp.phase == "releasing" and moves == [gripper.max_width_m]  # opened fully
        clock.t += 10.0
        node._advance()
        assert grasp.phase == "releasing"  # until the fingers have opened
        opening.set_result(True)
        node._advance()
        assert grasp.phase == "tail"
        opened_s = clock.t
        clock.t = opened_s + TAIL_S * 0.99
        node._advance()
        assert node.busy  # the readers' last data of the grasp may still come
        clock.t = opened_s + TAIL_S
        node._advance()
        assert not node.busy and _events(publisher) == ["start", "end"] and moves == [gripper.max_width_m]
    finally:
        node.close()


def test_a_grasp_that_cannot_be_simulated_is_started_and_ended_on_the_bus(rig):
    from teleop.errors import SimulationError

    node, publisher, _ = rig
    node._grasp = grasp = _Grasp("g1", "obj")
    grasp.prepared = Future()
    grasp.prepared.set_exception(SimulationError("no contact"))
    node._advance()
    assert _events(publisher) == ["start", "end"] and not node.busy  # an end never comes without its start


def test_a_replay_takes_the_fingers_stopping_them_first_and_leaves_no_live_object(rig, monkeypatch):
    # The last replay's opening move may still run: the replay's grasp command must not queue behind it
    # (its stop is the loading-end marker); an object a follow grasp left between the fingers is gone.
    node, publisher, _ = rig
    for device in node._devices:  # no readers: only the devices the replay plays through
        device.connect()
    node.start_grasp(object_index=0)
    node._grasp.prepared.result(timeout=120.0)
    calls: list[str] = []
    stop, grasp_async = node.gripper.stop, node.gripper.grasp_async
    monkeypatch.setattr(node.gripper, "stop", lambda: calls.append("stop") or stop())
    monkeypatch.setattr(node.gripper, "grasp_async", lambda *a, **k: calls.append("grasp") or grasp_async(*a, **k))
    node._follower.live = object()  # left by a follow grasp the watchdog ended
    node._advance()
    assert calls == ["stop", "grasp"] and node._follower.live is None
    assert _events(publisher) == ["start"] and node._grasp.phase == "tail"


def test_a_hardware_grasp_command_cancelled_before_it_ran_is_no_failure():
    # A cancelled future has no exception to ask for (asking raises): the node must not take it for one.
    scene = load_scene("quick")
    publisher = KeptPublisher()
    node = RobotNode(_hardware(scene.settings), publisher=publisher, clock=_Clock())
    try:
        node._grasp = grasp = _Grasp("g1", None, phase="grasping")
        grasp.motion = Future()
        grasp.motion.cancel()
        node._announce("start")
        node._advance()
        assert grasp.phase == "holding" and node.stats.device_errors == 0
    finally:
        node.close()
