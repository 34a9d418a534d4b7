"""A simulated backend other than ``sim`` (its class says it is simulated) runs the robot node as
simulated: it needs a scene, grasps the scene's objects and publishes their frames."""

from __future__ import annotations

import time

import pytest
from support import second_sim

from teleop.bus.pubsub import Publisher, Subscriber
from teleop.errors import SimulationError
from teleop.node import RobotNode
from teleop.scene import load_scene

TOPICS = ("frame", "grasp_event")


def test_a_second_simulated_gripper_needs_a_scene(monkeypatch):
    second_sim.register(monkeypatch)
    settings = second_sim.with_gripper(load_scene("quick").settings)
    robot = Publisher("tcp://127.0.0.1:*", lossless=True, source="robot")
    with robot, pytest.raises(SimulationError, match="needs a scene"):
        RobotNode(settings, publisher=robot)


@pytest.mark.slow
def test_a_second_simulated_gripper_grasps_the_scene_and_publishes_frames(monkeypatch):
    backend = second_sim.register(monkeypatch)
    scene = load_scene("quick")
    robot = Publisher("tcp://127.0.0.1:*", lossless=True, source="robot")
    operator = Publisher("tcp://127.0.0.1:*", lossless=True, source="operator")
    commands = Subscriber(operator.endpoint, ("command",))
    listener = Subscriber(robot.endpoint, TOPICS)
    node = RobotNode(second_sim.with_gripper(scene.settings), publisher=robot, commands=commands, scene=scene)
    try:
        node.connect()
        assert node.simulated and type(node.gripper) is backend
        robot.wait_for_subscriber(*TOPICS, timeout_s=5.0)
        operator.wait_for_subscriber("command", timeout_s=5.0)
        operator.send("command", t_capture_s=time.monotonic(), action="start_grasp", grasp_id="g-slow",
                      params={"object_index": 1.0})
        deadline = time.monotonic() + 30.0
        while node.busy or node.stats.grasps < 1:
            assert time.monotonic() < deadline, "the grasp did not end in time"
            node.step()
        got = []
        while (message := listener.recv(timeout_s=0.2)) is not None:
            got.append(message)
    finally:
        node.close()
        for sock in (robot, operator, commands, listener):
            sock.close()
    events = [m.body for m in got if m.type == "grasp_event" and m.body.get("grasp_id") == "g-slow"]
    assert events[0]["event"] == "start" and events[0]["object_name"] == scene.objects[1].name
    for sensor in scene.settings.sensors:
        assert any(m.topic == f"frame/{sensor.finger}" for m in got), f"no frame from {sensor.finger}"
