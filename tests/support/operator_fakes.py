"""Fakes of the operator's side for tests: an input device and a bus link for the operator's loop
on a fake clock (and the loop on them, :func:`loop_rig`), the bus sockets under a real link, a link
for the console on the real clock, and a wait for textual's pilot."""

from __future__ import annotations

import time
from dataclasses import dataclass

from haptics.errors import InputDeviceError, InputNotConnectedError
from haptics.operator_link import PEERS, OperatorView, Peer
from haptics.operator_loop import OperatorLoop
from teleop.bus.peers import Heartbeat
from teleop.bus.pubsub import SubscriberStats
from teleop.settings import load_settings

NOBODY = tuple(Peer(name, source, False, None) for name, source in PEERS)


@dataclass(frozen=True)
class Reading:
    """An operator input reading (the fields of haptics.inputs.OperatorInput)."""

    t_s: float
    grip: float = 0.0
    enable: bool = False
    force_n: float | None = None
    buttons: frozenset[str] = frozenset()


class FakeDevice:
    waits_for_robot = False

    def __init__(self, clock):
        self.clock = clock
        self.grip = 0.0
        self.enable = False
        self.buttons: set[str] = set()
        self.felt: list[tuple[float, float, float | None]] = []
        self.plugged, self.connected, self.connects = True, True, 0

    def connect(self):
        self.connects += 1
        if not self.plugged:
            raise InputDeviceError("no gamepad (unplugged)")
        self.connected = True
        return self

    def read(self, *, timeout_s: float) -> Reading:
        if not self.connected:
            raise InputNotConnectedError("read() needs a connected device")
        pressed, self.buttons = frozenset(self.buttons), set()
        return Reading(self.clock(), self.grip, self.enable, None, pressed)

    def feel(self, *, force_n: float, width_m: float, stiffness: float | None) -> None:
        self.felt.append((force_n, width_m, stiffness))


class FakeLink:
    """Records what the loop sends, with the fake clock's time."""

    def __init__(self, clock):
        self.clock = clock
        self.view = OperatorView(t_s=0.0)
        self.sent: list[tuple[float, str, dict]] = []
        self.cleared = 0

    def poll(self, timeout_s: float = 0.0) -> int:
        return 0

    def follow(self, target_width_m, *, enable, grasp_id=None):
        self.sent.append((self.clock(), "follow", {"target_width_m": target_width_m, "enable": enable,
                                                   "grasp_id": grasp_id}))

    def start_grasp(self, *, target_force_n, grasp_id=None):
        self.sent.append((self.clock(), "start_grasp", {"target_force_n": target_force_n, "grasp_id": grasp_id}))

    def stop(self, grasp_id=None):
        self.sent.append((self.clock(), "stop", {"grasp_id": grasp_id}))

    def release(self, grasp_id=None):
        self.sent.append((self.clock(), "release", {"grasp_id": grasp_id}))

    def clear(self):
        self.cleared += 1
        self.view = OperatorView(t_s=self.clock())

    def label(self, grasp_id, object_name, *, modulus_pa=None, source, detail=""):
        self.sent.append((self.clock(), "label", {"grasp_id": grasp_id, "object_name": object_name,
                                                  "modulus_pa": modulus_pa, "source": source, "detail": detail}))

    def kinds(self) -> list[str]:
        return [kind for _, kind, _ in self.sent]


class Clock:
    def __init__(self):
        self.t = 100.0

    def __call__(self) -> float:
        return self.t


def loop_rig(*, grip: float = 0.0) -> tuple[Clock, FakeLink, FakeDevice, OperatorLoop]:
    """An operator loop on a fake link and device (grip at ``grip``), stepped once: the enable read let
    go, so the loop starts armed off."""
    clock = Clock()
    link, device = FakeLink(clock), FakeDevice(clock)
    device.grip = grip
    loop = OperatorLoop(link, device, load_settings(), clock=clock)
    loop.step()
    return clock, link, device, loop


def press(loop: OperatorLoop, clock: Clock, button: str) -> str | None:
    """Press ``button`` and step the loop (then a millisecond passes): the grasp the loop names now."""
    loop.press(button)
    loop.step()
    clock.t += 0.001
    return loop.status.grasp_id


class QueuedSubscriber:
    """A bus subscriber handing out ``queue``'s messages: each refreshes its source's liveness."""

    def __init__(self, clock: Clock):
        self.heartbeat = Heartbeat(clock=clock)
        self.stats = SubscriberStats()
        self.queue: list = []

    def recv(self, timeout_s: float | None = None):
        if not self.queue:
            return None
        message = self.queue.pop(0)
        self.heartbeat.saw(message.source, interval_s=0.5)
        return message

    def close(self) -> None:
        pass


class SubscribedPublisher:
    """A bus publisher whose every topic has its subscriber (the robot node's, open)."""

    def heartbeat_if_due(self, now_s: float | None = None) -> bool:
        return False

    def subscriptions(self, prefix: str) -> int:
        return 1

    def close(self) -> None:
        pass


class ConsoleLink:
    """Records what the console's loop sends, on the real clock (textual's pilot runs in real time)."""

    def __init__(self, peers: tuple[Peer, ...] = NOBODY):
        self.view = OperatorView(t_s=time.monotonic(), peers=peers)
        self.sent: list[tuple[str, dict]] = []
        self.follows_sent = self.commands_sent = 0

    def poll(self, timeout_s: float = 0.0) -> int:
        time.sleep(timeout_s)
        return 0

    def follow(self, target_width_m, *, enable, grasp_id=None):
        self.follows_sent += 1
        self.sent.append(("follow", {"target_width_m": target_width_m, "enable": enable, "grasp_id": grasp_id}))

    def _command(self, action, **body):
        self.commands_sent += 1
        self.sent.append((action, body))

    def start_grasp(self, *, target_force_n, grasp_id=None):
        self._command("start_grasp", target_force_n=target_force_n, grasp_id=grasp_id)

    def stop(self, grasp_id=None):
        self._command("stop", grasp_id=grasp_id)

    def release(self, grasp_id=None):
        self._command("release", grasp_id=grasp_id)

    def clear(self):
        self._command("clear")
        self.view = OperatorView(t_s=time.monotonic())

    def kinds(self) -> list[str]:
        return [kind for kind, _ in self.sent]


async def until(predicate, pilot, timeout_s: float = 5.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not predicate():
        assert time.monotonic() < deadline, "timed out"
        await pilot.pause(0.05)
