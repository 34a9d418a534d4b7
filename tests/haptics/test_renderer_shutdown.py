"""The renderer sets the display free when it stops (:meth:`haptics.service.RendererService.finish`): one
stopped mid-grasp must not leave the display holding a stiffness until its own watchdog (or for ever)."""

from __future__ import annotations

import logging
import threading
import time

import pytest

from haptics.devices.sim import SimulatedDisplay
from haptics.renderer import HapticRenderer
from haptics.service import RendererService
from haptics.settings import display_settings
from teleop.bus.pubsub import Publisher, Subscriber
from teleop.settings import load_settings


@pytest.fixture
def rig():
    display = SimulatedDisplay()
    estimator = Publisher("tcp://127.0.0.1:*", lossless=False, source="estimator")
    renderer_pub = Publisher("tcp://127.0.0.1:*", lossless=False, source="renderer")
    subscriber = Subscriber(estimator.endpoint, ("estimate", "grasp_event"), conflate=True)
    listener = Subscriber(renderer_pub.endpoint, ("display",))
    service = RendererService(HapticRenderer(display, display_settings(load_settings())), subscriber=subscriber,
                              publisher=renderer_pub, tick_s=0.005)
    estimator.wait_for_subscriber("estimate", "grasp_event", timeout_s=5.0)
    renderer_pub.wait_for_subscriber("display", timeout_s=5.0)
    yield service, estimator, display, listener
    for sock in (estimator, renderer_pub, subscriber, listener):
        sock.close()


def _displays(listener: Subscriber, timeout_s: float = 0.3) -> list:
    out, deadline = [], time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        message = listener.recv(timeout_s=0.02)
        if message is not None:
            out.append(message.fields)
    return out


def _render_2_mpa(service, estimator, display, *, provisional: bool) -> None:
    """Send an estimate of 2 MPa and step the service until the display renders it."""
    estimator.send("estimate", t_capture_s=time.monotonic(), grasp_id="g1", method="series", E_pa=2e6,
                   interval_pa=[1e6, 4e6], state="ok", reason="test", provisional=provisional, latency_s=0.001)
    deadline = time.monotonic() + 5.0
    while not (display.rendered_command is not None and display.rendered_command.level > 0):
        assert time.monotonic() < deadline, "the estimate was never rendered"
        service.step()


def _stopped() -> threading.Event:
    stop = threading.Event()
    stop.set()
    return stop


def test_a_renderer_stopped_mid_grasp_sets_the_display_free_and_says_so(rig):
    service, estimator, display, listener = rig
    _render_2_mpa(service, estimator, display, provisional=True)
    assert service.renderer.phase in ("active", "stale")
    _displays(listener)  # what was published while rendering

    service.run(_stopped())  # a stop signal: no step, then the loop's finish

    assert display.rendered_command.level == 0  # free, not holding the squeeze
    last = _displays(listener)[-1]
    assert last.phase == "idle" and last.grasp_id is None and last.level == 0 and last.stiffness == 0.0


def test_an_idle_renderer_writes_nothing_more_on_stopping(rig):
    service, _, display, listener = rig
    for _ in range(3):
        service.step()
    written = display.reports_written
    service.run(_stopped())
    assert display.reports_written == written
    assert all(m.phase == "idle" for m in _displays(listener))


def test_a_renderer_stopped_with_the_display_unplugged_says_it_may_hold_the_last_level(rig, caplog):
    service, estimator, display, _ = rig
    _render_2_mpa(service, estimator, display, provisional=False)
    held = display.rendered_command.level
    display.unplug()
    service.step()
    with caplog.at_level(logging.WARNING, logger="haptics.service"):
        service.run(_stopped())
    assert display.rendered_command.level == held  # nothing could reach it
    (said,) = [r.getMessage() for r in caplog.records if r.name == "haptics.service"]
    assert said.startswith(f"{display}: not connected on stopping, so not set free")
    assert f"the last level written, {held} of {display.info.level_max}" in said
