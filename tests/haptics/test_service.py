"""The renderer process adapter: estimates from the bus onto a simulated display, with final latencies and
the display's own status in the ``display`` messages."""

from __future__ import annotations

import json
import logging
import math
import time

import pytest
from support.bus import KeptPublisher, admit_a_bound_without_its_bound
from support.operator_fakes import Clock, QueuedSubscriber

from haptics.devices.sim import DisplayFirmware, SimulatedDisplay
from haptics.errors import HapticsError
from haptics.protocol import DeviceStatus, encode_input_report
from haptics.renderer import HapticRenderer
from haptics.service import RendererService
from haptics.settings import display_settings
from teleop.bus.pubsub import Publisher, Subscriber
from teleop.live import JsonLines
from teleop.settings import load_settings


@pytest.fixture
def rig(tmp_path):
    settings = display_settings(load_settings())
    display = SimulatedDisplay()
    estimator = Publisher("tcp://127.0.0.1:*", lossless=False, source="estimator")
    heartbeat = Publisher("tcp://127.0.0.1:*", lossless=False, source="renderer")
    subscriber = Subscriber(estimator.endpoint, ("estimate", "grasp_event"), conflate=True)
    report = JsonLines(tmp_path / "renderer.jsonl")
    service = RendererService(HapticRenderer(display, settings), subscriber=subscriber, publisher=heartbeat,
                              report=report, tick_s=0.005)
    estimator.wait_for_subscriber("estimate", "grasp_event", timeout_s=5.0)
    yield service, estimator, display, tmp_path / "renderer.jsonl"
    for sock in (estimator, heartbeat, subscriber):
        sock.close()
    report.close()


def estimate(publisher: Publisher, *, grasp_id: str, t_capture_s: float, e_pa: float | None, provisional: bool,
             state: str = "ok", interval=None) -> None:
    interval = interval if interval is not None else ([e_pa / 2, e_pa * 2] if e_pa else [None, None])
    publisher.send("estimate", t_capture_s=t_capture_s, grasp_id=grasp_id, method="series", E_pa=e_pa,
                   interval_pa=interval, state=state, reason="test", provisional=provisional, latency_s=0.001)


