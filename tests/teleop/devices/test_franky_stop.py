"""The franky backend's stop against commands waiting behind a follow step (teleop.devices.franky_gripper),
with a stand-in for franky.Gripper: franky-sim is not needed."""

from __future__ import annotations

import threading
import time

import teleop.devices.franky_gripper as franky_gripper
from teleop.devices.gripper import make_gripper
from teleop.settings import GripperSettings


class StandInHand:
    """franky.Gripper as the backend uses it: a move blocks while the fingers travel; stop aborts a
    running move and does nothing when none runs (libfranka's stop)."""

    max_width = 0.08
    is_grasped = False

    def __init__(self, host: str):
        self.width = 0.08
        self._abort = threading.Event()
        self._moving = False

    def move(self, width: float, speed: float) -> bool:
        self._abort.clear()
        self._moving = True
        try:
            while abs(self.width - width) > 1e-6:
                if self._abort.is_set():
                    return False
                step = min(abs(width - self.width), speed * 0.005)
                self.width += step if width > self.width else -step
                time.sleep(0.005)
            return True
        finally:
            self._moving = False

    def grasp(self, width, speed, force, epsilon_inner, epsilon_outer) -> bool:
        return self.move(width, speed)

    def stop(self) -> bool:
        if self._moving:
            self._abort.set()
        return True


def test_a_stop_while_a_follow_step_holds_the_hand_cancels_the_commands_given_before_it(monkeypatch):
    # A follow release (stop, then the opening move), then the operator's stop while the last step
    # still holds the hand: the stop reached no motion, and the opening move must not run after it.
    monkeypatch.setattr(franky_gripper.franky, "Gripper", StandInHand)
    monkeypatch.setattr(franky_gripper, "FOLLOW_STEP_S", 0.5)  # one long step: the stop lands within it
    with make_gripper(GripperSettings(backend="franky", host="stand-in", width_read_hz=20.0)) as gripper:
        gripper.follow(0.02, speed_m_s=0.05)
        while not gripper._stepping:
            time.sleep(0.001)
        gripper.stop()
        opening = gripper.move_async(0.08, speed_m_s=0.05)
        grasp = gripper.grasp_async(0.0, epsilon_outer_m=0.08)
        gripper.stop()
        assert opening.result(timeout=10.0) is False and grasp.result(timeout=10.0) is False
        assert gripper.last_stop is None  # the grasp never began: no stop to mark a loading end by
        held = gripper.read_width()[1]
        time.sleep(0.1)
        assert gripper.read_width()[1] == held < 0.08
