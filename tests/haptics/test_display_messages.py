"""The renderer publishes what it renders: one ``display`` message per report written to the display."""

from __future__ import annotations

import dataclasses
import logging
import time

import pytest

from haptics.devices.sim import SimulatedDisplay
from haptics.mapping import stiffness_fraction
from haptics.protocol import DEVICE_STATES, FAULT_BITS
from haptics.renderer import HapticRenderer
from haptics.service import RendererService
from haptics.settings import display_settings
from teleop.bus.pubsub import Publisher, Subscriber
from teleop.bus.wire import SCHEMAS
from teleop.errors import BusTimeoutError
from teleop.settings import load_settings


@dataclasses.dataclass
class Rig:
    service: RendererService
    estimator: Publisher
    listener: Subscriber
    settings: object
    #: renderer.percept at the moment each ``display`` message was sent, in order.
    percepts: list = dataclasses.field(default_factory=list)

    def received(self, timeout_s: float = 0.2) -> list:
        """Every ``display`` message that arrived, in order (the listener does not conflate)."""
        out = []
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            message = self.listener.recv(timeout_s=0.02)
            if message is not None:
                out.append(message)
        return out


def make_rig(**display_overrides) -> Rig:
    settings = dataclasses.replace(display_settings(load_settings()), **display_overrides)
    estimator = Publisher("tcp://127.0.0.1:*", lossless=False, source="estimator")
    renderer_pub = Publisher("tcp://127.0.0.1:*", lossless=False, source="renderer")
    subscriber = Subscriber(estimator.endpoint, ("estimate", "grasp_event"), conflate=True)
    listener = Subscriber(renderer_pub.endpoint, ("display",))
    service = RendererService(HapticRenderer(SimulatedDisplay(), settings), subscriber=subscriber,
                              publisher=renderer_pub, tick_s=0.005)
    estimator.wait_for_subscriber("estimate", "grasp_event", timeout_s=5.0)
    renderer_pub.wait_for_subscriber("display", timeout_s=5.0)
    rig = Rig(service, estimator, listener, settings)
    send = renderer_pub.send

    def spy(kind, **kwargs):
        if kind == "display":
            rig.percepts.append(service.renderer.percept)
        return send(kind, **kwargs)

    renderer_pub.send = spy
    return rig


@pytest.fixture
def rigs():
    made = []

    def factory(**overrides) -> Rig:
        made.append(make_rig(**overrides))
        return made[-1]

    yield factory
    for rig in made:
        for sock in (rig.estimator, rig.service.publisher, rig.service.subscriber, rig.listener):
            sock.close()


def estimate(publisher: Publisher, *, grasp_id: str, e_pa: float | None, provisional: bool, state: str = "ok",
             interval=None) -> None:
    interval = interval if interval is not None else ([e_pa / 2, e_pa * 2] if e_pa else [None, None])
    publisher.send("estimate", t_capture_s=time.monotonic(), grasp_id=grasp_id, method="series", E_pa=e_pa,
                   interval_pa=interval, state=state, reason="test", provisional=provisional, latency_s=0.001)


def run_for(service: RendererService, seconds: float) -> None:
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        service.step()


