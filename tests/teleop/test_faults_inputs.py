"""Fault injection, bad input: every class of bad input into a RUNNING estimator service (and
renderer) over loopback is refused with a clear, counted log line, and the service still
estimates a good grasp afterwards. Decoders' own property tests live in
tests/teleop/bus/test_wire.py; here the entry points of the live estimator get random junk too.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Iterator

import msgpack
import numpy as np
import pytest
from hypothesis import HealthCheck, given
from hypothesis import settings as hyp_settings
from hypothesis import strategies as st
from support.bus import admit_a_bound_without_its_bound, raw_publisher, wait_subscribed
from support.live import in_capture_order

from estimator.errors import EstimatorError
from estimator.service import MAX_CLOCK_JUMP_S, EstimatorService
from estimator.stream import GraspStream
from haptics.devices.sim import SimulatedDisplay
from haptics.renderer import HapticRenderer
from haptics.service import RendererService
from haptics.settings import display_settings
from teleop.bus.pubsub import Publisher, Subscriber
from teleop.bus.wire import encode, make_message
from teleop.catalogue import load_catalogue
from teleop.record import GraspRecord
from teleop.settings import CONFIG_DIR
from teleop.sim.grasp import simulate_grasp

METHODS = ("series", "hertz", "elastic", "no_tactile")


@pytest.fixture(scope="module")
def record(settings) -> GraspRecord:
    obj = {o.name: o for o in load_catalogue(CONFIG_DIR / "objects.toml")}["steel_ball_bearing"]
    return simulate_grasp(obj, settings=settings, rng=np.random.default_rng(12))[0]


class LiveEstimator:
    """A running estimator service (own thread) fed by a robot publisher and a rogue raw socket,
    with operator commands, and a running renderer service fed by its estimates."""

    def __init__(self, settings, calibration):
        self.robot = Publisher("tcp://127.0.0.1:*", lossless=True, source="robot")
        self.operator = Publisher("tcp://127.0.0.1:*", lossless=True, source="operator")
        self.rogue, rogue_endpoint = raw_publisher()
        self.service = EstimatorService(
            settings, calibration=calibration, methods=METHODS,
            subscriber=Subscriber([self.robot.endpoint, rogue_endpoint],
                                  ("frame", "force", "width", "grasp_event")),
            publisher=Publisher("tcp://127.0.0.1:*", lossless=False, source="estimator", high_water_mark=10_000),
            commands=Subscriber(self.operator.endpoint, ("command",)), poll_s=0.01,
        )
        self.display = SimulatedDisplay()
        self.renderer = RendererService(
            HapticRenderer(self.display, display_settings(settings)),
            subscriber=Subscriber(self.service.publisher.endpoint, ("estimate", "grasp_event"), conflate=True),
            tick_s=0.005)
        self.estimates = Subscriber(self.service.publisher.endpoint, ("estimate", "grasp_event"))
        self.stop = threading.Event()
        self.threads = [threading.Thread(target=self.service.run, args=(self.stop,)),
                        threading.Thread(target=self.renderer.run, args=(self.stop,))]
        for thread in self.threads:
            thread.start()
        self.robot.wait_for_subscriber("frame", "force", "width", "grasp_event", timeout_s=5.0)
        self.operator.wait_for_subscriber("command", timeout_s=5.0)
        deadline = time.monotonic() + 5.0
        while "estimator" not in self.estimates.heartbeat.peers() and time.monotonic() < deadline:
            self.estimates.recv(timeout_s=0.05)
        # The renderer's subscription reached the estimator's publisher too: it heard a heartbeat (the
        # subscriber's last topic, sorted after "estimate" and "grasp_event").
        self.until(lambda: self.renderer.subscriber.heartbeat.last_seen_s("estimator") is not None,
                   "the renderer to hear the estimator", timeout_s=5.0)
        wait_subscribed(self.rogue, "frame", "force", "width", "grasp_event")  # the rogue socket is heard

    def until(self, done, what: str, timeout_s: float = 10.0) -> None:
        deadline = time.monotonic() + timeout_s
        while not done():
            assert time.monotonic() < deadline, f"timed out waiting for {what}"
            time.sleep(0.01)

    def collect(self, grasp_id: str, timeout_s: float = 30.0) -> list:
        got = []
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            message = self.estimates.recv(timeout_s=0.1)
            if message is not None and message.body["grasp_id"] == grasp_id:
                got.append(message)
                if message.type == "grasp_event":
                    return got
        raise AssertionError(f"no end of {grasp_id} within {timeout_s} s")

    def close(self) -> None:
        self.stop.set()
        for thread in self.threads:
            thread.join(timeout=10)
        for sock in (self.robot, self.operator, self.service.subscriber, self.service.commands,
                     self.service.publisher, self.renderer.subscriber, self.estimates):
            sock.close()
        self.rogue.close(linger=0)


@pytest.fixture(scope="module")
def live(settings, calibration) -> Iterator[LiveEstimator]:
    rig = LiveEstimator(settings, calibration)
    yield rig
    rig.close()


# --------------------------------------------------------------------------- raw wire faults


def force_frames(**changes) -> list[bytes]:
    """A valid ``force`` message of grasp ``g-bad`` as raw frames, with header/array changes."""
    message = make_message("force", t_capture_s=1.0, grasp_id="g-bad", t_s=[1.0], value_n=[2.0])
    frames = [bytes(f) for f in encode(message)]
    header = msgpack.unpackb(frames[1])
    header.update(changes.pop("header", {}))
    frames[1] = msgpack.packb(header)
    for index, array in changes.pop("buffers", {}).items():
        header["buffers"][index - 3][1:] = [array.dtype.str, list(array.shape)]
        frames[1] = msgpack.packb(header)
        frames[index] = array.tobytes()
    return frames


RAW_FAULTS = {
    # name: (frames, reason the subscriber counts)
    "corrupt msgpack header": ([b"force", b"\xc1\xc1 not msgpack", b"\x80"], "corrupt"),
    "oversized msgpack body": ([b"force", force_frames()[1], msgpack.packb({"x": "y" * 70_000})], "oversize"),
    "too few frames": ([b"force", b"\x80"], "frame_count"),
    "unknown schema version": (force_frames(header={"v": 99}), "unknown_version"),
    "unknown message type": (force_frames(header={"type": "teleport"}), "unknown_type"),
    "NaN samples": (force_frames(buffers={4: np.array([np.nan])}), "not_finite"),
    "infinite sample time": (force_frames(buffers={3: np.array([np.inf])}), "not_finite"),
    "empty arrays": (force_frames(buffers={3: np.zeros(0), 4: np.zeros(0)}), "mistyped_field"),
    "wrong dtype": (force_frames(buffers={4: np.array([2], dtype=np.int32)}), "mistyped_field"),
    "wrong shape": (force_frames(buffers={3: np.ones((1, 1)), 4: np.ones((1, 1))}), "mistyped_field"),
    "buffer size lies": (force_frames()[:3] + [b"\x00" * 8, b"\x00" * 3], "bad_buffer"),
    "NaN capture time": (force_frames(header={"t_capture_s": float("nan")}), "not_finite"),
}


def test_every_raw_wire_fault_is_refused_counted_and_logged(live, caplog):
    refused_before = dict(live.service.subscriber.stats.refused)
    with caplog.at_level(logging.WARNING, logger="teleop.bus.pubsub"):
        for frames, _ in RAW_FAULTS.values():
            live.rogue.send_multipart(frames)
        expected: dict[str, int] = {}
        for _, reason in RAW_FAULTS.values():
            expected[reason] = expected.get(reason, 0) + 1
        live.until(lambda: all(live.service.subscriber.stats.refused[r] - refused_before.get(r, 0) == n
                               for r, n in expected.items()), "the refusals")
    # Each reason said once (with its sender and what to do), then counted: a flood cannot flood the log.
    assert caplog.text.count("refused a message") == len(expected)
    wire = live.service.wire_stats()["subscriber"]  # as the service's --json summary gives them
    assert all(wire["refused"][r] - refused_before.get(r, 0) == n for r, n in expected.items())
    for detail in ("not valid msgpack", "header version 99", "holds NaN or infinity", "body frame has"):
        assert detail in caplog.text


# --------------------------------------------------------------------------- valid wire, bad content


def test_bad_content_is_refused_and_a_good_grasp_is_still_estimated(live, record, caplog):
    jpeg = record.stream("left").encoded[0]
    t0 = float(record.force_n.t_s[0])
    bad = [  # (what, kind, t_capture_s, body, log fragment)
        ("corrupted JPEG bytes", "frame", t0, dict(finger="left", index=0, encoding="jpeg",
                                                   data=jpeg[:2] + b"\x00" * 200), "does not decode"),
        ("truncated JPEG", "frame", t0, dict(finger="left", index=0, encoding="jpeg", data=jpeg[:120]),
         "does not decode"),
        ("raw frame of the wrong size", "frame", t0, dict(finger="left", index=0, encoding="raw",
                                                          data=np.zeros((8, 8, 3), np.uint8)), "left"),
        ("unknown finger", "frame", t0, dict(finger="thumb", index=0, encoding="jpeg", data=jpeg), "thumb"),
        ("first force sample", "force", t0, dict(t_s=[t0], value_n=[0.0]), None),  # good: sets the clock
        ("duplicate timestamp", "force", t0, dict(t_s=[t0], value_n=[0.1]), "out of order or repeated"),
        ("timestamps going backwards", "force", t0, dict(t_s=[t0 - 1.0], value_n=[0.1]), "out of order"),
        ("out-of-order batch", "force", t0, dict(t_s=[t0 + 0.02, t0 + 0.01], value_n=[0.1, 0.1]), "out of order"),
        ("clock jump", "force", t0, dict(t_s=[t0 + 10 * MAX_CLOCK_JUMP_S], value_n=[0.1]), "clock is broken"),
    ]
    grasp_id = "g-content"
    before = live.service.stats.bad_messages
    with caplog.at_level(logging.WARNING, logger="estimator.service"):
        live.robot.send("grasp_event", t_capture_s=t0, event="start", grasp_id=grasp_id, object_name=None)
        for _, kind, t, body, _ in bad:
            live.robot.send(kind, t_capture_s=t, grasp_id=grasp_id, **body)
        n_bad = sum(fragment is not None for *_, fragment in bad)
        live.until(lambda: live.service.stats.bad_messages - before == n_bad, "the bad messages")
        # The good grasp from after the first accepted force sample on: it is still estimated.
        for t, kind, body in in_capture_order(record):
            if not (kind == "force" and t <= t0):
                live.robot.send(kind, t_capture_s=t, grasp_id=grasp_id, **body)
        live.robot.send("grasp_event", t_capture_s=float(record.force_n.t_s[-1]), event="end", grasp_id=grasp_id)
        got = live.collect(grasp_id)
    for what, *_, fragment in bad:
        if fragment is not None:
            assert fragment in caplog.text, what
    assert live.service.stats.bad_messages - before == n_bad  # nothing of the good grasp was refused
    finals = [m.body for m in got if m.type == "estimate" and not m.body["provisional"]]
    assert len(finals) == 1 and finals[0]["state"] != "insufficient_data" and finals[0]["E_pa"] > 0
    # ... and the renderer shows it.
    live.until(lambda: any(f.grasp_id == grasp_id for f in live.renderer.stats.finals), "the renderer's final")


def test_renderer_refuses_an_unrenderable_estimate_and_carries_on(live, caplog, monkeypatch):
    before = live.renderer.stats.bad_messages
    admit_a_bound_without_its_bound(monkeypatch)
    with caplog.at_level(logging.WARNING):
        live.service.publisher.send("estimate", t_capture_s=time.monotonic(), grasp_id="g-r", method="series",
                                    E_pa=None, interval_pa=[None, None], state="lower_bound", reason="injected",
                                    provisional=True, latency_s=0.0)
        live.until(lambda: live.renderer.stats.bad_messages == before + 1, "the renderer's refusal")
        live.service.publisher.send("estimate", t_capture_s=time.monotonic(), grasp_id="g-r", method="series",
                                    E_pa=3e4, interval_pa=[2e4, 4e4], state="ok", reason="injected",
                                    provisional=False, latency_s=0.0)
        live.until(lambda: any(f.grasp_id == "g-r" for f in live.renderer.stats.finals), "the good estimate")
    assert "a bound may come from interval_pa" in caplog.text


def test_reload_model_command_reaches_the_estimator_service(live, caplog):
    before = live.service.stats.reload_requests
    with caplog.at_level(logging.WARNING, logger="estimator.service"):
        live.operator.send("command", t_capture_s=time.monotonic(), action="reload_model", params={})
        live.until(lambda: live.service.stats.reload_requests == before + 1, "the reload request")
    assert "runs without a model" in caplog.text  # this service has none: said, not crashed


def test_reload_model_command_asks_the_model_slot_to_reload(settings, calibration):
    class Slot:  # stands in for ModelSlot: its reload itself is tested in tests/estimator
        model_dir, requested = "tiny", 0

        def request_reload(self):
            self.requested += 1

    with Publisher("tcp://127.0.0.1:*", lossless=False) as estimates:
        service = EstimatorService(settings, calibration=calibration, methods=METHODS, subscriber=None,
                                   publisher=estimates, model=Slot())
        message = make_message("command", t_capture_s=0.0, action="reload_model", params={})
        service.handle_command(message)
        service.handle_command(make_message("command", t_capture_s=0.0, action="stop", params={}))
    assert service.model.requested == 1 and service.stats.reload_requests == 1


# --------------------------------------------------------------------------- random junk into the stream


@hyp_settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.one_of(st.binary(max_size=400),
                      st.binary(max_size=300).map(lambda b: b"\xff\xd8\xff" + b),
                      st.binary(max_size=300).map(lambda b: b"\x89PNG\r\n\x1a\n" + b)),
       encoding=st.sampled_from(["jpeg", "png", "raw", "gif"]),
       t_s=st.floats(allow_nan=True, allow_infinity=True))
def test_stream_add_frame_refuses_junk_with_an_estimator_error(settings, calibration, data, encoding, t_s):
    stream = GraspStream(settings=settings, calibration=calibration, methods=METHODS, grasp_id="junk")
    array = np.frombuffer(data, np.uint8)
    try:
        stream.add_frame("left", t_s, array, encoding)
    except EstimatorError as exc:
        assert "junk" in str(exc)
    else:
        pytest.fail(f"{len(data)} junk bytes as {encoding} were kept")


@hyp_settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(t_s=st.lists(st.floats(allow_nan=True, allow_infinity=True), max_size=5),
       value=st.lists(st.floats(allow_nan=True, allow_infinity=True), max_size=5))
def test_stream_add_force_refuses_junk_and_keeps_nothing_of_it(settings, calibration, t_s, value):
    stream = GraspStream(settings=settings, calibration=calibration, methods=METHODS, grasp_id="junk")
    t, v = np.array(t_s, dtype=float), np.array(value, dtype=float)
    try:
        stream.add_force(t, v)
    except EstimatorError as exc:
        assert "junk" in str(exc)
        assert len(stream.to_record().force_n.t_s) == 0
    else:
        assert len(t) == len(v) and np.isfinite(t).all() and np.isfinite(v).all()
