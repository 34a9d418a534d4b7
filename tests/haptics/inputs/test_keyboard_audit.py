"""Audit of the keyboard backend (:mod:`haptics.inputs.keyboard`): the grip lands on whole steps, so
stepping back down opens the grip fully rather than leaving a float residue."""

from __future__ import annotations

from haptics.inputs.keyboard import KeyboardInput


def test_steps_up_and_as_many_down_land_on_whole_steps_and_open_fully():
    with KeyboardInput(grip_step=0.1) as device:
        for _ in range(3):
            device.press("up")
        assert device.read().grip == 0.3
        for _ in range(3):
            device.press("down")
        assert device.read().grip == 0.0