def step_until(service: RendererService, done, timeout_s: float = 5.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not done():
        assert time.monotonic() < deadline, "timed out"
        service.step()


@pytest.mark.slow
def test_every_report_written_is_published_with_the_rendered_percept(rigs):
    rig = rigs()  # the shipped smoothing: the percept moves between reports
    service, settings = rig.service, rig.settings
    before = time.monotonic()
    estimate(rig.estimator, grasp_id="g1", e_pa=1e5, provisional=True)
    step_until(service, lambda: service.stats.estimates == 1)
    run_for(service, 0.3)
    estimate(rig.estimator, grasp_id="g1", e_pa=2e6, provisional=False)
    step_until(service, lambda: service.stats.estimates == 2)
    run_for(service, 0.5)  # smoothing settles; then keep-alive reports every keepalive_s
    messages = rig.received()
    assert service.stats.display_failures == 0
    # One message per report, nothing in between, none lost on loopback.
    assert service.stats.display_messages == service.renderer.stats.reports_sent == len(messages) == len(rig.percepts)
    assert [m.seq for m in messages] == list(range(len(messages)))
    assert len(messages) >= 5
    soft, rigid = settings.e_soft_pa, settings.e_rigid_pa
    last_t = before
    for message, percept in zip(messages, rig.percepts, strict=True):
        body = message.body
        assert message.type == message.topic == "display" and message.source == "renderer"
        assert set(body) == set(SCHEMAS["display"].fields)
        assert body["stiffness"] == percept.stiffness
        assert body["uncertainty_decades"] == percept.uncertainty_decades
        assert (body["rigid"], body["unknown"], body["provisional"]) == (percept.rigid, percept.unknown,
                                                                          percept.provisional)
        assert body["level_max"] == service.renderer.display.info.level_max
        assert body["level"] == round(body["stiffness"] * body["level_max"])
        assert last_t <= message.t_capture_s <= time.monotonic()  # the service clock at the write
        last_t = message.t_capture_s
        if body["phase"] == "idle":  # the display's first report, before the estimate came
            assert body["grasp_id"] is None and body["stiffness"] == 0.0 and body["E_pa"] is None
            continue
        assert body["grasp_id"] == "g1" and body["phase"] in ("active", "stale")
        if body["stiffness"] == 0.0:  # the estimate's first report: smoothing starts from free
            assert body["E_pa"] is None
            continue
        # E_pa is the modulus that stiffness stands for on the display's range.
        assert soft < body["E_pa"] <= rigid
        assert stiffness_fraction(body["E_pa"], e_soft_pa=soft, e_rigid_pa=rigid) == pytest.approx(body["stiffness"])
    rendering = [m.body for m in messages if m.body["phase"] != "idle"]
    assert len(rendering) >= 4 and rendering[0]["provisional"]
    assert not messages[-1].body["provisional"]
    # Settled on the final estimate: the last report's modulus is (nearly) the estimate's.
    assert messages[-1].body["E_pa"] == pytest.approx(2e6, rel=0.05)
    assert messages[-1].body["level"] == service.renderer.display.rendered_command.level


def test_rigid_lower_bound_is_published_rigid_at_the_stiff_end(rigs):
    rig = rigs(smoothing_s=0.0)
    service, settings = rig.service, rig.settings
    estimate(rig.estimator, grasp_id="g2", e_pa=settings.e_rigid_pa, provisional=False, state="lower_bound",
             interval=[settings.e_rigid_pa, None])
    step_until(service, lambda: service.stats.finals)
    body = rig.received()[-1].body
    assert body["rigid"] is True and body["unknown"] is False
    assert body["stiffness"] == 1.0
    assert body["E_pa"] == settings.e_rigid_pa
    assert body["level"] == body["level_max"] == service.renderer.display.info.level_max
    assert body["uncertainty_decades"] == 0.0


def test_unknown_fading_and_idle(rigs):
    rig = rigs(smoothing_s=0.0, fade_s=0.1)
    service = rig.service
    estimate(rig.estimator, grasp_id="g3", e_pa=None, provisional=True, state="insufficient_data")
    step_until(service, lambda: service.stats.estimates == 1)
    unknown = rig.received()[-1].body
    assert unknown["unknown"] is True and unknown["stiffness"] == 0.0 and unknown["E_pa"] is None
    assert unknown["grasp_id"] == "g3" and unknown["level"] == 0 and unknown["uncertainty_decades"] > 0
    estimate(rig.estimator, grasp_id="g3", e_pa=3e5, provisional=False)
    step_until(service, lambda: service.stats.finals)
    rig.estimator.send("grasp_event", t_capture_s=time.monotonic(), event="end", grasp_id="g3")
    step_until(service, lambda: service.stats.grasp_ends == 1)
    step_until(service, lambda: service.renderer.phase == "idle")
    run_for(service, 0.05)
    messages = [m.body for m in rig.received()]
    fading = [b for b in messages if b["phase"] == "fading"]
    assert fading and all(b["grasp_id"] == "g3" and not b["rigid"] for b in fading)  # the grasp that fades
    assert [b["stiffness"] for b in fading] == sorted((b["stiffness"] for b in fading), reverse=True)
    idle = messages[-1]
    assert idle["phase"] == "idle" and idle["grasp_id"] is None
    assert idle["stiffness"] == 0.0 and idle["E_pa"] is None and idle["level"] == 0


class _BrokenPublisher:
    """Heartbeats go out; every ``display`` message fails as a stuck bus would."""

    heartbeat_s = 0.5

    def __init__(self):
        self.attempts = 0

    def heartbeat_if_due(self, now_s=None) -> bool:
        return False

    def send(self, kind, **body):
        self.attempts += 1
        raise BusTimeoutError("no room for 'display'")


def test_rendering_goes_on_when_publishing_fails(caplog):
    settings = dataclasses.replace(display_settings(load_settings()), smoothing_s=0.0)
    estimator = Publisher("tcp://127.0.0.1:*", lossless=False, source="estimator")
    subscriber = Subscriber(estimator.endpoint, ("estimate", "grasp_event"), conflate=True)
    display = SimulatedDisplay()
    broken = _BrokenPublisher()
    service = RendererService(HapticRenderer(display, settings), subscriber=subscriber, publisher=broken,
                              tick_s=0.005)
    try:
        estimator.wait_for_subscriber("estimate", timeout_s=5.0)
        with caplog.at_level(logging.WARNING, logger="haptics.service"):
            estimate(estimator, grasp_id="g4", e_pa=5e5, provisional=False)
            step_until(service, lambda: service.stats.finals)
            run_for(service, 0.5)  # keep-alive reports: each one's message fails too
    finally:
        estimator.close()
        subscriber.close()
    assert display.rendered_command.level > 0  # the estimate reached the display regardless
    reports = service.renderer.stats.reports_sent
    assert reports >= 2 and broken.attempts == service.stats.display_failures == reports
    assert service.stats.display_messages == 0
    warnings = [r for r in caplog.records if "display message not published" in r.getMessage()]
    assert len(warnings) == 1  # once per run of failures, not once per report


def test_no_publisher_no_messages():
    settings = display_settings(load_settings())
    estimator = Publisher("tcp://127.0.0.1:*", lossless=False, source="estimator")
    subscriber = Subscriber(estimator.endpoint, ("estimate",), conflate=True)
    service = RendererService(HapticRenderer(SimulatedDisplay(), settings), subscriber=subscriber, tick_s=0.005)
    try:
        run_for(service, 0.3)
    finally:
        estimator.close()
        subscriber.close()
    assert service.renderer.stats.reports_sent >= 1  # keep-alive
    assert service.stats.display_messages == service.stats.display_failures == 0


@pytest.mark.slow
def test_the_display_says_what_the_device_reports_and_its_faults_are_logged_once(rigs, caplog):
    from teleop.bus.messages import DISPLAY_DEVICE_STATES, DISPLAY_FAULTS

    assert DEVICE_STATES == DISPLAY_DEVICE_STATES and tuple(FAULT_BITS) == DISPLAY_FAULTS  # one vocabulary
    rig = rigs(smoothing_s=0.0)
    service = rig.service
    firmware = service.renderer.display.firmware
    estimate(rig.estimator, grasp_id="g5", e_pa=2e6, provisional=False)
    step_until(service, lambda: service.stats.finals)
    run_for(service, 0.1)
    rendering = rig.received()[-1].fields
    assert (rendering.device_state, rendering.device_faults) == ("rendering", "") and rendering.level > 0
    with caplog.at_level(logging.INFO, logger="haptics.service"):
        firmware.inject_fault("over_temperature")  # the actuator goes free: state fault, level 0
        run_for(service, 0.5)  # keep-alive reports; the display answers each with its status
        faulted = [m.fields for m in rig.received()]
        firmware.faults.discard("over_temperature")
        run_for(service, 0.5)
        cleared = rig.received()[-1].fields
    assert len(faulted) >= 2 and all(f.device_state == "fault" for f in faulted[1:])
    last = faulted[-1]
    assert last.device_faults == "over_temperature" and last.level == rendering.level  # written, not rendered
    assert last.phase == "active" and last.grasp_id == "g5"
    said = [r for r in caplog.records if r.name == "haptics.service"]
    assert [r.levelno for r in said] == [logging.WARNING, logging.INFO], [r.getMessage() for r in said]
    assert "reports state fault, level 0, faults: over_temperature" in said[0].getMessage()
    assert "reports state rendering again, no faults (was fault)" in said[1].getMessage()
    assert (cleared.device_state, cleared.device_faults) == ("rendering", "")


@pytest.mark.slow
def test_a_status_report_that_does_not_decode_is_logged_and_skipped(rigs, caplog):
    rig = rigs(smoothing_s=0.0)
    service = rig.service
    display = service.renderer.display
    estimate(rig.estimator, grasp_id="g6", e_pa=2e5, provisional=False)
    step_until(service, lambda: service.stats.finals)
    with caplog.at_level(logging.WARNING, logger="haptics.service"):
        for _ in range(3):
            display.firmware.queue_input_report(b"\x03\x07\x00\x00\x00\x00\x00")  # state 7, a bad CRC
            run_for(service, 0.25)
    assert display.connected and display.rendered_command.level > 0  # the link and the rendering stay
    said = [r.getMessage() for r in caplog.records if r.name == "haptics.service"]
    assert len(said) == 1 and "a status report skipped" in said[0], said
    assert rig.received()[-1].fields.device_state == "rendering"  # the good reports after it are read