def step_until(service: RendererService, done, timeout_s: float = 5.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not done():
        assert time.monotonic() < deadline, "timed out"
        service.step()


def test_final_estimate_is_rendered_and_its_latency_measured_from_capture(rig):
    service, estimator, display, report_path = rig
    estimate(estimator, grasp_id="g1", t_capture_s=time.monotonic(), e_pa=1e5, provisional=True)
    step_until(service, lambda: service.stats.estimates == 1)
    assert display.rendered_command.provisional
    captured = time.monotonic() - 0.05  # the last loading frame was captured 50 ms ago
    estimate(estimator, grasp_id="g1", t_capture_s=captured, e_pa=2e6, provisional=False)
    step_until(service, lambda: service.stats.finals)
    final = service.stats.finals[0]
    assert final.grasp_id == "g1" and final.e_pa == 2e6 and final.estimates_received == 2
    # From that capture to the display write, which came before now.
    assert 0.05 <= final.latency_s <= time.monotonic() - captured
    shown = display.rendered_command
    assert not shown.provisional and shown.level > 0  # the final estimate reached the display
    assert json.loads(report_path.read_text().splitlines()[0])["latency_ms"] == pytest.approx(final.latency_s * 1e3)
    estimator.send("grasp_event", t_capture_s=time.monotonic(), event="end", grasp_id="g1")
    step_until(service, lambda: service.stats.grasp_ends == 1)
    assert service.renderer.phase in ("fading", "idle")
    # The same final again (a session replayed into a renderer that showed it): counted, not shown.
    estimate(estimator, grasp_id="g1", t_capture_s=captured, e_pa=2e6, provisional=False)
    step_until(service, lambda: service.stats.estimates == 3)
    assert service.stats.ignored == 1 and len(service.stats.finals) == 1
    assert service.stats.as_dict()["ignored"] == 1


def test_an_estimate_that_cannot_be_rendered_is_logged_and_skipped(rig, caplog, monkeypatch):
    service, estimator, display, _ = rig
    admit_a_bound_without_its_bound(monkeypatch)
    with caplog.at_level(logging.WARNING):
        estimate(estimator, grasp_id="g2", t_capture_s=time.monotonic(), e_pa=None, provisional=True,
                 state="lower_bound", interval=[None, None])
        step_until(service, lambda: service.stats.bad_messages == 1)
    assert "not rendered" in caplog.text and "a bound may come from interval_pa" in caplog.text
    estimate(estimator, grasp_id="g2", t_capture_s=time.monotonic(), e_pa=3e4, provisional=False)
    step_until(service, lambda: service.stats.finals)
    assert service.stats.finals[0].e_pa == 3e4 and not display.rendered_command.provisional


def test_renderer_heartbeats_and_ticks_without_messages(rig):
    service, estimator, _, _ = rig
    listener = Subscriber(service.publisher.endpoint, ())
    try:
        deadline = time.monotonic() + 5.0
        while "renderer" not in listener.heartbeat.peers():
            assert time.monotonic() < deadline
            service.step()
            listener.recv(timeout_s=0.01)
    finally:
        listener.close()
    with pytest.raises(HapticsError, match="tick_s"):
        RendererService(service.renderer, subscriber=service.subscriber, tick_s=0.0)


class _SlowPublisher:
    """A publisher whose ``send`` moves the service's clock ``delay_s`` on first (a loaded bus)."""

    def __init__(self, publisher: Publisher, delay_s: float):
        self._publisher, self.delay_s, self.sent, self.offset_s = publisher, delay_s, [], 0.0

    def clock(self) -> float:
        return time.monotonic() + self.offset_s

    def send(self, kind: str, **body) -> None:
        self.offset_s += self.delay_s
        self.sent.append(kind)
        self._publisher.send(kind, **body)

    def __getattr__(self, name: str):
        return getattr(self._publisher, name)


def test_a_finals_latency_ends_at_the_report_not_at_the_display_message(rig):
    service, estimator, _, _ = rig
    slow = service.publisher = _SlowPublisher(service.publisher, delay_s=100.0)
    service.clock = slow.clock
    estimate(estimator, grasp_id="g3", t_capture_s=slow.clock(), e_pa=2e5, provisional=False)
    step_until(service, lambda: service.stats.finals)
    # The display message went out after the report, taking 100 s; the latency does not count it.
    assert "display" in slow.sent
    assert service.stats.finals[0].latency_s < 100.0


@pytest.mark.parametrize("tick_s", [0, -0.01, math.inf, math.nan, True, "0.01"])
def test_a_bad_tick_is_refused_naming_it(tick_s):
    renderer = HapticRenderer(SimulatedDisplay(), display_settings(load_settings()))
    with pytest.raises(HapticsError, match=f"tick_s = {tick_s!r}: expected a finite number of seconds > 0"):
        RendererService(renderer, subscriber=None, tick_s=tick_s)


def test_a_tick_longer_than_the_keepalive_or_the_heartbeat_is_refused_naming_them():
    settings = display_settings(load_settings())
    renderer = HapticRenderer(SimulatedDisplay(), settings)
    with pytest.raises(HapticsError, match=r"tick_s = 1: .*\[display\] keepalive_s = 0.2 s\); expected at most 0.2 s"):
        RendererService(renderer, subscriber=None, tick_s=1.0)
    with Publisher("tcp://127.0.0.1:*", lossless=False, source="renderer", heartbeat_s=0.1) as publisher:
        with pytest.raises(HapticsError, match=r"\[bus\] heartbeat_s = 0.1 s\); expected at most 0.1 s"):
            RendererService(renderer, subscriber=None, publisher=publisher, tick_s=0.15)
        RendererService(renderer, subscriber=None, publisher=publisher, tick_s=0.1)  # the period itself: kept


def test_the_estimate_counts_stay_bounded_over_a_long_session():
    # Late estimates of ended grasps, and grasps whose end was lost (latest-value delivery), must
    # not grow what the service keeps per grasp.
    from haptics.service import _COUNTED_GRASPS
    from teleop.bus.wire import make_message

    service = RendererService(HapticRenderer(SimulatedDisplay(), display_settings(load_settings())),
                              subscriber=None, clock=lambda: 1.0)

    def send(kind: str, **body) -> None:
        service.handle(make_message(kind, t_capture_s=0.5, **body))

    for n in range(200):
        grasp_id = f"g{n}"
        for provisional in (True, False):
            send("estimate", grasp_id=grasp_id, method="series", E_pa=1e5, interval_pa=[5e4, 2e5], state="ok",
                 reason="", provisional=provisional, latency_s=0.001)
        if n % 2:  # every other grasp's end arrives, followed by a late estimate of it
            send("grasp_event", event="end", grasp_id=grasp_id)
            send("estimate", grasp_id=grasp_id, method="series", E_pa=1e5, interval_pa=[5e4, 2e5], state="ok",
                 reason="", provisional=False, latency_s=0.001)
    assert len(service._received) <= _COUNTED_GRASPS and service.stats.ignored == 100
    assert service.stats.finals and {f.estimates_received for f in service.stats.finals} == {2}


@pytest.mark.parametrize("t_capture_s", [3.9e9, -3.9e9])  # far in this clock's future, or its past
def test_a_final_stamped_off_this_clock_is_rendered_its_latency_left_out_and_logged_sparingly(
        rig, caplog, t_capture_s):
    service, estimator, display, report_path = rig
    with caplog.at_level(logging.WARNING, logger="haptics.service"):
        for i in range(12):
            estimate(estimator, grasp_id=f"g{i}", t_capture_s=t_capture_s, e_pa=2e6, provisional=False)
            step_until(service, lambda n=i + 1: len(service.stats.finals) == n)
            assert not display.rendered_command.provisional and display.rendered_command.level > 0  # shown
            estimator.send("grasp_event", t_capture_s=time.monotonic(), event="end", grasp_id=f"g{i}")
            step_until(service, lambda n=i + 1: service.stats.grasp_ends == n)
    assert [f.latency_s for f in service.stats.finals] == [None] * 12
    assert [json.loads(line)["latency_ms"] for line in report_path.read_text().splitlines()] == [None] * 12
    assert service.stats.unmeasured == 12 and service.stats.bad_messages == 0
    lines = [r.getMessage() for r in caplog.records if r.name == "haptics.service"]
    assert len(lines) == 2, lines  # the first, then the tenth
    assert "grasp g0: final estimate captured at" in lines[0] and "latency is left out" in lines[0]
    assert lines[1].startswith("10 final estimates' latencies left out so far")


def run_for(service: RendererService, seconds: float) -> None:
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        service.step()


def test_a_final_that_arrives_while_the_display_is_unplugged_is_reported_as_not_shown(rig, caplog):
    service, estimator, display, report_path = rig
    estimate(estimator, grasp_id="g1", t_capture_s=time.monotonic(), e_pa=1e5, provisional=True)
    step_until(service, lambda: service.stats.estimates == 1)
    display.unplug()
    with caplog.at_level(logging.WARNING, logger="haptics.service"):
        estimate(estimator, grasp_id="g1", t_capture_s=time.monotonic(), e_pa=2e6, provisional=False)
        step_until(service, lambda: service.stats.estimates == 2)
        run_for(service, 0.2)
        assert not service.stats.finals  # not shown yet: it may be, should the display come back
        estimator.send("grasp_event", t_capture_s=time.monotonic(), event="end", grasp_id="g1")
        step_until(service, lambda: service.stats.grasp_ends == 1)
    # Recorded at the grasp's end, not on the first report written after the replug (level 0).
    assert len(service.stats.finals) == 1
    final = service.stats.finals[0]
    assert final.latency_s is None and final.level is None and final.estimates_received == 2
    assert "g1: its final estimate" in caplog.text and "never shown" in caplog.text
    display.replug()
    step_until(service, lambda: display.connected)
    run_for(service, 0.3)
    assert display.rendered_command.level == 0 and len(service.stats.finals) == 1
    (line,) = report_path.read_text().splitlines()
    report = json.loads(line)
    assert report["latency_ms"] is None and report["level"] is None and report["estimates_received"] == 2
    assert report["E_pa"] == 2e6 and report["level_max"] == display.info.level_max


def test_a_final_shown_once_the_display_is_back_is_measured_to_that_report(rig):
    service, estimator, display, _ = rig
    display.unplug()
    captured = time.monotonic()
    estimate(estimator, grasp_id="g2", t_capture_s=captured, e_pa=2e6, provisional=False)
    step_until(service, lambda: service.stats.estimates == 1)
    run_for(service, 0.1)
    display.replug()
    step_until(service, lambda: service.stats.finals)
    final = service.stats.finals[0]
    assert final.level > 0 and final.estimates_received == 1  # the level it settles on
    assert display.rendered_command.level > 0 and not display.rendered_command.provisional
    assert 0.1 <= final.latency_s <= time.monotonic() - captured


def _unplugged_service(monkeypatch=None, kept: int | None = None):
    from haptics import service as service_module

    if kept is not None:
        monkeypatch.setattr(service_module, "KEPT_FINALS", kept)
    display = SimulatedDisplay()
    display.unplug()  # no report reaches it: every final is never shown
    return RendererService(HapticRenderer(display, display_settings(load_settings())), subscriber=None,
                           clock=lambda: 1.0)


def _send(service: RendererService, kind: str, seq: int = 0, t_capture_s: float = 0.5, **body) -> None:
    import dataclasses

    from teleop.bus.wire import make_message

    message = dataclasses.replace(make_message(kind, t_capture_s=t_capture_s, **body), source="estimator", seq=seq)
    service.handle(message)


def test_estimates_that_cannot_be_rendered_are_counted_and_logged_sparingly(caplog, monkeypatch):
    service = _unplugged_service()
    admit_a_bound_without_its_bound(monkeypatch)
    with caplog.at_level(logging.WARNING, logger="haptics.service"):
        for seq in range(120):
            _send(service, "estimate", seq=seq, grasp_id="g", method="series", E_pa=None, interval_pa=[None, None],
                  state="lower_bound", reason="", provisional=True, latency_s=0.0)
    assert service.stats.bad_messages == 120 and service.stats.estimates == 0
    lines = [r.getMessage() for r in caplog.records if r.name == "haptics.service"]
    assert len(lines) == 3, lines  # the first, then the 10th and the 100th
    assert lines[0].startswith("estimate from estimator (seq 0) not rendered:") and "counted" in lines[0]
    assert lines[1].startswith("10 estimates not rendered so far, the last from estimator (seq 9)")
    assert lines[2].startswith("100 estimates not rendered so far")


def test_finals_never_shown_are_logged_sparingly_and_only_the_last_ones_are_kept(monkeypatch, caplog, tmp_path):
    from haptics.service import KEPT_FINALS

    assert KEPT_FINALS == 1000  # as the docs say (``haptics serve --json``)
    service = _unplugged_service(monkeypatch, kept=10)
    with caplog.at_level(logging.WARNING, logger="haptics.service"):
        for n in range(25):
            _send(service, "estimate", seq=n, grasp_id=f"g{n}", method="series", E_pa=1e5, interval_pa=[5e4, 2e5],
                  state="ok", reason="", provisional=False, latency_s=0.0)
        _send(service, "grasp_event", seq=25, event="end", grasp_id="g24")
    stats = service.stats
    assert stats.final_estimates == stats.not_shown == 25
    assert [f.grasp_id for f in stats.finals] == [f"g{n}" for n in range(15, 25)]  # the last 10
    summary = stats.as_dict()
    assert summary["final_estimates"] == summary["not_shown"] == 25 and len(summary["finals"]) == 10
    lines = [r.getMessage() for r in caplog.records if r.name == "haptics.service"]
    assert len(lines) == 2, lines  # the first, then the 10th
    assert lines[0].startswith("grasp g0: its final estimate") and "never shown" in lines[0]
    assert lines[1].startswith("10 final estimates never shown so far")


# --------------------------------------------------------------------------- the display's status, on a fake clock


def _clocked_service(display: SimulatedDisplay | None = None, **display_overrides):
    """A service on a fake clock with a display (a simulated one by default); nothing on its subscriber."""
    import dataclasses

    clock, publisher = Clock(), KeptPublisher()
    settings = dataclasses.replace(display_settings(load_settings()), **display_overrides)
    renderer = HapticRenderer(display or SimulatedDisplay(), settings)
    service = RendererService(renderer, subscriber=QueuedSubscriber(clock), publisher=publisher, tick_s=0.005,
                              clock=clock)
    return service, publisher, clock


def _estimate_at(service: RendererService, grasp_id: str, e_pa: float | None, *, t_capture_s: float,
                 provisional: bool, state: str = "ok", interval=None) -> None:
    interval = interval if interval is not None else ([e_pa / 2, e_pa * 2] if e_pa else [None, None])
    _send(service, "estimate", t_capture_s=t_capture_s, grasp_id=grasp_id, method="series", E_pa=e_pa,
          interval_pa=interval, state=state, reason="test", provisional=provisional, latency_s=0.001)


def _run_clocked(service: RendererService, clock: Clock, seconds: float, dt_s: float = 0.005) -> None:
    for _ in range(round(seconds / dt_s)):
        clock.t += dt_s
        service.step()


def _queue_status(display: SimulatedDisplay, state: str, level: int, faults=()) -> None:
    display.firmware.queue_input_report(encode_input_report(DeviceStatus(state, level, frozenset(faults), 0)))


def test_an_unknown_percept_has_no_modulus_while_its_level_still_settles():
    service, publisher, clock = _clocked_service()
    _estimate_at(service, "g1", 1e6, t_capture_s=clock.t, provisional=True)
    _run_clocked(service, clock, 1.0)  # settled on 1 MPa
    _estimate_at(service, "g1", None, t_capture_s=clock.t, provisional=True, state="insufficient_data")
    shown = publisher.of("display")[-1]
    assert shown["unknown"] and shown["stiffness"] > 0  # smoothing: the level still falls
    assert shown["E_pa"] is None


def test_a_finals_level_is_the_level_the_display_settles_on():
    # Not the lagging level of the first report written after the final.
    service, publisher, clock = _clocked_service(smoothing_s=0.5)
    _estimate_at(service, "g1", 2e6, t_capture_s=clock.t - 0.05, provisional=False)
    final = service.stats.finals[-1]
    _run_clocked(service, clock, 10.0)
    assert final.level == service.renderer.command.level > 0


def test_a_final_captured_up_to_a_second_late_is_measured():
    # A camera may stamp its frames up to a second late: a latency of -0.5 s is kept, not left out.
    service, publisher, clock = _clocked_service()
    _estimate_at(service, "g1", 2e6, t_capture_s=clock.t + 0.5, provisional=False)
    final = service.stats.finals[-1]
    assert final.latency_s == pytest.approx(-0.5) and final.to_json()["latency_ms"] == pytest.approx(-500.0)
    assert service.stats.unmeasured == 0


def test_stopping_publishes_the_display_state_of_its_answer_to_the_free_command():
    service, publisher, clock = _clocked_service()
    _estimate_at(service, "g1", 2e6, t_capture_s=clock.t, provisional=True)
    _run_clocked(service, clock, 0.1)
    assert publisher.of("display")[-1]["device_state"] == "rendering"
    service.finish()
    last = publisher.of("display")[-1]
    assert (last["phase"], last["level"], last["device_state"]) == ("idle", 0, "free")


def test_stopping_mid_grasp_at_the_soft_end_still_publishes_the_idle_display():
    # The grasp's reports carried level 0, the free command's: the display is set free all the same.
    service, publisher, clock = _clocked_service()
    _estimate_at(service, "g1", 1e3, t_capture_s=clock.t, provisional=False, interval=[5e2, 2e3])
    _run_clocked(service, clock, 0.1)
    assert service.renderer.phase != "idle" and service.renderer.command.level == 0
    service.finish()
    last = publisher.of("display")[-1]
    assert (last["phase"], last["grasp_id"]) == ("idle", None)


def test_the_newest_of_the_status_reports_sent_since_the_last_message_is_published():
    # The display may send statuses of its own (state changes): the message carries the newest.
    service, publisher, clock = _clocked_service()
    display = service.renderer.display
    _estimate_at(service, "g1", 2e6, t_capture_s=clock.t, provisional=True)
    _run_clocked(service, clock, 0.1)
    _queue_status(display, "rendering", 100)
    _queue_status(display, "rendering", 100)
    display.firmware.inject_fault("over_current")  # the answer to the next write says fault
    count = len(publisher.of("display"))
    _estimate_at(service, "g1", 3e6, t_capture_s=clock.t, provisional=True)
    _run_clocked(service, clock, 0.005)  # the level starts toward 3 MPa: a report is written
    assert len(publisher.of("display")) > count
    assert (publisher.of("display")[-1]["device_state"], publisher.of("display")[-1]["device_faults"]) == (
        "fault", "over_current")


def test_a_status_report_that_does_not_decode_does_not_hide_the_ones_after_it(monkeypatch):
    service, publisher, clock = _clocked_service()
    firmware = service.renderer.display.firmware
    _estimate_at(service, "g1", 2e6, t_capture_s=clock.t, provisional=True)
    _run_clocked(service, clock, 0.1)
    answer = firmware.receive_output

    def garbled_then_answer(report):  # line noise just before the display's answer
        firmware.queue_input_report(b"\x03\x09\x00\x00\x00\x00\x00")  # state 9: does not decode
        answer(report)

    monkeypatch.setattr(firmware, "receive_output", garbled_then_answer)
    firmware.inject_fault("over_temperature")
    count = len(publisher.of("display"))
    _run_clocked(service, clock, 0.5)  # a keep-alive at least
    first = publisher.of("display")[count]  # the message of the first report written after the fault
    assert (first["device_state"], first["device_faults"]) == ("fault", "over_temperature")


class _SlowAnsweringFirmware(DisplayFirmware):
    """A display whose status answers may come later than the host's poll (a real one takes ms)."""

    quiet = False

    def receive_output(self, report):
        super().receive_output(report)
        if self.quiet:
            self._statuses.clear()


def test_a_display_back_from_an_unplug_has_no_status_until_it_sends_one():
    firmware = _SlowAnsweringFirmware()
    service, publisher, clock = _clocked_service(SimulatedDisplay(firmware=firmware))
    display = service.renderer.display
    _estimate_at(service, "g1", 2e6, t_capture_s=clock.t, provisional=True)
    _run_clocked(service, clock, 0.1)
    firmware.inject_fault("over_current")
    _run_clocked(service, clock, 0.5)  # a keep-alive went out: its status says fault
    assert publisher.of("display")[-1]["device_state"] == "fault"
    display.unplug()
    _run_clocked(service, clock, 0.5)  # the keep-alive fails: disconnected
    assert not display.connected
    firmware.quiet = True
    display.replug()  # power-on reset: the fault is gone
    count = len(publisher.of("display"))
    _run_clocked(service, clock, 3.0)
    assert display.connected and len(publisher.of("display")) > count
    assert publisher.of("display")[-1]["device_state"] is None


def test_fault_bits_without_a_fault_state_are_trouble_logged_once(caplog):
    service, publisher, clock = _clocked_service()
    _estimate_at(service, "g1", 2e6, t_capture_s=clock.t, provisional=True)
    _run_clocked(service, clock, 0.1)
    with caplog.at_level(logging.INFO, logger="haptics.service"):
        for _ in range(3):  # the same trouble, reported three times
            _queue_status(service.renderer.display, "rendering", 100, faults=("bad_report",))
        _run_clocked(service, clock, 0.5)  # keep-alives: statuses with no faults
    lines = [r.getMessage() for r in caplog.records if r.name == "haptics.service"]
    assert len([line for line in lines if "faults: bad_report" in line]) == 1, lines
    assert any("again, no faults" in line for line in lines), lines
