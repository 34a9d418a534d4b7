"""The estimator service: a grasp's lifecycle driven message by message (no bus), its per-grasp report on a
foreign clock, a model that fails, and its command line."""

from __future__ import annotations

import json
from types import SimpleNamespace
from typing import Any

import pytest
from support.live import METHODS, in_capture_order

import estimator.cli
from estimator.errors import ModelError
from estimator.service import EstimatorService
from teleop.bus.wire import make_message
from teleop.live import JsonLines


class _Sent:
    def __init__(self) -> None:
        self.sent: list[Any] = []

    def send(self, kind: str, *, t_capture_s: float, topic: str | None = None, **body: Any) -> None:
        self.sent.append(make_message(kind, t_capture_s=t_capture_s, topic=topic, **body))


@pytest.mark.parametrize("speed", [1.0, 4.0])
def test_time_to_first_estimate_is_read_on_the_capture_clock(settings, calibration, records, tmp_path, speed):
    # A replay (at 1x or 4x: `teleop replay --speed`), or a node on another host: capture times run
    # 1000 s behind the service's clock.
    offset_s, delay_s = 1000.0, 0.002
    now = [0.0]
    service = EstimatorService(settings, calibration=calibration, subscriber=None, publisher=_Sent(),
                               methods=METHODS, report=JsonLines(tmp_path / "report.jsonl"), clock=lambda: now[0])
    record = records["stress_ball"]
    items = [(0.0, "grasp_event", {"event": "start", "object_name": None})] + in_capture_order(record)
    items.append((float(record.force_n.t_s[-1]), "grasp_event", {"event": "end"}))
    for t_s, kind, body in items:
        now[0] = t_s / speed + offset_s + delay_s
        service.handle(make_message(kind, t_capture_s=t_s, grasp_id="g", **body), received_s=now[0])
    (report,) = [json.loads(line) for line in (tmp_path / "report.jsonl").read_text().splitlines()]
    first = next(m for m in service.publisher.sent if m.type == "estimate" and m.body["state"] != "insufficient_data")
    # Not before the data it rests on was captured; within the grasp's first fraction of a second.
    assert first.t_capture_s - report["t_contact_s"] <= report["time_to_first_estimate_s"] < 0.5


def test_time_to_first_estimate_maps_the_clocks_by_the_least_delay_seen(settings, calibration, records, tmp_path):
    # The service's clock runs 1000 s ahead of the capture clock; the first data came at once, the rest
    # 0.5 s late (a backlog): the least delay, not the latest, maps one clock onto the other.
    now = [0.0]
    service = EstimatorService(settings, calibration=calibration, subscriber=None, publisher=_Sent(),
                               methods=METHODS, report=JsonLines(tmp_path / "report.jsonl"), clock=lambda: now[0])
    first_s = None
    for n, (t_s, kind, body) in enumerate(_grasp_items(records["stress_ball"])):
        now[0] = t_s + 1000.0 + (0.0 if n <= 1 else 0.5)  # the start and the first data message at once
        sent = len(service.publisher.sent)
        service.handle(make_message(kind, t_capture_s=t_s, grasp_id="g", **body), received_s=now[0])
        if first_s is None and any(m.type == "estimate" and m.body["state"] != "insufficient_data"
                                   for m in service.publisher.sent[sent:]):
            first_s = t_s  # the capture time of the message that brought the first estimate
    (report,) = [json.loads(line) for line in (tmp_path / "report.jsonl").read_text().splitlines()]
    # That estimate went out 0.5 s after its message was captured, on the capture clock.
    assert first_s is not None
    assert report["time_to_first_estimate_s"] == pytest.approx(first_s + 0.5 - report["t_contact_s"], abs=1e-9)


@pytest.mark.parametrize("value", ["nan", "-1", "0", "inf"])
def test_serve_refuses_a_duration_that_is_no_positive_time(value, capsys):
    with pytest.raises(SystemExit) as exit_info:
        estimator.cli.main(["serve", "--duration-s", value])
    assert exit_info.value.code == 2 and "--duration-s" in capsys.readouterr().err


def _grasp_items(record, *, end: bool = True) -> list[tuple[float, str, dict]]:
    items = [(float(record.force_n.t_s[0]) - 0.01, "grasp_event", {"event": "start", "object_name": None}),
             *in_capture_order(record)]
    if end:
        items.append((float(record.force_n.t_s[-1]), "grasp_event", {"event": "end"}))
    return items


def _run(service, items, grasp_id: str) -> None:
    for t_s, kind, body in items:
        service.handle(make_message(kind, t_capture_s=t_s, grasp_id=grasp_id, **body), received_s=t_s)


