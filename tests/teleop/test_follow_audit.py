"""Follow grasps at unit level (teleop.follow): the robot node on the test's clock, fingers and bus,
with the hardware path (load-cell force cap) unless a test says otherwise. No sockets, no waiting."""

from __future__ import annotations

from concurrent.futures import Future
from types import SimpleNamespace

import numpy as np
import pytest
from support.operator_fakes import Clock, SubscribedPublisher

import teleop.follow as follow_module
from teleop.bus.wire import make_message
from teleop.errors import DeviceError, InvalidCommandError
from teleop.grasp_data import Samples
from teleop.node import RobotNode, _Grasp
from teleop.operator import WATCHDOG_S
from teleop.scene import load_scene


class Sent(SubscribedPublisher):
    """A publisher recording what the node sends."""

    def __init__(self):
        self.sent: list[tuple[str, dict]] = []

    def send(self, kind: str, **fields) -> None:
        self.sent.append((kind, fields))

    def of(self, kind: str) -> list[dict]:
        return [fields for sent, fields in self.sent if sent == kind]


class Fingers:
    """A gripper recording the node's calls, its fingers at ``width_m``."""

    def __init__(self, width_m: float = 0.08):
        self.width_m = width_m
        self.calls: list[tuple] = []

    def stop(self) -> bool:
        self.calls.append(("stop",))
        return True

    def follow(self, width_m: float) -> None:
        self.calls.append(("follow", width_m))

    def move_async(self, width_m: float) -> Future:
        self.calls.append(("move", width_m))
        done: Future = Future()
        done.set_result(True)
        return done

    def grasp_async(self, width_m: float, **options) -> Future:
        self.calls.append(("grasp", options.get("force_n")))
        return Future()

    def read_width(self) -> tuple[float, float]:
        return 0.0, self.width_m

    def live(self, live) -> None:
        pass

    def replay(self, playback) -> None:
        pass

    def moves(self) -> list[tuple]:
        return [call for call in self.calls if call[0] != "stop"]


@pytest.fixture
def node():
    scene = load_scene("quick")
    node = RobotNode(scene.settings, publisher=Sent(), scene=scene, clock=Clock())
    node.gripper = Fingers()
    node.simulated = False  # the hardware path: the node caps the force on what the load cell reads
    yield node
    node._simulator.shutdown(wait=False, cancel_futures=True)


def maximum(node) -> float:
    return node.settings.gripper.target_force_n


def reads(node, *, force_n: float | None = None, width_m: float | None = None) -> None:
    """The devices' samples, captured now, published by the node."""
    t = np.array([node.clock()])
    if force_n is not None:
        node._publish("force", Samples(t, np.array([force_n])))
    if width_m is not None:
        node._publish("width", Samples(t, np.array([width_m])))


def live(node, grasp_id: str = "g1", width_m: float = 0.07) -> _Grasp:
    """Follow grasp ``grasp_id`` started (hardware: live at once), fingers at 70 mm, 1 N fresh."""
    reads(node, force_n=1.0, width_m=0.07)
    node._follower.follow(grasp_id, width_m, True)
    assert node._grasp.phase == "following"
    return node._grasp


def notices(node, event: str | None = None) -> list[dict]:
    return [n for n in node.publisher.of("robot_notice") if event is None or n["event"] == event]


# ---------------------------------------------------------------------------- the force cap


def test_closing_stops_once_the_load_cell_reads_exactly_the_maximum_force(node):
    grasp = live(node)
    node.gripper.calls.clear()
    reads(node, force_n=maximum(node))
    node._follower.follow("g1", 0.0, True)
    assert node.gripper.calls == [("stop",)]  # stopped, not driven on toward 0 mm
    assert [n["grasp_id"] for n in notices(node, "force_limit")] == ["g1"] and grasp.force_limited


def test_the_force_limit_is_said_once_per_grasp(node):
    live(node)
    reads(node, force_n=maximum(node) + 5.0)
    for width in (0.05, 0.04, 0.03):
        node._follower.follow("g1", width, True)
    assert len(notices(node, "force_limit")) == 1
    assert not [call for call in node.gripper.moves() if call[1] < 0.07]


