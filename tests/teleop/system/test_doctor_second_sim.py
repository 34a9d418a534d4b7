"""``teleop doctor`` feeds the simulated grasp to every simulated backend, not only those named ``sim``."""

from __future__ import annotations

import dataclasses

from support import second_sim

from teleop.settings import default_settings_path, load_settings
from teleop.system import doctor


def test_a_second_simulated_gripper_among_hardware_is_fed_the_simulated_grasp(monkeypatch):
    backend = second_sim.register(monkeypatch)
    shipped = load_settings(default_settings_path())
    hardware = dataclasses.replace(
        shipped, load_cell=dataclasses.replace(shipped.load_cell, backend="serial", port="/dev/null"),
        sensors=tuple(dataclasses.replace(s, camera_backend="opencv", camera_source="0") for s in shipped.sensors))
    playback = object()  # what the probes are handed; none is read before the probes run
    monkeypatch.setattr(doctor, "_simulated_playback", lambda settings: playback)
    probes = {p.name: p for p in doctor._probes(second_sim.with_gripper(hardware))}
    gripper = probes["gripper"]
    assert type(gripper.device) is backend and gripper.where == "the simulated gripper"
    assert gripper.device._playback is playback
