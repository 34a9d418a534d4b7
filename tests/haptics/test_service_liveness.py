"""The renderer service lets go of what it renders when the estimator, which alone forwards grasp ends,
dies: a grasp that had its final ends; one still loading is released, and engages again if the
estimator is heard again."""

from __future__ import annotations

import time
from collections.abc import Iterator
from contextlib import contextmanager

from haptics.devices.sim import SimulatedDisplay
from haptics.renderer import HapticRenderer
from haptics.service import RendererService
from haptics.settings import display_settings
from teleop.bus.pubsub import Publisher, Subscriber
from teleop.settings import load_settings

HEARTBEAT_S = 0.05


def _final(publisher: Publisher, grasp_id: str, *, provisional: bool = False) -> None:
    publisher.send("estimate", t_capture_s=time.monotonic(), grasp_id=grasp_id, method="series", E_pa=1e12,
                   interval_pa=[1e11, None], state="lower_bound", reason="test", provisional=provisional,
                   latency_s=0.001)


@contextmanager
def _rig(heartbeat_s: float = HEARTBEAT_S) -> Iterator[tuple[Publisher, RendererService]]:
    """An estimator's publisher (heartbeat period ``heartbeat_s``, announced only by its heartbeats) and a
    renderer service subscribed to it."""
    estimator = Publisher("tcp://127.0.0.1:*", lossless=False, source="estimator", heartbeat_s=heartbeat_s)
    subscriber = Subscriber(estimator.endpoint, ("estimate", "grasp_event"), conflate=True)
    renderer = HapticRenderer(SimulatedDisplay(), display_settings(load_settings()))
    try:
        estimator.wait_for_subscriber("estimate", timeout_s=5.0)
        yield estimator, RendererService(renderer, subscriber=subscriber, tick_s=0.005)
    finally:
        for sock in (estimator, subscriber):
            sock.close()


def _step_until(service: RendererService, done, timeout_s: float = 5.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not done():
        assert time.monotonic() < deadline, "timed out"
        service.step()


def test_a_final_is_let_go_when_the_estimator_dies_before_forwarding_the_grasps_end():
    with _rig() as (estimator, service):
        renderer = service.renderer
        estimator.heartbeat_if_due()
        _final(estimator, "g1")  # rigid: the display holds its stiff end
        _step_until(service, lambda: renderer.grasp_id == "g1")
        # Alive and heartbeating: the final stays rendered (it never goes stale).
        end = time.monotonic() + 4 * HEARTBEAT_S
        while time.monotonic() < end:
            estimator.heartbeat_if_due()
            service.step()
        assert renderer.phase == "active" and renderer.percept.rigid
        # The estimator dies (its end of g1 never comes): the display lets go of g1.
        _step_until(service, lambda: renderer.phase in ("fading", "idle"))
        _step_until(service, lambda: renderer.phase == "idle")
        assert not renderer.percept.rigid and renderer.percept.stiffness == 0


def test_an_estimator_that_never_announced_a_heartbeat_period_is_not_judged():
    with _rig(heartbeat_s=0.5) as (estimator, service):  # never sends a heartbeat
        renderer = service.renderer
        _final(estimator, "g2")
        _step_until(service, lambda: renderer.grasp_id == "g2")
        end = time.monotonic() + 0.3
        while time.monotonic() < end:
            service.step()
        assert renderer.phase == "active"


def test_a_loading_grasp_is_released_when_its_estimator_dies_and_engages_again_when_it_is_back():
    with _rig() as (estimator, service):
        renderer = service.renderer
        estimator.heartbeat_if_due()
        _final(estimator, "g3", provisional=True)  # rigid, still loading
        _step_until(service, lambda: renderer.grasp_id == "g3")
        assert renderer.percept.rigid and not renderer.has_final
        # The estimator dies mid-grasp: the stiff end is not held over the operator's next grasp.
        _step_until(service, lambda: renderer.phase == "idle")
        assert renderer.percept.stiffness == 0 and renderer.display.last_command.level == 0
        # It was only starved: heard again, its next estimate of g3 is rendered (g3 did not end).
        estimator.heartbeat_if_due()
        _final(estimator, "g3", provisional=True)
        _step_until(service, lambda: renderer.grasp_id == "g3")
        assert renderer.percept.rigid


def test_a_final_let_go_when_its_estimator_dies_is_ended_so_a_late_estimate_of_it_cannot_engage():
    with _rig() as (estimator, service):
        renderer = service.renderer
        estimator.heartbeat_if_due()
        _final(estimator, "g1")
        _step_until(service, lambda: renderer.grasp_id == "g1")
        _step_until(service, lambda: renderer.phase == "idle")  # the estimator dies: let go
        # Heard again, it sends one more estimate of g1 (a duplicate held up on the bus): g1 has ended.
        estimator.heartbeat_if_due()
        _final(estimator, "g1", provisional=True)
        _step_until(service, lambda: service.stats.estimates == 2)
        assert renderer.phase == "idle" and renderer.stats.estimates_ignored == 1
        assert renderer.display.last_command.level == 0
