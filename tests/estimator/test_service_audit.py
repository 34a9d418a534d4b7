"""EstimatorService behaviours pinned by a mutation audit, driven message by message (no bus)."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest
from support.live import METHODS, feed, in_capture_order
from support.operator_fakes import Clock, QueuedSubscriber, SubscribedPublisher

from estimator import service as service_module
from estimator.estimate import Estimate
from estimator.model_slot import ModelEvent
from estimator.segment import PEAK_FRAME_WINDOW_S
from estimator.service import EstimatorService, resolve_model_dir
from estimator.stream import GraspStream
from teleop.bus.wire import make_message
from teleop.live import JsonLines


class _Outbox(SubscribedPublisher):
    """A publisher that keeps what the service sends, as the bus would deliver it."""

    def __init__(self) -> None:
        self.sent: list[Any] = []

    def send(self, kind: str, *, t_capture_s: float, topic: str | None = None, **body: Any) -> None:
        self.sent.append(make_message(kind, t_capture_s=t_capture_s, topic=topic, **body))

    def of(self, kind: str) -> list[dict]:
        return [m.body for m in self.sent if m.type == kind]


def service_of(settings, calibration, **kwargs) -> EstimatorService:
    return EstimatorService(settings, calibration=calibration, subscriber=None, publisher=_Outbox(), methods=METHODS,
                            clock=lambda: 0.0, **kwargs)


def deliver(service: EstimatorService, kind: str, at_s: float, *, grasp_id: str = "g", received_s: float | None = None,
            **body: Any) -> None:
    """One message captured at ``at_s`` (s), received then unless ``received_s`` says otherwise."""
    message = make_message(kind, t_capture_s=at_s, grasp_id=grasp_id, **body)
    service.handle(message, received_s=at_s if received_s is None else received_s)


def start(service: EstimatorService, record, grasp_id: str = "g") -> None:
    deliver(service, "grasp_event", float(record.force_n.t_s[0]) - 0.01, grasp_id=grasp_id, event="start",
            object_name=None)


def data(service: EstimatorService, record, grasp_id: str = "g", *, until_s: float = float("inf")) -> None:
    for t_s, kind, body in in_capture_order(record):
        if t_s <= until_s:
            deliver(service, kind, t_s, grasp_id=grasp_id, **body)


def end(service: EstimatorService, record, grasp_id: str = "g") -> None:
    deliver(service, "grasp_event", float(record.force_n.t_s[-1]), grasp_id=grasp_id, event="end")


@pytest.fixture(scope="module")
def steel(records):
    return dataclasses.replace(records["steel_ball_bearing"], events={})


def test_a_follow_grasp_stays_one_when_the_robot_reports_another_mode_before_its_start(settings, calibration):
    service = service_of(settings, calibration)
    deliver(service, "robot_state", 1.0, mode="following", target_width_m=0.05, enable=True)
    deliver(service, "robot_state", 1.1, grasp_id=None, mode="idle", target_width_m=None, enable=False)
    deliver(service, "grasp_event", 1.2, event="start", object_name=None)
    assert service._grasp.stream.follow


def finals(service: EstimatorService) -> list[dict]:
    return [body for body in service.publisher.of("estimate") if not body["provisional"]]


def test_the_final_goes_out_with_the_message_that_completes_the_loading(settings, calibration, steel):
    # No marker: the data alone end the loading (force settled, a width and a frame past the peak),
    # whichever of them comes last; the final goes out on it, not on some later message.
    service = service_of(settings, calibration)
    start(service, steel)
    mirror = GraspStream(settings=settings, calibration=calibration, methods=METHODS)
    for t_s, kind, body in in_capture_order(steel):
        deliver(service, kind, t_s, **body)
        feed(mirror, kind, body, t_s)
        if mirror.segment() and mirror.loading_complete():
            break
        assert not finals(service), (t_s, kind)
    (final,) = finals(service)
    assert final["state"] != "insufficient_data" and service._grasp.final_by == "settled"


def test_a_value_error_from_a_message_is_counted_and_logged_and_the_service_carries_on(settings, calibration, steel,
                                                                                         monkeypatch, caplog):
    # numpy's and the fits' ValueErrors are bad input (estimator.service._BAD_INPUT), not a crash.
    service = service_of(settings, calibration)
    start(service, steel)

    def broken(stream, t_s, value_m):
        raise ValueError("width samples the fits cannot take")

    monkeypatch.setattr(GraspStream, "add_width", broken)
    with caplog.at_level("WARNING", logger="estimator.service"):
        deliver(service, "width", float(steel.width_m.t_s[0]), t_s=steel.width_m.t_s[:1], value_m=steel.width_m.value[:1])
    assert service.stats.bad_messages == 1 and "width samples the fits cannot take" in caplog.text
    end(service, steel)
    assert len(finals(service)) == 1 and service.publisher.of("grasp_event") == [{"event": "end", "grasp_id": "g",
                                                                                   "object_name": None}]


def test_the_report_times_the_first_answer_not_the_first_refusal_on_the_capture_clock(settings, calibration, steel,
                                                                                      tmp_path):
    # Every message is received 0.5 s after its capture (another host's clock): the report reads on the capture clock.
    now = [0.0]
    service = service_of(settings, calibration, report=JsonLines(tmp_path / "report.jsonl"))
    service.clock = lambda: now[0]
    sent_by: list[tuple[float, str]] = []  # (capture time of the message that made it, state) per provisional
    items = [(float(steel.force_n.t_s[0]) - 0.01, "grasp_event", {"event": "start", "object_name": None}),
             *in_capture_order(steel)]
    for t_s, kind, body in items:
        now[0] = t_s + 0.5
        before = len(service.publisher.sent)
        deliver(service, kind, t_s, received_s=now[0], **body)
        sent_by += [(t_s, m.body["state"]) for m in service.publisher.sent[before:]
                    if m.type == "estimate" and m.body["provisional"]]
    now[0] = float(steel.force_n.t_s[-1]) + 0.5
    end(service, steel)
    (report,) = [json.loads(line) for line in (tmp_path / "report.jsonl").read_text().splitlines()]
    assert sent_by[0][1] == "insufficient_data"  # the first provisional estimates refuse: too few frames yet
    answered_s = next(t_s for t_s, state in sent_by if state != "insufficient_data")
    assert report["time_to_first_estimate_s"] == pytest.approx(answered_s - report["t_contact_s"], abs=1e-9)
    assert report["provisional"] == len(sent_by) and report["loading_frames"] > 0
    assert report["provisional_span_s"] == pytest.approx(sent_by[-1][0] - sent_by[0][0], abs=1e-9)


def test_two_provisional_estimates_have_a_span_one_has_none(settings, calibration, steel, tmp_path):
    now = [0.0]
    service = service_of(settings, calibration, report=JsonLines(tmp_path / "report.jsonl"))
    service.clock = lambda: now[0]
    spans = []
    for count, grasp_id in ((1, "one"), (2, "two")):
        start(service, steel, grasp_id)
        sent_s = []
        for t_s, kind, body in in_capture_order(steel):
            now[0] = t_s
            deliver(service, kind, t_s, grasp_id=grasp_id, **body)
            provisional = [b for b in service.publisher.of("estimate") if b["grasp_id"] == grasp_id and b["provisional"]]
            if len(provisional) > len(sent_s):
                sent_s.append(t_s)
            if len(sent_s) == count:
                break
        deliver(service, "grasp_event", now[0], grasp_id=grasp_id, event="end")
        spans.append(sent_s[-1] - sent_s[0])
    reports = [json.loads(line) for line in (tmp_path / "report.jsonl").read_text().splitlines()]
    assert [r["provisional"] for r in reports] == [1, 2]
    assert reports[0]["provisional_span_s"] is None and reports[1]["provisional_span_s"] == pytest.approx(spans[1])


def test_a_grasp_of_a_silent_robot_node_ends_at_its_newest_capture_time(settings, calibration, steel):
    clock = Clock()
    subscriber = QueuedSubscriber(clock)  # each message taken refreshes its sender's liveness
    service = EstimatorService(settings, calibration=calibration, subscriber=subscriber, publisher=_Outbox(),
                               methods=METHODS, clock=clock)
    items = [(float(steel.force_n.t_s[0]) - 0.01, "grasp_event", {"event": "start", "object_name": None}),
             *in_capture_order(steel)[:40]]
    for t_s, kind, body in items:
        subscriber.queue.append(dataclasses.replace(make_message(kind, t_capture_s=t_s, grasp_id="g", **body),
                                                    source="robot"))
        service.step(timeout_s=0)
    assert service._grasp is not None
    clock.t += 1.6  # three of its 0.5 s heartbeat periods and a bit
    service.step(timeout_s=0)
    assert service._grasp is None
    (ended,) = [m for m in service.publisher.sent if m.type == "grasp_event"]
    newest_s = max(max(body.get("t_s", [t_s])) for t_s, _, body in items[1:])  # a frame's or a batch's newest
    assert ended.t_capture_s == newest_s > items[0][0]


class _Slot:
    """A model slot that takes load requests and never answers (the check runs elsewhere), and serves no model."""

    estimator = None
    def __init__(self, *args: Any, **kwargs: Any) -> None:
        self.loads: list[str] = []
        self.idle: list[bool] = []  # what each poll was told

    def request_load(self, path: str, request: str) -> None:
        self.loads.append(request)

    def poll(self, *, idle: bool):
        self.idle.append(idle)


def test_load_requests_are_remembered_up_to_a_bound_the_oldest_forgotten_first(settings, calibration):
    service = service_of(settings, calibration, model=_Slot())

    def load(request: str) -> None:
        service.handle_command(make_message("load_model", t_capture_s=1.0, path="/models/m", request=request))

    bound = service_module.REMEMBERED_REQUESTS
    for i in range(bound + 1):
        load(f"r{i}")
    load(f"r{bound}")  # the newest: remembered, not loaded twice
    load("r0")  # the oldest: forgotten, taken as new
    assert service.model.loads == [*(f"r{i}" for i in range(bound + 1)), "r0"]
    assert service.stats.load_requests == bound + 2


def test_a_model_file_names_its_folder(settings, tmp_path):
    assert resolve_model_dir(str(tmp_path / "m" / "model.onnx"), settings) == tmp_path / "m"
    assert resolve_model_dir(str(tmp_path / "m"), settings) == Path(tmp_path / "m")


def test_the_report_is_written_before_the_end_goes_out(settings, calibration, steel, tmp_path):
    # A reader of both (teleop's latency check) finds the report line once it has the end.
    report = tmp_path / "report.jsonl"
    service = service_of(settings, calibration, report=JsonLines(report))
    lines_at_end = []
    send = service.publisher.send

    def sending(kind: str, **fields: Any) -> None:
        if kind == "grasp_event":
            lines_at_end.append(len(report.read_text().splitlines()) if report.exists() else 0)
        send(kind, **fields)

    service.publisher.send = sending
    start(service, steel)
    data(service, steel, until_s=float(steel.force_n.t_s[0]) + 0.1)
    end(service, steel)
    assert lines_at_end == [1]


def test_a_message_of_a_type_the_service_does_not_take_is_counted_as_ignored(settings, calibration):
    service = service_of(settings, calibration)
    service.handle(make_message("heartbeat", t_capture_s=1.0, interval_s=0.5), received_s=1.0)
    assert service.stats.ignored == 1 and service.stats.bad_messages == 0 and not service.publisher.sent


def test_a_load_cell_that_lags_every_frame_still_ends_the_loading_when_its_force_settles(settings, calibration, steel):
    # The force shows the contact only after the last frame came: the force alone must find the contact,
    # and then the settled loading (frames and widths past the peak are all in).
    service = service_of(settings, calibration)
    start(service, steel)
    items = in_capture_order(steel)
    for t_s, kind, body in [item for item in items if item[1] != "force"] + [item for item in items if item[1] == "force"]:
        deliver(service, kind, t_s, **body)
    assert service._grasp.final is not None and service._grasp.final_by == "settled"
    end(service, steel)
    assert len(finals(service)) == 1


def test_a_grasp_of_nothing_ends_its_loading_once_the_load_cell_ran_past_the_stop(settings, calibration):
    # The fingers closed on air and stopped: no contact will show, the final (a refusal) comes with the force
    # read past the stop, not at the grasp's end.
    service = service_of(settings, calibration)
    deliver(service, "grasp_event", 0.0, event="start", object_name=None)
    deliver(service, "width", 0.05, t_s=[0.05], value_m=[0.08])
    deliver(service, "force", 0.1, t_s=np.arange(1, 9) / 80, value_n=np.full(8, 0.01))
    deliver(service, "grasp_event", 0.1, event="loading_end")
    assert service._grasp.final is None  # the load cell lags the stop
    deliver(service, "force", 0.3, t_s=0.1 + np.arange(1, 17) / 80, value_n=np.full(16, 0.01))
    assert PEAK_FRAME_WINDOW_S <= 16 / 80  # the force read runs past the stop by the window
    (final,) = finals(service)
    assert final["state"] == "insufficient_data" and service._grasp.final_by == "loading_end"


def test_a_service_without_a_model_takes_a_load_request_into_a_new_slot(settings, calibration, monkeypatch):
    monkeypatch.setattr(service_module, "ModelSlot", _Slot)
    service = service_of(settings, calibration)
    service.handle_command(make_message("load_model", t_capture_s=1.0, path="/models/m", request="first"))
    assert isinstance(service.model, _Slot) and service.model.loads == ["first"]


def test_the_model_slot_may_switch_only_while_no_grasp_is_open(settings, calibration):
    clock = Clock()
    subscriber = QueuedSubscriber(clock)
    service = EstimatorService(settings, calibration=calibration, subscriber=subscriber, publisher=_Outbox(),
                               methods=METHODS, model=_Slot(), clock=clock)
    for event in ("start", "end"):
        subscriber.queue.append(make_message("grasp_event", t_capture_s=clock.t, grasp_id="g", event=event,
                                             object_name=None))
        service.step(timeout_s=0)
    service.step(timeout_s=0)
    assert service.model.idle == [False, True, True]


class _Answering:
    """A learned model that answers every stream with one estimate (reads no cached depths)."""

    predictor = SimpleNamespace(variant=SimpleNamespace(image="rgb", markers=False))

    def estimate_stream(self, stream: GraspStream, *, mode: str) -> Estimate:
        return Estimate.ok("hybrid", 1e6, 5e5, 2e6, "the stand-in's answer")


class _Serving(_Slot):
    estimator, model_id, model_dir, mode = _Answering(), "stand-in", "/models/stand-in", "auto"


def test_an_operators_grasp_shows_the_models_answer_while_squeezing(settings, calibration, steel):
    service = service_of(settings, calibration, model=_Serving())
    deliver(service, "robot_state", 1.0, mode="following", target_width_m=0.05, enable=True)
    start(service, steel)
    data(service, steel)
    provisional = [body for body in service.publisher.of("estimate") if body["provisional"]]
    answered = [body for body in provisional if body["model"] == "stand-in"]
    assert answered and all(body["E_pa"] == 1e6 and body["method"] == "hybrid" for body in answered)
    assert not finals(service)  # an operator's grasp: its final comes at its end


def test_a_load_request_repeated_after_its_answer_is_answered_again_not_loaded_again(settings, calibration):
    # The sender may have missed the answer (the estimate endpoint is latest-value).
    service = service_of(settings, calibration, model=_Slot())
    request = make_message("load_model", t_capture_s=1.0, path="/models/m", request="r")
    service.handle_command(request)
    service._model_event(ModelEvent("refused", "r", None, "/models/m", "no model.onnx there"))
    service.handle_command(request)
    answers = service.publisher.of("model_event")
    assert service.model.loads == ["r"] and len(answers) == 2 and answers[0] == answers[1]
    assert answers[0]["event"] == "refused" and service.stats.model_refusals == 1
