"""The estimator service against hostile or broken input: a frame declaring a huge size, one sample
stamped far from the grasp's clock, and a sender repeating a bad message."""

from __future__ import annotations

import dataclasses
import logging
from typing import Any

import cv2
import numpy as np
import pytest
from support.live import METHODS, in_capture_order

from estimator.service import EstimatorService
from teleop.bus.wire import make_message
from teleop.live import JsonLines


class _Sent:
    def __init__(self) -> None:
        self.sent: list[Any] = []

    def send(self, kind: str, *, t_capture_s: float, topic: str | None = None, **body: Any) -> None:
        self.sent.append(make_message(kind, t_capture_s=t_capture_s, topic=topic, **body))


def _service(settings, calibration, tmp_path) -> EstimatorService:
    return EstimatorService(settings, calibration=calibration, subscriber=None, publisher=_Sent(),
                            methods=METHODS, report=JsonLines(tmp_path / "report.jsonl"), clock=lambda: 0.0)


def _handle(service: EstimatorService, kind: str, t_s: float, body: dict, *, seq: int = 0) -> None:
    message = dataclasses.replace(make_message(kind, t_capture_s=t_s, grasp_id="g", **body), seq=seq)
    service.handle(message, received_s=t_s)


def _final(service: EstimatorService) -> dict:
    (final,) = [m.body for m in service.publisher.sent if m.type == "estimate" and not m.body["provisional"]]
    return final


def _run_grasp(service: EstimatorService, record, *, injected: tuple[str, float, dict] | None = None) -> None:
    """The record as a grasp (start, data in capture order, end), ``injected`` right after the start."""
    start_s = float(record.force_n.t_s[0]) - 0.01
    items = [(start_s, "grasp_event", {"event": "start", "object_name": None})]
    if injected is not None:
        kind, t_s, body = injected
        items.append((t_s, kind, body))
    items += [*in_capture_order(record), (float(record.force_n.t_s[-1]), "grasp_event", {"event": "end"})]
    for t_s, kind, body in items:
        _handle(service, kind, t_s, body)


def _huge_jpeg(side_px: int) -> bytes:
    """A few hundred bytes of JPEG whose header declares ``side_px`` x ``side_px``."""
    data = bytearray(cv2.imencode(".jpg", np.zeros((16, 16, 3), np.uint8))[1].tobytes())
    sof = data.find(b"\xff\xc0")
    data[sof + 5:sof + 9] = side_px.to_bytes(2, "big") * 2
    return bytes(data)


def test_a_frame_declaring_a_huge_size_is_refused_before_decoding(settings, calibration, tmp_path, caplog,
                                                                   monkeypatch):
    sensor = next(s for s in settings.sensors if s.finger == settings.sensing.finger)
    service = _service(settings, calibration, tmp_path)
    _handle(service, "grasp_event", 1.0, {"event": "start", "object_name": None})

    def decoding(*args):
        pytest.fail("decoded a frame that declares 9000 x 9000 px (seconds of work)")

    monkeypatch.setattr(cv2, "imdecode", decoding)
    with caplog.at_level(logging.WARNING, logger="estimator.service"):
        _handle(service, "frame", 1.1, {"finger": sensor.finger, "index": 0, "encoding": "jpeg",
                                        "data": _huge_jpeg(9000)})
    assert service.stats.bad_messages == 1 and service._grasp.stream.frame_count == 0
    assert (f"frame 0 of finger {sensor.finger!r}: image declares 9000x9000 px, expected "
            f"{sensor.raw_width_px}x{sensor.raw_height_px} px: refused before decoding") in caplog.text


@pytest.fixture(scope="module")
def clean_final(settings, calibration, records, tmp_path_factory) -> dict:
    service = _service(settings, calibration, tmp_path_factory.mktemp("clean"))
    _run_grasp(service, records["stress_ball"])
    return _final(service)