def test_at_the_maximum_force_the_fingers_may_still_open(node):
    live(node)
    reads(node, force_n=maximum(node) + 5.0, width_m=0.04)
    node.gripper.calls.clear()
    node._follower.follow("g1", 0.06, True)
    assert node.gripper.calls == [("follow", 0.06)] and not notices(node, "force_limit")


def test_below_the_maximum_force_on_a_fresh_reading_the_fingers_close(node):
    live(node)
    reads(node, force_n=0.5 * maximum(node), width_m=0.07)
    node._follower.follow("g1", 0.05, True)
    assert node.gripper.calls[-1] == ("follow", 0.05)


def test_with_no_width_read_yet_a_target_counts_as_closing_and_is_capped(node):
    # Nothing says where the fingers are: the cap must not be skipped for want of a width.
    reads(node, force_n=maximum(node))
    node._follower.follow("g1", 0.07, True)
    assert ("follow", 0.07) not in node.gripper.calls and notices(node, "force_limit")


def test_a_load_cell_silent_just_over_its_limit_stops_the_closing_fingers_and_says_why(node):
    live(node)
    node.gripper.calls.clear()
    node.clock.t += 0.11  # the last force (at the start) over 0.1 s old: 8 samples at the HX711's 80 Hz
    node._follower.follow("g1", 0.03, True)
    assert node.gripper.calls == [("stop",)]
    said = notices(node, "refused")
    assert [(n["action"], n["grasp_id"]) for n in said] == [("follow", "g1")]
    assert "load cell has sent no force" in said[0]["reason"]


def test_a_load_cell_never_heard_keeps_the_fingers_from_closing(node):
    node._publish("width", Samples(np.array([node.clock()]), np.array([0.07])))
    node._follower.follow("g1", 0.0, True)
    assert node.gripper.moves() == [] and ("stop",) in node.gripper.calls


def test_fingers_closing_between_follows_stop_once_the_load_cell_reads_the_maximum_force(node):
    # The hardware fingers keep closing toward the last target between follows (a follow every 20 ms,
    # none for up to the watchdog's 200 ms when the console hiccups): the cap must not wait for the next one.
    live(node)
    node._follower.follow("g1", 0.0, True)
    assert node.gripper.calls[-1] == ("follow", 0.0)
    node.clock.t += 0.01
    reads(node, force_n=maximum(node), width_m=0.05)
    node.step(timeout_s=0)
    assert node.gripper.calls[-1] == ("stop",) and node._grasp is not None
    assert [n["grasp_id"] for n in notices(node, "force_limit")] == ["g1"]
    for _ in range(3):  # stopped once, not again at every step
        node.clock.t += 0.005
        node.step(timeout_s=0)
    assert node.gripper.calls.count(("stop",)) == 1


def test_fingers_closing_between_follows_stop_when_the_load_cell_falls_silent(node):
    live(node)
    node._follower.follow("g1", 0.0, True)
    node.clock.t += 0.11  # no force since: the closing cannot be capped
    node.step(timeout_s=0)
    assert node.gripper.calls[-1] == ("stop",)
    assert "load cell has sent no force" in notices(node, "refused")[0]["reason"]


def test_fingers_opening_between_follows_are_not_stopped_by_the_cap(node):
    live(node)
    reads(node, force_n=maximum(node) + 5.0, width_m=0.04)
    node._follower.follow("g1", 0.06, True)
    node.clock.t += 0.01
    reads(node, force_n=maximum(node) + 5.0, width_m=0.045)
    node.step(timeout_s=0)
    assert ("stop",) not in node.gripper.calls


def test_the_simulated_robot_leaves_the_force_cap_to_its_physics(node):
    # Simulated fingers stall at the maximum force by themselves: the node's cap (on a load cell
    # sample) is the hardware's; a simulated grasp is driven on.
    node.simulated = True
    grasp = _Grasp("s1", "ball", follow=True, phase="following", started_s=node.clock(), target_width_m=0.0)
    node._latest.update(force=2 * maximum(node), width=0.07)
    node._follower._drive_fingers(grasp)
    assert node.gripper.calls == [("follow", 0.0)]


# ---------------------------------------------------------------------------- the dead-man (enable)


