"""Audit of the renderer service (:mod:`haptics.service`): what it leaves the display and reports on
stopping, the edges of a final's plausible latency, a forwarded loading-end, the display's trouble
states, and the status reports a failed link leaves behind. All on a fake clock, no bus."""

from __future__ import annotations

import dataclasses
import json
import logging

import pytest
from support.bus import KeptPublisher
from support.operator_fakes import Clock, QueuedSubscriber

from haptics.devices.sim import SimulatedDisplay
from haptics.errors import DisplayError, DisplayNotConnectedError
from haptics.mapping import Percept
from haptics.protocol import DeviceStatus, encode_input_report
from haptics.renderer import HapticRenderer
from haptics.service import PLAUSIBLE_LATENCY_S, FinalLatency, RendererService
from haptics.settings import display_settings
from teleop.bus.wire import make_message
from teleop.settings import load_settings


def _service(**display_overrides) -> tuple[RendererService, KeptPublisher, Clock]:
    clock, publisher = Clock(), KeptPublisher()
    settings = dataclasses.replace(display_settings(load_settings()), **display_overrides)
    service = RendererService(HapticRenderer(SimulatedDisplay(), settings), subscriber=QueuedSubscriber(clock),
                              publisher=publisher, tick_s=0.005, clock=clock)
    return service, publisher, clock


def _send(service: RendererService, kind: str, *, t_capture_s: float, **body) -> None:
    message = dataclasses.replace(make_message(kind, t_capture_s=t_capture_s, **body), source="estimator", seq=0)
    service.handle(message)


def _estimate(service: RendererService, grasp_id: str, e_pa: float, *, t_capture_s: float,
              provisional: bool) -> None:
    _send(service, "estimate", t_capture_s=t_capture_s, grasp_id=grasp_id, method="series", E_pa=e_pa,
          interval_pa=[e_pa / 2, e_pa * 2], state="ok", reason="test", provisional=provisional, latency_s=0.001)


def _run(service: RendererService, clock: Clock, seconds: float, dt_s: float = 0.005) -> None:
    for _ in range(round(seconds / dt_s)):
        clock.t += dt_s
        service.step()


# --------------------------------------------------------------------------- stopping


def test_stopping_mid_grasp_counts_the_idle_display_message_it_publishes():
    service, publisher, clock = _service()
    _estimate(service, "g1", 2e6, t_capture_s=clock.t, provisional=True)
    _run(service, clock, 0.1)
    before = service.stats.display_messages
    assert before == len(publisher.of("display"))
    service.finish()
    assert service.renderer.display.last_command.level == 0  # set free
    assert service.stats.display_messages == before + 1 == len(publisher.of("display"))
    assert publisher.of("display")[-1]["phase"] == "idle"


@pytest.mark.parametrize("error", [OSError("the bus went away"), DisplayError("write failed")])
def test_a_free_command_that_cannot_be_written_on_stopping_is_logged_not_raised(monkeypatch, caplog, error):
    service, publisher, clock = _service()
    _estimate(service, "g1", 2e6, t_capture_s=clock.t, provisional=True)
    _run(service, clock, 0.1)
    published = len(publisher.of("display"))

    def failing(command):
        raise error

    monkeypatch.setattr(service.renderer.display, "write_command", failing)
    with caplog.at_level(logging.WARNING, logger="haptics.service"):
        service.finish()  # must not raise: the service still closes what it holds
    (said,) = [r.getMessage() for r in caplog.records if r.name == "haptics.service"]
    assert "not set free on stopping" in said and str(error) in said
    assert len(publisher.of("display")) == published  # no idle message claims a display that was not freed


def test_stopping_with_the_display_unplugged_names_the_level_last_written_not_the_one_that_failed(caplog):
    # The write that found the display gone asked for level 0: the display still holds what was written.
    service, _, clock = _service(smoothing_s=0.0)
    display = service.renderer.display
    _estimate(service, "g1", 2e6, t_capture_s=clock.t, provisional=True)
    held = display.rendered_command.level
    assert held > 0
    display.unplug()
    clock.t += 0.005
    _estimate(service, "g1", 1e3, t_capture_s=clock.t, provisional=True)  # the soft end: level 0, not written
    assert not display.connected and display.last_command.level == 0
    assert display.rendered_command.level == held
    with caplog.at_level(logging.INFO, logger="haptics.service"):
        service.finish()
    (said,) = [r for r in caplog.records if r.name == "haptics.service"]
    assert said.levelno == logging.WARNING
    assert f"the last level written, {held} of {display.info.level_max}" in said.getMessage()


