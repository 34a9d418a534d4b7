"""A flood of commands does not hold off the robot node's watchdog: a step takes a bounded share
of them before the grasp advances (the node's clock and command queue are the test's)."""

from __future__ import annotations

from collections import deque

import pytest
from support.node_rig import drain, running_node, wait_prepared

from teleop.bus.wire import make_message
from teleop.node import COMMANDS_PER_STEP
from teleop.operator import WATCHDOG_S

TICK_S = 0.001  # the node's clock moves on this much per command taken: a slow node, without waiting


@pytest.fixture
def rig():
    with running_node() as (node, _, listener, _scene):
        yield node, listener


class Queue:
    """Commands already queued for the node; taking one moves the node's clock on by TICK_S."""

    def __init__(self, now: list[float]):
        self.now = now
        self.messages: deque = deque()

    def recv(self, timeout_s: float | None = None):
        if not self.messages:
            return None
        self.now[0] += TICK_S
        return self.messages.popleft()


def follow(grasp_id: str, width_m: float) -> object:
    return make_message("follow", t_capture_s=0.0, grasp_id=grasp_id, target_width_m=width_m, enable=True)


def live_with_queue(node, grasp_id: str) -> Queue:
    """Follow grasp ``grasp_id`` live, its last follow just taken, the node on the test's clock and queue."""
    wait_prepared(node)
    node.handle_command(follow(grasp_id, 0.07))
    while node._grasp.phase == "preparing":
        node.handle_command(follow(grasp_id, 0.07))
        node.step(timeout_s=0.002)
    now = [node.clock()]
    node.clock = lambda: now[0]
    node._follower.last_follow_s = node._looked_s = now[0]
    node.commands = Queue(now)
    return node.commands


def test_follows_of_another_grasp_flooding_the_queue_do_not_hold_off_the_watchdog(rig):
    node, listener = rig
    queue = live_with_queue(node, "A1")
    last_s = queue.now[0]
    flood = 1000  # a second's worth of the node's time, each refused
    queue.messages.extend(follow("B1", 0.05) for _ in range(flood))
    while node.stats.watchdogs == 0:
        node.step(timeout_s=0)
    # The watchdog went off at its time, give or take one step's share of commands, not once the
    # flood was taken.
    due = WATCHDOG_S / TICK_S
    assert due <= flood - len(queue.messages) <= due + COMMANDS_PER_STEP + 1
    assert not node.busy
    said = [m.body for m in drain(listener) if m.type == "robot_notice" and m.body["event"] == "watchdog"]
    assert [n["grasp_id"] for n in said] == ["A1"]
    assert node.clock() - last_s <= WATCHDOG_S + (COMMANDS_PER_STEP + 1) * TICK_S


def test_a_step_takes_at_most_its_share_of_commands_then_the_next_step_the_next_share(rig):
    node, _ = rig
    queue = live_with_queue(node, "A2")
    queue.messages.extend(follow("A2", 0.07) for _ in range(3 * COMMANDS_PER_STEP))
    node.step(timeout_s=0)
    assert len(queue.messages) == 2 * COMMANDS_PER_STEP
    node.step(timeout_s=0)
    assert len(queue.messages) == COMMANDS_PER_STEP and node.busy