def test_a_follow_without_enable_starts_no_grasp(node):
    reads(node, force_n=1.0, width_m=0.07)
    node._follower.follow("g1", 0.0, False)
    assert node._grasp is None and node.gripper.moves() == []
    assert not node.publisher.of("grasp_event")


def test_letting_go_of_the_enable_stops_the_fingers_and_clears_the_target(node):
    grasp = live(node, width_m=0.05)
    node.gripper.calls.clear()
    node._follower.follow("g1", 0.0, False)
    assert node.gripper.calls == [("stop",)]
    assert grasp.target_width_m is None and node._follower.enable is False and grasp.phase == "following"


def test_a_let_go_follow_beyond_the_gripper_width_still_stops_the_fingers(node):
    # Only an enabled target must fit the gripper: a let-go follow is the dead-man, whatever its width.
    live(node, width_m=0.05)
    node.gripper.calls.clear()
    node._follower.follow("g1", 10 * node.settings.gripper.max_width_m, False)
    assert node.gripper.calls == [("stop",)] and node._follower.enable is False


def test_a_target_at_the_gripper_width_is_followed_and_one_beyond_it_refused(node):
    widest = node.settings.gripper.max_width_m
    live(node, width_m=widest)
    assert node.gripper.calls[-1] == ("follow", widest)
    with pytest.raises(InvalidCommandError, match="open to"):
        node._follower.follow("g1", widest + 1e-6, True)


def test_the_enable_is_held_only_while_follows_say_so(node):
    live(node)
    assert node._follower.enable is True
    node._follower.follow("g1", 0.07, False)
    assert node._follower.enable is False
    node._follower.follow("g1", 0.06, True)
    assert node._follower.enable is True and node.gripper.calls[-1] == ("follow", 0.06)


def test_after_a_stop_enabled_follows_move_nothing(node):
    grasp = live(node)
    node._follower.stop(grasp)
    node.gripper.calls.clear()
    node._follower.follow("g1", 0.01, True)
    assert node.gripper.calls == [] and grasp.phase == "stopped"
    assert grasp.target_width_m == 0.07  # the robot_state's target: the last one taken, not an ignored one


# ---------------------------------------------------------------------------- the watchdog


def test_the_watchdog_waits_its_time_then_stops_the_fingers_and_ends_the_grasp(node):
    grasp = live(node)
    node.gripper.calls.clear()
    node.step(timeout_s=0)
    node.clock.t += WATCHDOG_S - 0.01
    node._advance()
    assert node._grasp is grasp and node.gripper.calls == []
    node.clock.t += 0.02
    node.step(timeout_s=0)
    assert node.gripper.calls == [("stop",)] and node._grasp is None
    assert node._follower.enable is False and node._follower.stopped is True
    said = notices(node, "watchdog")
    assert [(n["action"], n["grasp_id"]) for n in said] == [("follow", "g1")]
    assert said[0]["reason"] == "no follow command for 0.210 s (watchdog 0.2 s): the fingers stopped"
    assert [e["event"] for e in node.publisher.of("grasp_event")] == ["start", "end"]
    assert node.publisher.of("robot_state")[-1]["mode"] == "stopped"
    assert node.publisher.of("robot_state")[-1]["enable"] is False
    assert node.stats.watchdogs == 1


def test_the_watchdog_also_ends_a_grasp_stopped_by_a_stop(node):
    grasp = live(node)
    node._follower.stop(grasp)
    node.clock.t += WATCHDOG_S + 0.01
    node._advance()
    assert node._grasp is None and notices(node, "watchdog")


def test_the_watchdog_ends_a_grasp_still_preparing_and_its_id_is_spent(node):
    node.simulated = True
    node._follower.next_live = (0, Future())  # the object never ready
    node._follower.follow("p1", 0.03, True)
    assert node._grasp.phase == "preparing" and node.gripper.moves() == []  # nothing to close on yet
    node.clock.t += WATCHDOG_S + 0.01
    node._advance()
    assert node._grasp is None and node._follower.stopped
    assert not node.publisher.of("grasp_event")  # it never went live: no start, no end
    with pytest.raises(DeviceError, match="has ended"):
        node._follower.follow("p1", 0.03, True)