@pytest.mark.parametrize("topic", ["force", "width", "frame"])
@pytest.mark.parametrize("t_s", [3.9e9, -3.9e9])
def test_one_sample_stamped_far_off_the_grasps_clock_is_refused_and_the_rest_kept(
        settings, calibration, records, tmp_path, caplog, clean_final, topic, t_s):
    record = records["stress_ball"]
    stream = next(s for s in record.frames if s.finger == settings.sensing.finger)
    body = {"force": {"t_s": [t_s], "value_n": [1.0]}, "width": {"t_s": [t_s], "value_m": [0.05]},
            "frame": {"finger": stream.finger, "index": 0, "encoding": stream.encoding, "data": stream.encoded[0]}}
    service = _service(settings, calibration, tmp_path)
    with caplog.at_level(logging.WARNING, logger="estimator.service"):
        _run_grasp(service, record, injected=(topic, t_s, body[topic]))
    assert service.stats.bad_messages == 1
    assert "from the grasp's newest capture time" in caplog.text and "the capture clock is broken" in caplog.text
    final = _final(service)
    assert clean_final["state"] != "insufficient_data"
    assert (final["state"], final["E_pa"], final["interval_pa"]) == (
        clean_final["state"], clean_final["E_pa"], clean_final["interval_pa"])


def test_a_repeated_bad_message_is_logged_once_then_at_powers_of_ten_and_each_counted(
        settings, calibration, tmp_path, caplog):
    service = _service(settings, calibration, tmp_path)
    _handle(service, "grasp_event", 1.0, {"event": "start", "object_name": None})
    _handle(service, "force", 1.1, {"t_s": [1.1], "value_n": [0.0]})
    with caplog.at_level(logging.WARNING, logger="estimator.service"):
        for seq in range(1, 13):  # the same time again: repeated
            _handle(service, "force", 1.1, {"t_s": [1.1], "value_n": [0.0]}, seq=seq)
    assert service.stats.bad_messages == 12
    lines = [r.getMessage() for r in caplog.records if r.name == "estimator.service"]
    assert len(lines) == 2, lines
    assert "not after the previous one" in lines[0] and "counted, not each logged" in lines[0]
    assert lines[1].startswith("10 bad force messages of out_of_order skipped so far, the last from ? (seq 10)")


def test_bad_messages_on_made_up_topics_log_a_bounded_number_of_lines(settings, calibration, tmp_path, caplog):
    """The log's counts go by message type and reason, never by the topic a sender chooses: a stream of
    bad messages each on its own topic (a hand-built force/<n>, as the wire now refuses, or a frame of
    a made-up finger, which it cannot) logs the first of each kind, then a count at powers of ten."""
    service = _service(settings, calibration, tmp_path)
    _handle(service, "grasp_event", 1.0, {"event": "start", "object_name": None})
    n = 1500
    with caplog.at_level(logging.WARNING, logger="estimator.service"):
        for i in range(n):  # a broken capture clock, each on a topic of its own
            force = make_message("force", t_capture_s=1e5, grasp_id="g", t_s=[1e5], value_n=[1.0])
            service.handle(dataclasses.replace(force, topic=f"force/{i:0200d}", seq=i), received_s=1.0)
        for i in range(n):  # capture times a clock gives, each from a finger the rig lacks
            frame = make_message("frame", t_capture_s=1.1 + i * 1e-4, grasp_id="g", finger=f"made-up-{i}",
                                 index=0, encoding="jpeg", data=_huge_jpeg(16))
            service.handle(dataclasses.replace(frame, seq=i), received_s=1.1)
    assert service.stats.bad_messages == 2 * n
    lines = [r.getMessage() for r in caplog.records if r.name == "estimator.service"]
    assert len(lines) == 8, lines  # each kind: the 1st, 10th, 100th and 1000th
    assert "further ones of far_from_grasp are counted" in lines[0]
    assert any(line.startswith("1000 bad frame messages of unknown_finger") for line in lines)
    assert len(service._bad) == 2
    # No made-up finger's frame is remembered by its topic: the grasp knows only the rig's topics.
    assert not any(topic.startswith("frame/made-up") for topic in service._grasp.last_t_s)