def test_a_grasp_started_again_while_open_leaves_the_new_one_alone(settings, calibration, records, tmp_path):
    # A robot node killed mid-grasp and restarted names the grasp again: nothing of the first may
    # go out under that id (a final or an end would make a renderer ignore the new grasp's estimates).
    service = EstimatorService(settings, calibration=calibration, subscriber=None, publisher=_Sent(),
                               methods=METHODS, report=JsonLines(tmp_path / "report.jsonl"), clock=lambda: 0.0)
    items = _grasp_items(records["stress_ball"])
    _run(service, items[: len(items) // 3], "g")  # cut off before its final
    assert not any(m.type == "grasp_event" or not m.body.get("provisional", True) for m in service.publisher.sent)
    before = len(service.publisher.sent)
    _run(service, items, "g")  # the restarted node's grasp: its capture times start again
    after = service.publisher.sent[before:]
    assert [m.body["provisional"] for m in after if m.type == "estimate"][-1] is False
    assert [(m.type, m.body["event"]) for m in service.publisher.sent if m.type == "grasp_event"] == [
        ("grasp_event", "end")]
    (report,) = [json.loads(line) for line in (tmp_path / "report.jsonl").read_text().splitlines()]
    # The report is the new grasp's alone: its provisional estimates, not the first one's as well.
    provisional = sum(m.type == "estimate" and m.body["provisional"] for m in after)
    assert report["grasp_id"] == "g" and report["final"] is not None and report["provisional"] == provisional
    assert service.stats.grasps == 2


def test_a_grasp_started_while_another_is_open_closes_that_one(settings, calibration, records, tmp_path):
    service = EstimatorService(settings, calibration=calibration, subscriber=None, publisher=_Sent(),
                               methods=METHODS, report=JsonLines(tmp_path / "report.jsonl"), clock=lambda: 0.0)
    items = _grasp_items(records["stress_ball"])
    _run(service, items[: len(items) // 3], "a")
    _run(service, items[:1], "b")
    ends = [m.body["grasp_id"] for m in service.publisher.sent if m.type == "grasp_event"]
    finals = [m.body["grasp_id"] for m in service.publisher.sent if m.type == "estimate" and not m.body["provisional"]]
    assert ends == finals == ["a"]
    (report,) = [json.loads(line) for line in (tmp_path / "report.jsonl").read_text().splitlines()]
    assert report["grasp_id"] == "a" and report["final_by"] == "grasp_end"


def test_a_loading_end_marker_after_the_service_closed_the_loading_sends_no_second_final(settings, calibration,
                                                                                         records, tmp_path):
    # The force settled first: the service's own final went out; the robot's marker comes late.
    service = EstimatorService(settings, calibration=calibration, subscriber=None, publisher=_Sent(),
                               methods=METHODS, report=JsonLines(tmp_path / "report.jsonl"), clock=lambda: 0.0)
    record = records["stress_ball"]
    _run(service, _grasp_items(record, end=False), "g")
    assert any(m.type == "estimate" and not m.body["provisional"] for m in service.publisher.sent)
    t_end_s = float(record.force_n.t_s[-1])
    _run(service, [(t_end_s, "grasp_event", {"event": "loading_end", "object_name": None}),
                   (t_end_s, "grasp_event", {"event": "end"})], "g")
    estimates = [m for m in service.publisher.sent if m.type == "estimate"]
    assert [m.body["provisional"] for m in estimates].count(False) == 1 and not estimates[-1].body["provisional"]


def test_a_grasp_ended_twice_gets_one_final_one_end_and_one_report(settings, calibration, records, tmp_path):
    service = EstimatorService(settings, calibration=calibration, subscriber=None, publisher=_Sent(),
                               methods=METHODS, report=JsonLines(tmp_path / "report.jsonl"), clock=lambda: 0.0)
    items = _grasp_items(records["steel_ball_bearing"])
    _run(service, [*items, items[-1]], "g")  # its end comes twice (a retry, a second subscriber path)
    finals = [m.body for m in service.publisher.sent if m.type == "estimate" and not m.body["provisional"]]
    assert len(finals) == 1 and finals[0]["state"] != "insufficient_data"  # no refusal after the final
    assert [m.type for m in service.publisher.sent].count("grasp_event") == 1
    assert len((tmp_path / "report.jsonl").read_text().splitlines()) == 1 and service.stats.ignored == 1


class _FailingModel:
    """A model pinned to a grasp whose every estimate fails (a broken input, a runtime error)."""

    predictor = SimpleNamespace(variant=SimpleNamespace(image="force", markers=False, size_px=None, window_m=None))

    def estimate_stream(self, stream, *, mode):
        raise ModelError("the network gave NaN")


@pytest.fixture(scope="module")
def failing_model_run(settings, calibration, records, tmp_path_factory) -> tuple[EstimatorService, dict]:
    """A grasp through a service whose model fails (its clock, at 0 s, reads earlier than the messages
    were received); the service and its report line."""
    report = tmp_path_factory.mktemp("failing") / "report.jsonl"
    service = EstimatorService(settings, calibration=calibration, subscriber=None, publisher=_Sent(),
                               methods=METHODS, report=JsonLines(report), clock=lambda: 0.0)
    service.model = SimpleNamespace(estimator=_FailingModel(), model_id="tiny-123", model_dir="/models/tiny",
                                    mode="auto")
    _run(service, _grasp_items(records["steel_ball_bearing"]), "g")
    (line,) = report.read_text().splitlines()
    return service, json.loads(line)


def test_a_failing_model_gives_the_analytical_final_saying_why(failing_model_run):
    service, report = failing_model_run
    (final,) = [m for m in service.publisher.sent if m.type == "estimate" and not m.body["provisional"]]
    assert final.body["model"] is None  # the analytical estimate names no model
    assert "model failed: the network gave NaN" in final.body["reason"]
    assert report["model"] is None and report["model_served"] == "tiny-123"  # pinned, but it made no estimate
    assert "model failed" in report["final"]["reason"]
    # The report says which frames the final rests on: its loading frames, the last stamping the final.
    assert report["loading_frames"] > 0 and report["t_last_loading_frame_s"] == final.t_capture_s


def test_an_estimates_latency_is_never_negative(failing_model_run):
    service, _ = failing_model_run  # its clock reads earlier than the messages were received
    estimates = [m.body for m in service.publisher.sent if m.type == "estimate"]
    assert estimates and all(e["latency_s"] == 0.0 for e in estimates)


class _Silent:
    """A subscriber that heard the robot node once and now hears nothing but what is ``queued``."""

    def __init__(self, clock) -> None:
        from teleop.bus.peers import Heartbeat

        self.heartbeat = Heartbeat(clock=clock)
        self.queued: list = []

    def recv(self, timeout_s: float):
        return self.queued.pop(0) if self.queued else None


class _Beating(_Sent):
    def heartbeat_if_due(self, now_s: float) -> None:
        pass


def test_a_grasp_whose_robot_node_went_silent_is_closed_on_what_came(settings, calibration, records):
    # The node died mid-grasp: no end will come. Closed once it misses three heartbeats, its final and
    # end go out (and a model switch waiting for the grasp to end can take place).
    import dataclasses

    now = [0.0]
    subscriber = _Silent(clock=lambda: now[0])
    service = EstimatorService(settings, calibration=calibration, subscriber=subscriber, publisher=_Beating(),
                               methods=METHODS, clock=lambda: now[0])
    items = _grasp_items(records["stress_ball"], end=False)
    subscriber.heartbeat.saw("robot", interval_s=0.5, now_s=items[0][0])
    for t_s, kind, body in items:
        now[0] = t_s
        message = make_message(kind, t_capture_s=t_s, grasp_id="g", **body)
        service.handle(dataclasses.replace(message, source="robot"), received_s=t_s)
        subscriber.heartbeat.saw("robot", interval_s=0.5, now_s=t_s)
    service.step(timeout_s=0)
    assert service._grasp is not None  # still heard: the grasp stays open
    now[0] += 1.6  # three periods and a bit
    late = make_message("width", t_capture_s=items[-1][0] + 0.01, grasp_id="g", t_s=[items[-1][0] + 0.01],
                        value_m=[0.05])
    subscriber.queued.append(dataclasses.replace(late, source="robot"))
    service.step(timeout_s=0)
    assert service._grasp is not None  # a message was still queued: busy, not silent
    service.step(timeout_s=0)
    assert service._grasp is None
    sent = service.publisher.sent
    assert [m.body["event"] for m in sent if m.type == "grasp_event"] == ["end"]
    assert any(m.type == "estimate" and not m.body["provisional"] for m in sent)


def test_an_empty_model_name_is_refused_not_taken_for_the_default(settings):
    from estimator.errors import ModelError
    from estimator.service import resolve_model_dir

    for name in ("", "  "):
        with pytest.raises(ModelError, match="empty name"):
            resolve_model_dir(name, settings)
    assert resolve_model_dir("none", settings) is None and resolve_model_dir(None, settings) is not None