def test_a_node_stalled_ends_only_a_follow_grasp_that_the_watchdog_watches(node):
    node.simulated = True
    commanded = node._grasp = _Grasp("c1", "ball", prepared=Future())  # a scripted grasp being simulated
    node._follower.stalled(1.0)
    assert node._grasp is commanded and not notices(node)
    releasing = node._grasp = _Grasp("r1", None, follow=True, phase="releasing", started_s=node.clock())
    node._follower.stalled(1.0)
    assert node._grasp is releasing and not notices(node)
    node._grasp = _Grasp("f1", None, follow=True, phase="following", started_s=node.clock())
    node._follower.stalled(0.25)
    assert node._grasp is None
    assert notices(node, "watchdog")[0]["reason"].startswith("the robot node itself stalled for 0.250 s")


class Released:
    """A live object the simulated fingers no longer press."""

    object = SimpleNamespace(name="ball")

    def force_at(self, t_s: float) -> float:
        return 0.0


def test_an_object_the_fingers_let_go_leaves_and_the_next_grasp_prepares_the_next_one(node):
    node.simulated = True
    node._follower.live = Released()
    node._follower.next_live = (0, Future())
    node._follower.follow("n1", 0.07, True)
    assert node._follower.live is None and node._grasp.phase == "preparing" and node._grasp.object_name is None


def test_going_live_drives_the_fingers_to_the_target_set_while_preparing(node, monkeypatch):
    monkeypatch.setattr("teleop.devices.live_sim.LiveGrasp", lambda obj, **_: SimpleNamespace(object=obj))
    node.simulated = True
    ready: Future = Future()
    node._follower.next_live = (0, ready)
    node._follower.follow("p1", 0.03, True)
    ready.set_result((SimpleNamespace(name="ball"), None))
    node._advance()
    assert node._grasp.phase == "following" and node._grasp.object_name == "ball"
    assert node.gripper.calls == [("follow", 0.03)]
    assert [(e["event"], e["object_name"]) for e in node.publisher.of("grasp_event")] == [("start", "ball")]


# ---------------------------------------------------------------------------- release, ended ids


def test_a_release_stops_the_fingers_then_opens_them_fully(node):
    grasp = live(node)
    node.gripper.calls.clear()
    node._follower.release(grasp)
    assert node.gripper.calls == [("stop",), ("move", node.settings.gripper.max_width_m)]
    assert grasp.phase == "releasing"
    with pytest.raises(DeviceError, match="nothing to release"):
        node._follower.release(grasp)


def test_a_grasp_started_after_the_watchdog_leaves_the_watchdogs_stop(node):
    live(node, "w1")
    node.clock.t += WATCHDOG_S + 0.01
    node._advance()
    assert node._mode() == "stopped"
    live(node, "w2")
    node._gripper_failed(DeviceError("link down"))  # ends w2 without a release or the watchdog
    assert node._grasp is None and node._mode() == "idle"


def test_exactly_the_last_ended_kept_grasps_are_remembered(node):
    kept = follow_module.ENDED_KEPT
    for i in range(kept + 3):
        node._follower.record_ended(f"e{i}")
    assert list(node._follower.ended) == [f"e{i}" for i in range(3, kept + 3)]


# ---------------------------------------------------------------------------- the node's commands


def command(node, action: str, grasp_id: str | None = None, **params) -> None:
    node.handle_command(make_message("command", t_capture_s=node.clock(), action=action, grasp_id=grasp_id,
                                     params=params))


def refusals(node) -> list[tuple[str, str | None, str]]:
    return [(n["action"], n["grasp_id"], n["reason"]) for n in notices(node, "refused")]


@pytest.mark.parametrize("force_n", [-1.0, 0.0, "above"])
def test_a_start_grasp_outside_zero_to_the_maximum_force_is_refused_and_closes_nothing(node, force_n):
    force_n = maximum(node) + 0.5 if force_n == "above" else force_n
    command(node, "start_grasp", "h1", target_force_n=force_n)
    assert node._grasp is None and node.gripper.calls == []
    [(action, grasp_id, reason)] = refusals(node)
    assert (action, grasp_id) == ("start_grasp", "h1") and f"({0}, {maximum(node)}] N" in reason
    assert node.stats.bad_commands == 1