def test_stopping_with_the_display_unplugged_after_a_rigid_level_0_write_warns_it_may_hold_it(caplog):
    # A rigid estimate's flag goes out at once while its level still starts from 0 (smoothing): a display
    # unplugged then was last written rigid, and may hold that rigid flag.
    service, _, clock = _service()
    display = service.renderer.display
    _send(service, "estimate", t_capture_s=clock.t, grasp_id="g1", method="series", E_pa=1e12,
          interval_pa=[1e11, None], state="lower_bound", reason="test", provisional=True, latency_s=0.001)
    written = display.rendered_command
    assert written.rigid and written.level == 0
    display.unplug()
    _run(service, clock, 0.05)  # the next write finds it gone
    assert not display.connected
    with caplog.at_level(logging.INFO, logger="haptics.service"):
        service.finish()
    (said,) = [r for r in caplog.records if r.name == "haptics.service"]
    assert said.levelno == logging.WARNING and "may hold the last level written, 0 of" in said.getMessage()


# --------------------------------------------------------------------------- inputs and latency


def test_a_forwarded_loading_end_does_not_end_the_grasp_rendered():
    service, _, clock = _service()
    _estimate(service, "g1", 2e6, t_capture_s=clock.t, provisional=True)
    _send(service, "grasp_event", t_capture_s=clock.t, event="loading_end", grasp_id="g1")
    assert service.renderer.grasp_id == "g1" and service.stats.grasp_ends == 0
    _estimate(service, "g1", 3e6, t_capture_s=clock.t, provisional=False)  # its final still counts
    assert service.stats.ignored == 0
    assert [(f.grasp_id, f.estimates_received) for f in service.stats.finals] == [("g1", 2)]


def _forgotten_by_the_renderer(service: RendererService, clock: Clock) -> None:
    """Ends of 16 other grasps (with no estimates): the renderer no longer remembers an earlier end."""
    for n in range(16):
        _send(service, "grasp_event", t_capture_s=clock.t, event="end", grasp_id=f"h{n}")


def test_a_grasp_named_again_after_its_end_counts_its_estimates_anew():
    # A session replayed, or a robot node that names its grasps again: once the renderer no longer
    # remembers g1's end, g1's new estimates are rendered, and its final counts them only.
    service, _, clock = _service()
    _estimate(service, "g1", 1e5, t_capture_s=clock.t, provisional=True)
    _estimate(service, "g1", 2e5, t_capture_s=clock.t, provisional=False)
    _send(service, "grasp_event", t_capture_s=clock.t, event="end", grasp_id="g1")
    _forgotten_by_the_renderer(service, clock)
    _estimate(service, "g1", 3e5, t_capture_s=clock.t, provisional=False)
    assert service.stats.ignored == 0
    assert [f.estimates_received for f in service.stats.finals] == [2, 1]


def test_a_grasp_its_dead_estimators_final_ended_counts_its_estimates_anew_when_named_again():
    service, _, clock = _service()

    def heard(provisional: bool) -> None:  # an estimate of g1 the subscriber hands in: its source is heard
        service.subscriber.queue.append(dataclasses.replace(make_message(
            "estimate", t_capture_s=clock.t, grasp_id="g1", method="series", E_pa=2e5, interval_pa=[1e5, 4e5],
            state="ok", reason="test", provisional=provisional, latency_s=0.001), source="estimator", seq=0))
        _run(service, clock, 0.005)

    heard(provisional=True)
    heard(provisional=False)
    assert service.renderer.has_final
    _run(service, clock, 3.0)  # the estimator unheard for three of its periods: g1 ends here
    assert service.renderer.phase == "idle" and service.stats.grasp_ends == 0
    _forgotten_by_the_renderer(service, clock)
    heard(provisional=False)
    _run(service, clock, 0.05)  # the level leaves 0: a report shows the final
    assert [f.estimates_received for f in service.stats.finals] == [2, 1]


def test_an_estimator_that_dies_while_nothing_is_rendered_is_not_said_and_changes_nothing(caplog):
    service, publisher, clock = _service()
    service.subscriber.queue.append(dataclasses.replace(make_message(
        "estimate", t_capture_s=clock.t, grasp_id="g1", method="series", E_pa=2e5, interval_pa=[1e5, 4e5],
        state="ok", reason="test", provisional=False, latency_s=0.001), source="estimator", seq=0))
    _run(service, clock, 0.05)
    _send(service, "grasp_event", t_capture_s=clock.t, event="end", grasp_id="g1")
    _run(service, clock, 3.0)  # faded to free; the estimator goes unheard meanwhile
    assert service.renderer.phase == "idle"
    with caplog.at_level(logging.INFO, logger="haptics.service"):
        _run(service, clock, 1.0)
    assert [r.getMessage() for r in caplog.records if r.name == "haptics.service"] == []
    assert service.renderer.display.last_command.level == 0


class _TickingClock(Clock):
    """A clock that moves a millisecond on at every reading (a real one never stands still)."""

    def __call__(self) -> float:
        self.t += 0.001
        return self.t


