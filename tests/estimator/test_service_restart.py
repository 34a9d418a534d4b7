"""An estimator service restarted mid-grasp: the grasp's end still gets a final (a refusal) and its
end, so the renderer, which learns of ends only from the estimator, lets go of the display."""

from __future__ import annotations

import json
from typing import Any

from support.live import METHODS, in_capture_order

from estimator.service import EstimatorService
from haptics.devices.sim import SimulatedDisplay
from haptics.mapping import FREE
from haptics.renderer import HapticRenderer
from haptics.service import RendererService
from haptics.settings import display_settings
from teleop.bus.wire import make_message
from teleop.live import JsonLines


class _Sent:
    def __init__(self) -> None:
        self.sent: list[Any] = []

    def send(self, kind: str, *, t_capture_s: float, topic: str | None = None, **body: Any) -> None:
        self.sent.append(make_message(kind, t_capture_s=t_capture_s, topic=topic, **body))


def _items(record) -> list[tuple[float, str, dict]]:
    return [(float(record.force_n.t_s[0]) - 0.01, "grasp_event", {"event": "start", "object_name": None}),
            *in_capture_order(record),
            (float(record.force_n.t_s[-1]), "grasp_event", {"event": "end"})]


def _service(settings, calibration, report=None) -> EstimatorService:
    return EstimatorService(settings, calibration=calibration, subscriber=None, publisher=_Sent(),
                            methods=METHODS, report=report, clock=lambda: 0.0)


def _feed(service: EstimatorService, items) -> None:
    for t_s, kind, body in items:
        service.handle(make_message(kind, t_capture_s=t_s, grasp_id="g", **body), received_s=t_s)


def test_an_end_of_a_grasp_begun_before_the_service_started_is_refused_then_forwarded(
        settings, calibration, records, tmp_path):
    items = _items(records["stress_ball"])
    restarted = _service(settings, calibration, JsonLines(tmp_path / "report.jsonl"))
    _feed(restarted, items[len(items) // 3:])  # its data ignored: no such grasp open; then its end
    final, end = restarted.publisher.sent
    assert final.type == "estimate" and final.body["grasp_id"] == "g" and not final.body["provisional"]
    assert final.body["state"] == "insufficient_data" and final.body["E_pa"] is None
    assert "started after this grasp began" in final.body["reason"]
    assert (end.type, end.body["event"], end.body["grasp_id"]) == ("grasp_event", "end", "g")
    (report,) = [json.loads(line) for line in (tmp_path / "report.jsonl").read_text().splitlines()]
    assert report["grasp_id"] == "g" and report["final"]["state"] == "insufficient_data"
    # The same end again (or one of a grasp closed as its robot went silent): its final and end went out.
    _feed(restarted, items[-1:])
    assert len(restarted.publisher.sent) == 2 and restarted.stats.final == 1


def test_the_display_fades_to_free_when_a_grasp_ends_after_an_estimator_restart(settings, calibration, records):
    items = _items(records["stress_ball"])
    now = [0.0]
    display = SimulatedDisplay()
    renderer = RendererService(HapticRenderer(display, display_settings(settings)), subscriber=None,
                               clock=lambda: now[0])

    def render(messages) -> None:
        for message in messages:
            now[0] += 0.01
            renderer.handle(message)
            renderer.renderer.tick(now[0])

    before = _service(settings, calibration)
    _feed(before, items[: len(items) // 3])  # provisional estimates, then the service is killed
    render(before.publisher.sent)
    assert renderer.renderer.grasp_id == "g" and renderer.renderer.percept.provisional
    assert renderer.renderer.percept.stiffness > 0 and display.rendered_command.level > 0
    restarted = _service(settings, calibration)
    _feed(restarted, items[len(items) // 3:])
    now[0] += 5.0  # the estimates went stale meanwhile
    renderer.renderer.tick(now[0])
    assert renderer.renderer.phase == "stale"
    render(restarted.publisher.sent)
    now[0] += 1.0  # past the fade
    renderer.renderer.tick(now[0])
    assert renderer.renderer.phase == "idle" and renderer.renderer.percept == FREE
    assert display.rendered_command.level == 0 and renderer.stats.grasp_ends == 1