def test_a_start_grasp_at_exactly_the_maximum_force_grasps_with_that_force(node):
    command(node, "start_grasp", "h1", target_force_n=maximum(node))
    assert node._grasp.grasp_id == "h1" and node.gripper.calls == [("grasp", maximum(node))]
    assert not refusals(node)


def test_a_start_grasp_during_a_grasp_or_with_an_unknown_param_is_refused(node):
    live(node)
    command(node, "start_grasp", "h2")
    command(node, "start_grasp", None, hold_s=1.0)
    assert node._grasp.grasp_id == "g1" and ("grasp", None) not in node.gripper.calls
    said = refusals(node)
    assert [(a, g) for a, g, _ in said] == [("start_grasp", "h2"), ("start_grasp", "g1")]  # none named: the grasp's
    assert "'g1' is still in progress" in said[0][2] and "params hold_s" in said[1][2]


@pytest.mark.parametrize(("index", "why"), [(1.5, "whole number"), (99.0, "the scene has objects")])
def test_a_simulated_start_grasp_with_a_bad_object_index_is_refused(node, index, why):
    node.simulated = True
    command(node, "start_grasp", "s1", object_index=index)
    assert node._grasp is None and node._count == 0
    assert [(a, g) for a, g, _ in refusals(node)] == [("start_grasp", "s1")] and why in refusals(node)[0][2]


def test_anyones_stop_stops_the_fingers_with_or_without_a_grasp(node):
    command(node, "stop")
    assert node.gripper.calls == [("stop",)] and not refusals(node)
    grasp = live(node)
    command(node, "stop", "someone-else")
    assert grasp.phase == "stopped" and node.gripper.calls[-1] == ("stop",)


def test_a_release_naming_another_grasp_is_refused_and_moves_nothing(node):
    grasp = live(node)
    node.gripper.calls.clear()
    command(node, "release", "other")
    assert node.gripper.calls == [] and grasp.phase == "following"
    assert refusals(node) == [("release", "other", "grasp 'g1' is in progress, not 'other'")]
    command(node, "release")
    assert grasp.phase == "releasing" and node.gripper.calls[-1] == ("move", node.settings.gripper.max_width_m)


def test_a_release_after_the_watchdog_opens_the_fingers_and_leaves_its_stop(node):
    live(node)
    node.clock.t += WATCHDOG_S + 0.01
    node._advance()
    node.gripper.calls.clear()
    command(node, "release")
    assert node.gripper.calls == [("move", node.settings.gripper.max_width_m)] and node._mode() == "idle"


def test_a_simulated_release_with_nothing_between_the_fingers_moves_nothing(node):
    node.simulated = True
    command(node, "release")
    assert node.gripper.calls == [] and not refusals(node)
    node._follower.live = object()  # an object the watchdog left between the closed fingers
    command(node, "release")
    assert node.gripper.calls == [("move", node.settings.gripper.max_width_m)]


def test_a_simulated_replay_refuses_stop_and_release_and_keeps_its_fingers(node):
    node.simulated = True
    node._grasp = _Grasp("r1", "ball", phase="tail", started_s=node.clock())
    command(node, "stop")
    command(node, "release", "r1")
    assert node.gripper.calls == [] and [(a, g) for a, g, _ in refusals(node)] == [("stop", "r1"), ("release", "r1")]


def test_a_follow_beyond_the_gripper_is_refused_on_the_bus_not_raised(node):
    follow(node, "w1", 1.0)
    assert node._grasp is None and node.gripper.calls == []
    assert [(a, g) for a, g, _ in refusals(node)] == [("follow", "w1")] and node.stats.bad_commands == 1


def follow(node, grasp_id: str | None, width_m: float, *, enable: bool = True) -> None:
    node.handle_command(make_message("follow", t_capture_s=node.clock(), grasp_id=grasp_id,
                                     target_width_m=width_m, enable=enable))


def test_the_robot_state_says_the_mode_target_and_enable(node):
    reads(node, force_n=1.0, width_m=0.07)
    follow(node, "g1", 0.06)
    node._send_state()
    assert node.publisher.of("robot_state")[-1] == {"t_capture_s": node.clock(), "mode": "following",
                                                    "grasp_id": "g1", "target_width_m": 0.06, "enable": True}
    command(node, "stop")
    node._send_state()
    assert node.publisher.of("robot_state")[-1]["mode"] == "stopped"