def test_every_report_written_when_the_estimator_dies_has_its_display_message():
    clock, publisher = _TickingClock(), KeptPublisher()
    service = RendererService(HapticRenderer(SimulatedDisplay(), display_settings(load_settings())),
                              subscriber=QueuedSubscriber(clock), publisher=publisher, tick_s=0.005, clock=clock)
    service.subscriber.queue.append(dataclasses.replace(make_message(
        "estimate", t_capture_s=clock.t, grasp_id="g1", method="series", E_pa=2e5, interval_pa=[1e5, 4e5],
        state="ok", reason="test", provisional=True, latency_s=0.001), source="estimator", seq=0))
    phases = []
    for _ in range(1000):  # the estimator goes unheard mid-grasp: released, faded to free
        service.step()
        phases.append(service.renderer.phase)
        assert service.stats.display_messages == service.renderer.stats.reports_sent == len(publisher.of("display"))
    assert "fading" in phases and phases[-1] == "idle"


@pytest.mark.parametrize("latency_s, measured", [
    (PLAUSIBLE_LATENCY_S[0], True), (PLAUSIBLE_LATENCY_S[1], True),
    (PLAUSIBLE_LATENCY_S[0] - 0.5, False), (PLAUSIBLE_LATENCY_S[1] + 0.5, False),
])
def test_a_finals_latency_on_the_plausible_bounds_is_measured_and_beyond_them_left_out(latency_s, measured):
    service, _, clock = _service()
    clock.t = 4000.0  # both bounds are exact on this clock
    _estimate(service, "g1", 2e6, t_capture_s=clock.t - latency_s, provisional=False)
    (final,) = service.stats.finals
    assert final.latency_s == (latency_s if measured else None)
    assert service.stats.unmeasured == (0 if measured else 1)
    assert final.level is not None and final.level > 0  # shown all the same


def test_a_finals_report_says_unknown_and_rigid_apart():
    final = FinalLatency(grasp_id="g", state="insufficient_data", e_pa=None, latency_s=0.01, estimates_received=1,
                         percept=Percept(stiffness=0.25, uncertainty_decades=1.5, unknown=True), level=5,
                         level_max=10)
    out = final.to_json()
    assert (out["unknown"], out["rigid"]) == (True, False)
    assert out["display_fraction"] == 0.25 and out["uncertainty_decades"] == 1.5
    assert (out["latency_ms"], out["level"], out["level_max"]) == (pytest.approx(10.0), 5, 10)


# --------------------------------------------------------------------------- the display's status


def test_a_display_whose_watchdog_tripped_is_logged_as_trouble(caplog):
    service, _, clock = _service()
    _estimate(service, "g1", 2e6, t_capture_s=clock.t, provisional=True)
    _run(service, clock, 0.1)
    with caplog.at_level(logging.WARNING, logger="haptics.service"):
        service.renderer.display.firmware.queue_input_report(
            encode_input_report(DeviceStatus("watchdog", 0, frozenset(), 0)))
        _run(service, clock, 0.01)
    lines = [r.getMessage() for r in caplog.records if r.name == "haptics.service"]
    assert any("reports state watchdog" in line for line in lines), lines


@pytest.mark.parametrize("error", [DisplayError("link lost"), DisplayNotConnectedError("closed meanwhile")])
def test_a_failed_status_read_forgets_the_status_the_display_last_sent(monkeypatch, error):
    service, publisher, clock = _service(smoothing_s=0.0)
    display = service.renderer.display
    _estimate(service, "g1", 2e6, t_capture_s=clock.t, provisional=True)
    _run(service, clock, 0.1)
    assert publisher.of("display")[-1]["device_state"] == "rendering"

    def failing(timeout_s=None):
        raise error

    monkeypatch.setattr(display, "read_status", failing)
    _estimate(service, "g1", 3e6, t_capture_s=clock.t, provisional=True)  # a report written: a message
    assert publisher.of("display")[-1]["device_state"] is None  # no status vouches for what it does now
    assert publisher.of("display")[-1]["device_faults"] is None


def test_a_final_still_waiting_for_the_display_when_the_service_stops_is_reported_as_not_shown(tmp_path):
    # The display unplugged: the final waits for a report that could show it. The service stopping ends
    # that wait: the final goes to the report all the same (one object per final), as never shown.
    from teleop.live import JsonLines

    service, _, clock = _service()
    service.report = report = JsonLines(tmp_path / "renderer.jsonl")
    display = service.renderer.display
    _estimate(service, "g1", 1e5, t_capture_s=clock.t, provisional=True)
    display.unplug()
    _run(service, clock, 0.05)
    _estimate(service, "g1", 2e6, t_capture_s=clock.t, provisional=False)
    _run(service, clock, 0.05)
    assert not service.stats.finals  # it may still be shown, should the display come back
    service.finish()
    report.close()
    (final,) = service.stats.finals
    assert (final.grasp_id, final.e_pa, final.latency_s, final.level) == ("g1", 2e6, None, None)
    assert final.estimates_received == 2
    assert service.stats.not_shown == service.stats.final_estimates == 1
    (line,) = (tmp_path / "renderer.jsonl").read_text().splitlines()
    assert json.loads(line)["E_pa"] == 2e6 and json.loads(line)["latency_ms"] is None
