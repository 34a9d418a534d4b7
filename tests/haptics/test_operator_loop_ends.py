"""The operator's loop when the robot ends its follow grasp, and what it says of the enable
(against a fake link and device; the rest of the loop: test_operator_link.py)."""

from __future__ import annotations

from dataclasses import dataclass

from haptics.operator_link import OperatorView
from haptics.operator_loop import OperatorLoop
from teleop.bus.messages import RobotNoticeBody
from teleop.settings import load_settings


@dataclass(frozen=True)
class Reading:
    t_s: float
    grip: float = 0.0
    enable: bool = False
    force_n: float | None = None
    buttons: frozenset[str] = frozenset()


class Clock:
    def __init__(self):
        self.t = 100.0

    def __call__(self) -> float:
        return self.t


class Device:
    """A toggle enable, as the keyboard's."""

    waits_for_robot = False

    def __init__(self, clock):
        self.clock, self.grip, self.enable, self.buttons = clock, 0.5, False, set()

    def connect(self):
        return self

    def read(self, *, timeout_s: float) -> Reading:
        pressed, self.buttons = frozenset(self.buttons), set()
        return Reading(self.clock(), self.grip, self.enable, None, pressed)

    def feel(self, **_) -> None:
        pass


class Link:
    def __init__(self, clock):
        self.clock, self.view, self.sent = clock, OperatorView(t_s=0.0), []

    def poll(self, timeout_s: float = 0.0) -> int:
        return 0

    def follow(self, target_width_m, *, enable, grasp_id=None):
        self.sent.append(("follow", enable, grasp_id))

    def start_grasp(self, *, target_force_n, grasp_id=None):
        self.sent.append(("start_grasp", True, grasp_id))

    def stop(self, grasp_id=None):
        self.sent.append(("stop", False, grasp_id))

    def release(self, grasp_id=None):
        self.sent.append(("release", False, grasp_id))

    def clear(self):
        self.view = OperatorView(t_s=self.clock())


def _run(clock: Clock, loop: OperatorLoop, seconds: float) -> None:
    end = clock.t + seconds
    while clock.t < end - 1e-9:
        loop.step()
        clock.t += 0.001


def _rig():
    clock = Clock()
    link, device = Link(clock), Device(clock)
    return clock, link, device, OperatorLoop(link, device, load_settings(), clock=clock)


def test_the_watchdogs_notice_ends_the_follow_grasp_it_names():
    # The watchdog ended the grasp before its start was announced (the node was preparing the
    # object): no grasp_event end comes, only the notice. The console must not go on driving it.
    clock, link, device, loop = _rig()
    device.enable = True
    _run(clock, loop, 0.1)
    grasp_id = link.sent[-1][2]
    watchdog = RobotNoticeBody(event="watchdog", action="follow", grasp_id=grasp_id,
                               reason="no follow command for 0.210 s (watchdog 0.2 s): the fingers stopped")
    link.view = OperatorView(t_s=clock(), notice=watchdog, notice_t_s=clock(), ended_by=watchdog,
                             ended_by_t_s=clock())
    _run(clock, loop, 0.05)
    sent = len(link.sent)
    _run(clock, loop, 0.5)
    assert link.sent[sent:] == [] and loop.status.grasp_id is None
    assert loop.status.suspended and loop.status.held and not loop.status.enable
    device.enable = False  # let go (the console turns a keyboard's toggle off) and hold again: a new grasp
    _run(clock, loop, 0.05)
    assert not loop.status.suspended and not loop.status.held
    device.enable = True
    _run(clock, loop, 0.05)
    assert link.sent[-1][:2] == ("follow", True) and link.sent[-1][2] not in (grasp_id, None)