class Queued:
    """Commands waiting for the node (its subscriber)."""

    def __init__(self, *messages):
        self.messages = list(messages)

    def recv(self, timeout_s: float | None = None):
        return self.messages.pop(0) if self.messages else None


def test_a_node_that_did_not_look_for_commands_over_the_watchdogs_time_ends_the_grasp_first(node):
    live(node)
    node._looked_s = node._follower.last_follow_s = node.clock()
    node.clock.t += WATCHDOG_S + 0.01  # stalled; the operator's follow queued meanwhile
    node.commands = Queued(make_message("follow", t_capture_s=node.clock(), grasp_id="g1", target_width_m=0.01,
                                        enable=True))
    node.gripper.calls.clear()
    node.step(timeout_s=0)
    assert node._grasp is None and node.gripper.calls == [("stop",)]  # not driven to the queued 10 mm
    assert notices(node, "watchdog")[0]["reason"].startswith("the robot node itself stalled for 0.210 s")
    assert "has ended" in refusals(node)[0][2]


def test_a_node_that_looked_within_the_watchdogs_time_takes_the_follow(node):
    live(node)
    node._looked_s = node._follower.last_follow_s = node.clock()
    node.clock.t += WATCHDOG_S - 0.01
    node.commands = Queued(make_message("follow", t_capture_s=node.clock(), grasp_id="g1", target_width_m=0.06,
                                        enable=True))
    reads(node, force_n=1.0)
    node.step(timeout_s=0)
    assert node._grasp is not None and node.gripper.calls[-1] == ("follow", 0.06) and not notices(node, "watchdog")


def _watchdog_with_the_link_down(node) -> None:
    """A live follow grasp left WATCHDOG_S + 10 ms without follows, the gripper's stop failing."""
    live(node)

    def link_down() -> bool:
        raise DeviceError("the gripper's link is down")

    node.gripper.stop = link_down
    node.clock.t += WATCHDOG_S + 0.01
    node.step(timeout_s=0)


def test_a_gripper_failing_to_stop_for_the_watchdog_is_said_and_the_node_carries_on(node):
    _watchdog_with_the_link_down(node)
    assert [n["action"] for n in notices(node, "device")] == ["gripper"]
    node._looked_s = node.clock() - 2 * WATCHDOG_S  # and when the node itself stalled
    live(node, "g2")
    node.commands = Queued()
    node.step(timeout_s=0)
    assert len(notices(node, "device")) == 2


def test_a_watchdog_whose_stop_fails_still_says_so_lets_the_enable_go_and_ends_the_grasp(node):
    _watchdog_with_the_link_down(node)
    said = notices(node, "watchdog")
    assert [n["reason"] for n in said] == ["no follow command for 0.210 s (watchdog 0.2 s): stopping the fingers "
                                           "failed (the gripper's link is down)"]
    assert node.stats.watchdogs == 1 and node._grasp is None
    assert node._follower.enable is False and node.publisher.of("robot_state")[-1]["enable"] is False
    assert [e["event"] for e in node.publisher.of("grasp_event")] == ["start", "end"]


class Flood(Queued):
    """Commands queued for the node, each taking the node a millisecond (its clock moves on)."""

    def __init__(self, clock: Clock, *messages):
        super().__init__(*messages)
        self.clock = clock

    def recv(self, timeout_s: float | None = None):
        if self.messages:
            self.clock.t += 0.001
        return super().recv(timeout_s)


def test_a_flood_of_refused_follows_does_not_hold_off_the_watchdog(node):
    live(node)
    node._looked_s = last = node._follower.last_follow_s = node.clock()
    node.commands = Flood(node.clock, *(make_message("follow", t_capture_s=0.0, grasp_id="other",
                                                     target_width_m=0.05, enable=True) for _ in range(1000)))
    while node._grasp is not None:
        node.step(timeout_s=0)
    # A second of the node's time queued: the watchdog went off at its time, not once all was taken.
    assert notices(node, "watchdog")[0]["t_capture_s"] - last < WATCHDOG_S + 0.1
