"""Helpers of the live estimator's tests: a grasp record as the robot node publishes it, and an
estimator service in a thread between a robot-side publisher and an estimate subscriber."""

from __future__ import annotations

import threading
import time
from pathlib import Path

import numpy as np

from estimator.estimate import Estimate
from estimator.model_slot import ModelSlot
from estimator.service import COMMAND_TOPICS, INPUT_TOPICS, EstimatorService
from estimator.stream import GraspStream
from teleop.bus.pubsub import Publisher, Subscriber
from teleop.bus.wire import Message
from teleop.live import JsonLines
from teleop.record import GraspRecord

METHODS = ("series", "hertz", "elastic", "no_tactile")


def in_capture_order(record: GraspRecord) -> list[tuple[float, str, dict]]:
    """The record's data as the robot node publishes it: one message per sample or frame,
    ordered by capture time (a frame before samples of the same time)."""
    items = [(float(t), 1, "force", {"t_s": [t], "value_n": [v]})
             for t, v in zip(record.force_n.t_s, record.force_n.value, strict=True)]
    items += [(float(t), 1, "width", {"t_s": [t], "value_m": [v]})
              for t, v in zip(record.width_m.t_s, record.width_m.value, strict=True)]
    for stream in record.frames:
        items += [(float(t), 0, "frame", {"finger": stream.finger, "index": i, "encoding": stream.encoding,
                                           "data": stream.encoded[i]}) for i, t in enumerate(stream.t_s)]
    items.sort(key=lambda item: item[:2])
    return [(t, kind, body) for t, _, kind, body in items]


def feed(stream: GraspStream, kind: str, body: dict, t_s: float) -> bool:
    """One message into a GraspStream; True when it is a frame of the estimator's finger."""
    if kind == "force":
        stream.add_force(np.asarray(body["t_s"]), np.asarray(body["value_n"]))
    elif kind == "width":
        stream.add_width(np.asarray(body["t_s"]), np.asarray(body["value_m"]))
    else:
        return stream.add_frame(body["finger"], t_s, body["data"], body["encoding"])
    return False


def same(a: Estimate, b: Estimate) -> bool:
    return (a.method, a.state, a.e_pa, a.interval_pa, a.reason) == (b.method, b.state, b.e_pa, b.interval_pa, b.reason)


class Rig:
    """An estimator service in a thread between a robot-side publisher and an estimate subscriber."""

    def __init__(self, settings, calibration, *, model: ModelSlot | None = None, report: Path | None = None,
                 extra_endpoint: str | None = None, commands: str | None = None):
        self.robot = Publisher("tcp://127.0.0.1:*", lossless=True, source="robot")
        endpoints = [self.robot.endpoint] + ([extra_endpoint] if extra_endpoint else [])
        self.service = EstimatorService(
            settings, calibration=calibration, methods=METHODS, model=model, report=JsonLines(report),
            subscriber=Subscriber(endpoints, INPUT_TOPICS),
            publisher=Publisher("tcp://127.0.0.1:*", lossless=False, source="estimator", high_water_mark=10_000),
            commands=None if commands is None else Subscriber(commands, COMMAND_TOPICS), poll_s=0.01,
        )
        self.estimates = Subscriber(self.service.publisher.endpoint, ("estimate", "grasp_event", "model_event"))
        self.model_events: list[Message] = []  # model_event messages, as collect() met them
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self.service.run, args=(self.stop,))
        self.thread.start()
        self.robot.wait_for_subscriber("frame", "force", "width", "grasp_event", timeout_s=5.0)
        deadline = time.monotonic() + 5.0
        while "estimator" not in self.estimates.heartbeat.peers() and time.monotonic() < deadline:
            self.estimates.recv(timeout_s=0.05)

    def send_grasp(self, record: GraspRecord, grasp_id: str, *, start: bool = True, end: bool = True,
                   part: slice = slice(None)) -> None:
        if start:
            self.robot.send("grasp_event", t_capture_s=0.0, event="start", grasp_id=grasp_id, object_name="secret")
        for t, kind, body in in_capture_order(record)[part]:
            self.robot.send(kind, t_capture_s=t, grasp_id=grasp_id, **body)
        if end:
            self.robot.send("grasp_event", t_capture_s=record.force_n.t_s[-1], event="end", grasp_id=grasp_id)

    def collect(self, grasp_id: str, timeout_s: float = 30.0) -> list:
        """Messages about ``grasp_id`` up to its forwarded end."""
        got = []
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            message = self.estimates.recv(timeout_s=0.1)
            if message is not None and message.type == "model_event":
                self.model_events.append(message)
            if message is None or message.body.get("grasp_id") != grasp_id:
                continue
            got.append(message)
            if message.type == "grasp_event":
                return got
        raise AssertionError(f"no end of {grasp_id} within {timeout_s} s; got {len(got)} messages")

    def model_event(self, request: str | None, timeout_s: float = 30.0) -> Message:
        """The next model_event answering ``request`` (one collect() met first, else from the bus)."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            found = next((m for m in self.model_events if m.body["request"] == request), None)
            if found is not None:
                self.model_events.remove(found)
                return found
            message = self.estimates.recv(timeout_s=0.1)
            if message is not None and message.type == "model_event":
                self.model_events.append(message)
        raise AssertionError(f"no model_event for request {request!r} within {timeout_s} s")

    def close(self) -> None:
        self.stop.set()
        self.thread.join(timeout=10)
        for sock in (self.robot, self.service.subscriber, self.service.publisher, self.estimates,
                     self.service.commands):
            if sock is not None:
                sock.close()


def expected_final(settings, calibration, record: GraspRecord) -> tuple[Estimate, int]:
    """The final estimate and the provisional count a service must produce for ``record``."""
    stream = GraspStream(settings=settings, calibration=calibration, methods=METHODS)
    provisional = 0
    for t, kind, body in in_capture_order(record):
        is_frame = feed(stream, kind, body, t)
        segment = stream.segment()
        if stream.loading_complete(segment):
            return stream.estimate(segment).estimate, provisional
        provisional += bool(is_frame and segment and body["finger"] == "left")
    return stream.estimate().estimate, provisional
