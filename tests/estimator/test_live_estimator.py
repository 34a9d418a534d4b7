"""The live estimator: incremental estimation of a grasp (GraspStream) and the estimator service on the bus."""

from __future__ import annotations

import dataclasses
import json
import logging
import math
import re
import shutil
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import cv2
import numpy as np
import pytest
import zmq

from estimator.errors import CalibrationError, FitError, PerceptionError
from estimator.estimate import Estimate
from estimator.measure import estimate_grasp, measure_grasp
from estimator.model_slot import ModelSlot
from estimator.segment import PEAK_FRAME_WINDOW_S, segment_grasp
from estimator.service import COMMAND_TOPICS, INPUT_TOPICS, EstimatorService
from estimator.settings import estimator_settings
from estimator.stream import GraspStream, choose_estimate
from teleop.bus.pubsub import Publisher, Subscriber
from teleop.bus.wire import Message
from teleop.catalogue import load_catalogue
from teleop.errors import BusError, SettingsError
from teleop.live import JsonLines
from teleop.record import GraspRecord
from teleop.settings import CONFIG_DIR, default_settings_path, load_settings
from teleop.sim.grasp import simulate_grasp

METHODS = ("split", "hertz", "elastic", "no_tactile")


@pytest.fixture(scope="module")
def records(settings) -> dict[str, GraspRecord]:
    """A soft and a rigid simulated grasp (a few seconds)."""
    objects = {o.name: o for o in load_catalogue(CONFIG_DIR / "objects.toml")}
    return {name: simulate_grasp(objects[name], settings=settings, rng=np.random.default_rng(seed))[0]
            for name, seed in (("stress_ball", 11), ("steel_ball_bearing", 12))}


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


# --------------------------------------------------------------------------- GraspStream


@pytest.mark.parametrize(("name", "binning"), [pytest.param("stress_ball", 2, marks=pytest.mark.slow),
                                               ("steel_ball_bearing", 2), ("steel_ball_bearing", 1)])
def test_stream_fed_in_capture_order_ends_where_batch_estimation_is(settings, calibration, records, name, binning):
    # No loading-end marker: the stream sees the end in the data, batch estimation has no stop event.
    record = dataclasses.replace(records[name], events={})
    settings = settings.with_section(dataclasses.replace(estimator_settings(settings), depth_binning=binning))
    stream = GraspStream(settings=settings, calibration=calibration, methods=METHODS)
    assert stream.grid.image_shape == (250 // binning, 350 // binning) == stream.calibration.image_shape
    provisional, complete_at = 0, None
    for t, kind, body in in_capture_order(record):
        if feed(stream, kind, body, t) and complete_at is None and stream.segment():
            stream.estimate()
            provisional += 1
        if complete_at is None and stream.loading_complete():
            complete_at = t
    final = stream.estimate()
    measured = measure_grasp(record, settings=settings, calibration=calibration)
    batch = [estimate_grasp(measured, m, settings=settings) for m in METHODS]
    assert all(same(a, b) for a, b in zip(final.estimates, batch, strict=True))
    assert final.estimate is choose_estimate(final.estimates) or same(final.estimate, choose_estimate(final.estimates))
    assert provisional >= 1
    # Loading ends (force settled past the peak) well before the record does.
    segment = stream.segment()
    assert complete_at is not None and segment.t_peak_s < complete_at < record.force_n.t_s[-1]
    # The last loading frame is the peak frame, captured after the peak.
    assert segment.t_peak_s < final.t_data_s == segment.frame_t_s[-1] <= segment.t_peak_s + PEAK_FRAME_WINDOW_S
    assert final.loading_frames == segment.frame_index.size


def test_stream_segmentation_follows_every_sample_frame_and_marker(settings, calibration, records):
    # The stream keeps the loading phase between frames; any new force or width sample, or the
    # marker (here right after a frame, with no sample between), must move it as segmenting
    # everything received afresh would.
    record = records["steel_ball_bearing"]
    stop_s = record.events["grasp_done"]
    stream = GraspStream(settings=settings, calibration=calibration, methods=METHODS)
    est, finger = estimator_settings(settings), settings.sensing.finger
    checked = 0
    for t, kind, body in in_capture_order(record):
        is_frame = feed(stream, kind, body, t)
        if is_frame and t >= stop_s and stream.loading_end_s is None:
            stream.segment()
            stream.mark_loading_end(stop_s)
        received = stream.to_record()
        frames = next((f.t_s for f in received.frames if f.finger == finger), np.zeros(0))
        fresh = segment_grasp(received.force_n.t_s, received.force_n.value, received.width_m.t_s,
                              received.width_m.value, frames, contact_force_n=est.contact_force_n,
                              n_frames=est.n_frames, stopped_s=stream.loading_end_s)
        kept = stream.segment()
        for f in dataclasses.fields(fresh):
            np.testing.assert_equal(getattr(kept, f.name), getattr(fresh, f.name), err_msg=f.name)
        checked += bool(fresh)
    assert checked > 20 and stream.loading_end_s == stop_s


def test_stream_estimates_are_provisional_until_contact_and_move_with_the_data(settings, calibration, records):
    record = records["stress_ball"]
    stream = GraspStream(settings=settings, calibration=calibration, methods=METHODS)
    seen = []
    for t, kind, body in in_capture_order(record):
        if feed(stream, kind, body, t) and not stream.loading_complete():
            segment = stream.segment()
            if not segment:
                assert "no contact" in segment.reason or "too few" in segment.reason
                continue
            result = stream.estimate(segment)
            seen.append(result)
            assert result.estimate.latency_s >= 0
            if result.loading_frames:
                assert result.t_data_s == segment.frame_t_s[-1] <= t
    frames = [r.loading_frames for r in seen]
    assert frames == sorted(frames) and frames[-1] > frames[0]  # more loading frames as they arrive
    assert len({r.estimate.e_pa for r in seen if r.estimate}) > 1  # the estimate evolves


def test_stream_refuses_bad_frames_and_samples_without_keeping_them(settings, calibration, records):
    record = records["steel_ball_bearing"]
    stream = GraspStream(settings=settings, calibration=calibration, methods=METHODS, grasp_id="g1")
    good = record.stream("left").encoded[0]
    assert stream.add_frame("left", 1.0, good, "jpeg") and stream.frame_count == 1
    with pytest.raises(PerceptionError, match="does not decode"):
        stream.add_frame("left", 1.1, good[:2] + b"\x00" * 64, "jpeg")
    small = cv2.imencode(".jpg", np.zeros((48, 64, 3), np.uint8))[1].tobytes()
    with pytest.raises(PerceptionError, match="raw_bgr"):  # decodes, but is not the sensor's frame size
        stream.add_frame("left", 1.2, small, "jpeg")
    with pytest.raises(PerceptionError, match="raw after jpeg frames"):
        stream.add_frame("left", 1.25, np.zeros((480, 640, 3), np.uint8), "raw")
    with pytest.raises(PerceptionError, match="no sensor on finger 'thumb'"):
        stream.add_frame("thumb", 1.3, good, "jpeg")
    with pytest.raises(PerceptionError, match="not finite"):
        stream.add_frame("left", math.nan, good, "jpeg")
    with pytest.raises(PerceptionError, match="png after jpeg"):
        stream.add_frame("left", 1.4, b"\x89PNG" + b"\x00" * 8, "png")
    with pytest.raises(PerceptionError, match="finite"):
        stream.add_force(np.array([1.0, 2.0]), np.array([0.5, np.inf]))
    with pytest.raises(PerceptionError, match="2 timestamps but 1 values"):
        stream.add_width(np.array([1.0, 2.0]), np.array([0.05]))
    assert stream.frame_count == 1
    assert not stream.segment() and not stream.loading_complete()
    result = stream.estimate()
    assert not result.estimate and "every method refuses" in result.estimate.reason


def test_stream_checks_methods_and_calibration(settings, calibration):
    with pytest.raises(FitError, match="methods"):
        GraspStream(settings=settings, calibration=calibration, methods=("split", "magic"))
    small = dataclasses.replace(calibration, image_shape=(10, 10))
    stream = GraspStream(settings=settings, calibration=small)  # checked when first used (offline: a frame measured)
    with pytest.raises(CalibrationError, match="calibration is for"):
        stream.warm_up()  # as the service does when it starts


def test_the_settings_refuse_a_configured_method_they_do_not_know(settings, tmp_path):
    from estimator.settings import configured_methods

    assert configured_methods(settings) == estimator_settings(settings).methods
    text = default_settings_path().read_text().replace('methods = ["split", "hertz"', 'methods = ["split", "hertzz"')
    typo = tmp_path / "typo.toml"
    typo.write_text(text)
    with pytest.raises(SettingsError, match=r"typo.toml: \[estimator\] EstimatorSettings.methods\[1\] = 'hertzz'"):
        estimator_settings(load_settings(typo))


def test_stream_record_holds_what_arrived(settings, calibration, records):
    record = records["steel_ball_bearing"]
    stream = GraspStream(settings=settings, calibration=calibration, grasp_id="g7")
    for t, kind, body in in_capture_order(record):
        feed(stream, kind, body, t)
    rebuilt = stream.to_record()
    assert rebuilt.stream("right").encoded == record.stream("right").encoded
    assert np.array_equal(rebuilt.stream("left").t_s, record.stream("left").t_s)
    assert np.array_equal(rebuilt.force_n.value, record.force_n.value)
    assert rebuilt.provenance.source == "hardware" and rebuilt.label is None


def test_choose_estimate_takes_the_first_answer_in_order():
    refusal = Estimate.refuse("split", "no frames")
    bound = Estimate.at_least("hertz", 1e6, "stiff")
    ok = Estimate.ok("elastic", 2e6, 1e6, 4e6)
    assert choose_estimate([refusal, bound, ok]) is bound
    everything_refuses = choose_estimate([refusal, Estimate.refuse("hertz", "flat")])
    assert not everything_refuses and "split: no frames" in everything_refuses.reason and "hertz: flat" in everything_refuses.reason
    with pytest.raises(FitError):
        choose_estimate([])


# --------------------------------------------------------------------------- the service on the bus


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
            commands=None if commands is None else Subscriber(commands, COMMAND_TOPICS),
        )
        self.estimates = Subscriber(self.service.publisher.endpoint, ("estimate", "grasp_event", "model_event"))
        self.model_events: list[Message] = []  # model_event messages, as collect() met them
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self.service.run, args=(self.stop,), kwargs={"poll_s": 0.01})
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


@pytest.fixture
def rig(settings, calibration, tmp_path) -> Iterator[Rig]:
    rig = Rig(settings, calibration, report=tmp_path / "estimator.jsonl")
    yield rig
    rig.close()


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


def test_service_streams_provisional_estimates_per_frame_and_one_final_per_grasp(rig, settings, calibration,
                                                                                  records, tmp_path):
    counts = {}
    for grasp_id, name in (("g-soft", "stress_ball"), ("g-rigid", "steel_ball_bearing")):
        rig.send_grasp(records[name], grasp_id)
        got = rig.collect(grasp_id)
        estimates = [m for m in got if m.type == "estimate"]
        provisional = [m for m in estimates if m.body["provisional"]]
        final, count = expected_final(settings, calibration, records[name])
        assert len(provisional) == count >= 1
        counts[grasp_id] = count
        assert [m.body["provisional"] for m in estimates] == [True] * count + [False]  # the final one is last
        last = estimates[-1].body
        assert (last["method"], last["state"], last["E_pa"]) == (final.method, final.state, final.e_pa)
        assert got[-1].type == "grasp_event" and got[-1].body["event"] == "end"
        # Stamped with the newest loading frame used: the final one's is the last loading frame.
        answered = [m.t_capture_s for m in estimates if m.body["state"] != "insufficient_data"]
        assert answered == sorted(answered) and all(m.body["latency_s"] >= 0 for m in estimates)
    reports = [json.loads(line) for line in (tmp_path / "estimator.jsonl").read_text().splitlines()]
    assert {r["grasp_id"]: r["provisional"] for r in reports} == counts
    assert all(r["final"]["state"] in ("ok", "lower_bound", "upper_bound", "insufficient_data") for r in reports)
    assert rig.service.stats.final == 2 and rig.service.stats.bad_messages == 0


def test_service_logs_bad_messages_and_carries_on(settings, calibration, records, caplog):
    context = zmq.Context.instance()
    rogue = context.socket(zmq.PUB)
    port = rogue.bind_to_random_port("tcp://127.0.0.1")
    rig = Rig(settings, calibration, extra_endpoint=f"tcp://127.0.0.1:{port}")
    try:
        time.sleep(0.3)  # the service's subscription reaches the rogue publisher
        with caplog.at_level(logging.WARNING):
            rogue.send_multipart([b"frame/left", b"\xc1 not msgpack", b"{}"])
            record = records["steel_ball_bearing"]
            rig.robot.send("grasp_event", t_capture_s=0.0, event="start", grasp_id="g1", object_name=None)
            jpeg = record.stream("left").encoded[0]
            rig.robot.send("frame", t_capture_s=0.5, grasp_id="g1", finger="left", index=0, encoding="jpeg",
                           data=jpeg[:2] + b"\x00" * 100)  # passes the wire's magic check, does not decode
            rig.robot.send("frame", t_capture_s=0.5, grasp_id="g1", finger="thumb", index=0, encoding="jpeg",
                           data=jpeg)
            rig.robot.send("force", t_capture_s=0.5, grasp_id="no-such-grasp", t_s=[0.5], value_n=[1.0])
            rig.send_grasp(record, "g1", start=False)
            got = rig.collect("g1")
        assert sum(m.type == "estimate" and not m.body["provisional"] for m in got) == 1
        assert rig.service.subscriber.stats.refused["corrupt"] == 1
        assert rig.service.stats.bad_messages == 2 and rig.service.stats.ignored >= 1
        text = caplog.text
        assert "refused a message" in text and "does not decode" in text and "no sensor on finger 'thumb'" in text
    finally:
        rig.close()
        rogue.close(linger=0)


# --------------------------------------------------------------------------- model reload


def write_tiny_model(model_dir: Path, log10_e: float, *, data: dict | None = None, note: str = "",
                     broken: bool = False) -> float:
    """A model that ignores its input and puts all its mass in the bin of ``log10_e``; returns the
    median it answers (the bin's centre, Pa). ``data`` goes into the metadata's ``data`` (e.g. another
    ``depth_binning``), ``note`` into its ``training`` (metadata that differs, for a model's id);
    ``broken``: it answers NaN (it loads, and fails its first inference)."""
    onnx = pytest.importorskip("onnx")
    from onnx import TensorProto, helper

    from estimator.inference.distribution import BIN_DECADES, EDGES_LOG10, N_BINS, bin_index
    from estimator.inference.infer import MODEL_FORMAT, MODEL_VERSION, OUTPUT_NAME, current_scales

    shape = [3, 1, 16, 22]
    index = int(bin_index(log10_e))
    logits = np.full(N_BINS, -60.0, np.float32)
    logits[index] = 0.0
    if broken:
        logits[0] = np.nan
    nodes = [helper.make_node("ReduceMean", ["frames"], ["mean"], axes=[2, 3, 4], keepdims=0),
             helper.make_node("Mul", ["mean", "zero"], ["nothing"]),  # (batch, frames) of zeros
             helper.make_node("ReduceMean", ["nothing"], ["column"], axes=[1], keepdims=1),
             helper.make_node("Add", ["column", "logits"], [OUTPUT_NAME])]
    graph = helper.make_graph(
        nodes, "tiny", [helper.make_tensor_value_info("frames", TensorProto.FLOAT, ["batch", *shape])],
        [helper.make_tensor_value_info(OUTPUT_NAME, TensorProto.FLOAT, ["batch", N_BINS])],
        [helper.make_tensor("zero", TensorProto.FLOAT, [], [0.0]),
         helper.make_tensor("logits", TensorProto.FLOAT, [N_BINS], logits.tolist())])
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 13)])
    model.ir_version = 8
    model_dir.mkdir(parents=True, exist_ok=True)
    onnx.save(model, model_dir / "model.onnx")
    (model_dir / "metadata.json").write_text(json.dumps({
        "format": MODEL_FORMAT, "version": MODEL_VERSION,
        "variant": {"name": "depth", "n_frames": 3, "size_px": [16, 22]},
        "inputs": {"frames": [None, *shape]}, "output": OUTPUT_NAME, "scales": current_scales(),
        "calibration": {"temperature": 1.0, "p_rigids": [0.5], "level": 0.9, "force_band_edges_n": [],
                        "interval_scales": [1.645], "soft_pa": 5e3},
        "data": {"depth_binning": estimator_settings(load_settings()).depth_binning, **(data or {})},
        "training": {"note": note},
    }))
    return float(10.0 ** (EDGES_LOG10[index] + BIN_DECADES / 2))


def test_model_id_names_the_folder_and_the_contents_of_its_files(tmp_path):
    from estimator.errors import ModelError
    from estimator.inference.infer import CompliancePredictor, model_id

    folder = tmp_path / "soft-v1"
    write_tiny_model(folder, 5.55)
    ident = model_id(folder)
    assert re.fullmatch(r"soft-v1-[0-9a-f]{8}", ident) and model_id(folder) == ident  # stable
    assert CompliancePredictor(folder).model_id == ident  # the id of the bytes it loaded
    copy = tmp_path / "elsewhere" / "soft-v1"
    shutil.copytree(folder, copy)
    assert model_id(copy) == ident  # a copy is the same model
    (folder / "notes.txt").write_text("not part of the model")
    assert model_id(folder) == ident
    metadata = (folder / "metadata.json").read_text()
    (folder / "metadata.json").write_text(metadata.replace('"temperature": 1.0', '"temperature": 1.5'))
    assert model_id(folder) not in (ident, model_id(copy))  # the metadata changed
    (folder / "metadata.json").write_text(metadata)
    assert model_id(folder) == ident
    write_tiny_model(folder, 4.25)  # the same metadata, another network
    assert model_id(folder) != ident
    long = tmp_path / ("a-very-long-model-folder-name-" * 4)
    write_tiny_model(long, 5.55)
    assert len(model_id(long)) == 64 and model_id(long).startswith("a-very-long")
    (copy / "model.onnx").unlink()
    with pytest.raises(ModelError, match=r"soft-v1 is not a model folder: it has no model\.onnx"):
        model_id(copy)
    with pytest.raises(ModelError, match="does not exist"):
        model_id(tmp_path / "nowhere")


@pytest.mark.slow
def test_model_reload_swaps_between_grasps_without_dropping_one(settings, calibration, records, tmp_path):
    model_dir = tmp_path / "model"
    first_e = write_tiny_model(model_dir, 5.55)
    # Only the reload asked for below, not the files' change (check_interval_s): one reload.
    slot = ModelSlot(model_dir, settings=settings, calibration=calibration, mode="model", check_interval_s=3600)
    first_id = slot.model_id
    rig = Rig(settings, calibration, model=slot)
    try:
        record = records["stress_ball"]
        messages = in_capture_order(record)
        half = slice(0, len(messages) // 2)
        rig.send_grasp(record, "g-a", end=False, part=half)
        deadline = time.monotonic() + 20
        while not rig.service.stats.provisional and time.monotonic() < deadline:
            time.sleep(0.05)
        assert rig.service.stats.provisional > 0  # grasp A is loading now
        second_e = write_tiny_model(model_dir, 4.25)  # the files change mid-grasp...
        slot.request_reload()  # ...and a reload is asked for
        rig.send_grasp(record, "g-a", start=False, part=slice(len(messages) // 2, None))
        got_a = rig.collect("g-a")
        rig.send_grasp(record, "g-b")
        got_b = rig.collect("g-b")
    finally:
        rig.close()
    final_a = [m.body for m in got_a if m.type == "estimate" and not m.body["provisional"]]
    final_b = [m.body for m in got_b if m.type == "estimate" and not m.body["provisional"]]
    _, provisional = expected_final(settings, calibration, record)
    assert sum(m.type == "estimate" and m.body["provisional"] for m in got_a) == provisional  # none dropped
    assert len(final_a) == len(final_b) == 1
    assert final_a[0]["method"] == "cnn" and final_a[0]["E_pa"] == pytest.approx(first_e, rel=1e-5)
    assert final_b[0]["E_pa"] == pytest.approx(second_e, rel=1e-5)
    assert final_a[0]["model"] == first_id and final_b[0]["model"] == slot.model_id != first_id
    assert slot.loads == 2 and rig.service.stats.reloads == 1


def settled(slot: ModelSlot, *, idle: bool = True):
    """Let the candidate the slot is loading be checked, then poll: what the slot did."""
    assert slot.wait(30.0)
    return slot.poll(idle=idle)


def test_model_slot_switches_to_new_files_once_they_stay_the_same_and_keeps_a_good_model_over_a_bad_one(
        settings, calibration, tmp_path, caplog):
    from estimator.inference.infer import model_id

    served, new = tmp_path / "served", tmp_path / "new"
    write_tiny_model(served, 5.55)
    write_tiny_model(new, 4.75, note="fine-tuned")  # another network and another metadata
    now = [0.0]
    slot = ModelSlot(served, settings=settings, calibration=calibration, check_interval_s=1.0,
                     clock=lambda: now[0])
    first, first_id = slot.estimator, slot.model_id
    assert first_id == model_id(served) and slot.loads == 1
    now[0] = 1.0
    assert slot.poll(idle=True) is None and not slot.busy  # nothing changed
    # The new model is copied over the served one, the metadata first: a mismatched pair for a while.
    shutil.copy(new / "metadata.json", served / "metadata.json")
    now[0] = 1.5
    assert slot.poll(idle=True) is None  # not looked at before check_interval_s
    now[0] = 2.0
    assert slot.poll(idle=True) is None and not slot.busy  # changed: wait for it to stay the same
    shutil.copy(new / "model.onnx", served / "model.onnx")
    now[0] = 3.0
    assert slot.poll(idle=True) is None and not slot.busy  # changed again: the half-copied pair was never loaded
    now[0] = 4.0
    with caplog.at_level(logging.INFO, logger="estimator.service.model"):
        assert slot.poll(idle=False) is None and slot.busy  # the same twice: loading while a grasp goes on
        assert slot.wait(30.0) and slot.switch_pending
        assert slot.poll(idle=False) is None and slot.estimator is first  # never swapped mid-grasp
        event = slot.poll(idle=True)
    assert event.event == "loaded" and event.request is None and event.model == model_id(served) == slot.model_id
    assert event.model.startswith("served-") and event.model[-8:] == model_id(new)[-8:]  # new's files, in served/
    assert event.path == str(served) and slot.estimator is not first and slot.loads == 2 and slot.failures == 0
    assert f"model {slot.model_id} ({served}) serves from the next grasp on, in place of {first_id}" in caplog.text
    good, good_id = slot.estimator, slot.model_id

    # Broken files that stay broken: tried once, refused, the good model stays.
    (served / "metadata.json").write_text("{ not json")
    for t in (5.0, 6.0):
        now[0] = t
        assert slot.poll(idle=True) is None
    with caplog.at_level(logging.WARNING, logger="estimator.service.model"):
        event = settled(slot)
    assert event.event == "refused" and event.model == good_id and "not a readable model metadata" in event.reason
    assert slot.estimator is good and slot.failures == 1
    assert f"model {served} refused, still serving {good_id}" in caplog.text
    for t in (7.0, 8.0, 9.0):
        now[0] = t
        assert slot.poll(idle=True) is None and not slot.busy  # not tried again until they change
    assert slot.failures == 1

    # Asked for by path: a folder that is not there, and a model that does not fit the settings.
    slot.request_load(tmp_path / "nowhere", "r1")
    assert slot.poll(idle=True) is None
    event = settled(slot)
    assert (event.event, event.request, event.model) == ("refused", "r1", good_id)
    assert "does not exist" in event.reason
    other_binning = tmp_path / "other-binning"
    write_tiny_model(other_binning, 4.25, data={"depth_binning": 7})
    slot.request_load(other_binning / "model.onnx", "r2")  # its model.onnx names the folder
    slot.poll(idle=True)
    event = settled(slot)
    assert event.event == "refused" and event.path == str(other_binning) and "depth_binning" in event.reason
    assert slot.estimator is good and slot.failures == 3
    write_tiny_model(tmp_path / "broken", 4.25, broken=True)
    slot.request_load(tmp_path / "broken", "r-nan")
    slot.poll(idle=True)
    event = settled(slot)
    assert event.event == "refused" and "fails on the reference grasp" in event.reason and "not finite" in event.reason
    slot.request_load(new, "r3")
    slot.poll(idle=True)
    event = settled(slot)
    assert (event.event, event.request, event.model, event.path) == ("loaded", "r3", model_id(new), str(new))
    assert slot.model_dir == new and slot.estimator is not good


def test_model_slot_without_a_model_serves_the_first_one_it_is_given(settings, calibration, tmp_path):
    write_tiny_model(tmp_path / "m", 5.55)
    slot = ModelSlot(None, settings=settings, calibration=calibration)
    assert slot.estimator is None and slot.model_id is None
    slot.request_reload()  # nothing to reload: said, nothing done
    assert slot.poll(idle=True) is None and not slot.busy
    slot.request_load(tmp_path / "m", "r1")
    slot.poll(idle=True)
    event = settled(slot)
    assert event.event == "loaded" and slot.model_id == event.model and "was no model" in event.reason


def test_service_switches_models_on_load_model_between_grasps_and_every_estimate_names_its_model(
        settings, calibration, records, tmp_path):
    from estimator.inference.infer import model_id

    first_e, second_e = write_tiny_model(tmp_path / "a", 5.55), write_tiny_model(tmp_path / "b", 4.25)
    slot = ModelSlot(tmp_path / "a", settings=settings, calibration=calibration, mode="model", check_interval_s=3600)
    operator = Publisher("tcp://127.0.0.1:*", lossless=True, source="operator")
    rig = Rig(settings, calibration, model=slot, commands=operator.endpoint, report=tmp_path / "estimator.jsonl")
    try:
        operator.wait_for_subscriber("load_model", timeout_s=5.0)
        record = records["steel_ball_bearing"]
        half = len(in_capture_order(record)) // 2
        rig.send_grasp(record, "g-a", end=False, part=slice(0, half))
        operator.send("load_model", t_capture_s=0.0, path=str(tmp_path / "b"), request="r1")
        deadline = time.monotonic() + 30
        while not slot.switch_pending and time.monotonic() < deadline:
            time.sleep(0.02)
        assert slot.switch_pending and slot.model_id == model_id(tmp_path / "a")  # checked; g-a still open
        rig.send_grasp(record, "g-a", start=False, part=slice(half, None))
        got_a = rig.collect("g-a")
        assert not rig.model_events  # nothing said before g-a's end went out
        loaded = rig.model_event("r1")
        rig.send_grasp(record, "g-b")
        got_b = rig.collect("g-b")
    finally:
        rig.close()
        operator.close()
    ids = model_id(tmp_path / "a"), model_id(tmp_path / "b")
    assert loaded.body == {"event": "loaded", "request": "r1", "model": ids[1], "path": str(tmp_path / "b"),
                           "reason": f"switched; was {ids[0]}"}
    for got, ident, e_pa in ((got_a, ids[0], first_e), (got_b, ids[1], second_e)):
        estimates = [m.body for m in got if m.type == "estimate"]
        final = estimates[-1]
        assert not final["provisional"] and final["method"] == "cnn" and final["E_pa"] == pytest.approx(e_pa, rel=1e-5)
        assert final["model"] == ident
        assert all(e["model"] is None for e in estimates[:-1])  # provisional: analytical, no model made them
    reports = [json.loads(line) for line in (tmp_path / "estimator.jsonl").read_text().splitlines()]
    assert [(r["grasp_id"], r["model"], r["model_path"]) for r in reports] == [
        ("g-a", ids[0], str(tmp_path / "a")), ("g-b", ids[1], str(tmp_path / "b"))]
    assert rig.service.stats.reloads == 1 and rig.service.stats.load_requests == 1


def test_service_refuses_a_model_that_does_not_check_out_and_keeps_its_own(settings, calibration, records,
                                                                           tmp_path, caplog):
    write_tiny_model(tmp_path / "a", 5.55)
    (tmp_path / "empty").mkdir()
    slot = ModelSlot(tmp_path / "a", settings=settings, calibration=calibration, mode="model", check_interval_s=3600)
    operator = Publisher("tcp://127.0.0.1:*", lossless=True, source="operator")
    rig = Rig(settings, calibration, model=slot, commands=operator.endpoint)
    try:
        operator.wait_for_subscriber("load_model", timeout_s=5.0)
        with caplog.at_level(logging.WARNING, logger="estimator.service.model"):
            answers = {}
            for request, path in (("r-missing", tmp_path / "nowhere"), ("r-empty", tmp_path / "empty")):
                operator.send("load_model", t_capture_s=0.0, path=str(path), request=request)
                answers[request] = rig.model_event(request).body
            operator.send("load_model", t_capture_s=0.0, path=str(tmp_path / "nowhere"), request="r-missing")
            again = rig.model_event("r-missing").body  # a repeat is answered again, not loaded again
        rig.send_grasp(records["steel_ball_bearing"], "g-c")
        got = rig.collect("g-c")
    finally:
        rig.close()
        operator.close()
    assert {a["event"] for a in answers.values()} == {"refused"}
    assert {a["model"] for a in answers.values()} == {slot.model_id}
    assert "does not exist" in answers["r-missing"]["reason"] and again == answers["r-missing"]
    assert "no model.onnx and no metadata.json" in answers["r-empty"]["reason"]
    assert "refused, still serving" in caplog.text and "does not exist" in caplog.text
    final = [m.body for m in got if m.type == "estimate" and not m.body["provisional"]]
    assert final[-1]["model"] == slot.model_id and slot.model_dir == tmp_path / "a"
    stats = rig.service.stats
    assert (stats.load_requests, stats.model_refusals, stats.reloads) == (2, 2, 0)


@pytest.mark.slow
def test_estimator_reload_switches_a_running_service_and_says_why_it_refuses(settings, calibration, records,
                                                                              tmp_path, capsys):
    import estimator.cli
    from estimator.inference.infer import model_id
    from teleop.system.demo import free_ports

    write_tiny_model(tmp_path / "a", 5.55)
    second_e = write_tiny_model(tmp_path / "b", 4.25)
    command, nobody = (f"tcp://127.0.0.1:{port}" for port in free_ports(2))
    slot = ModelSlot(tmp_path / "a", settings=settings, calibration=calibration, mode="model", check_interval_s=3600)
    rig = Rig(settings, calibration, model=slot, commands=command)

    def reload(model: Path, *options: str) -> tuple[int, str, str]:
        code = estimator.cli.main(["reload", "--model", str(model), "--control", command, "--estimate-pub",
                                   rig.service.publisher.endpoint, *options])
        out, err = capsys.readouterr()
        return code, out, err

    try:
        code, out, err = reload(tmp_path / "b", "--json")
        assert code == 0, err
        answer = json.loads(out.splitlines()[-1])
        assert answer["event"] == "loaded" and answer["model"] == model_id(tmp_path / "b") == slot.model_id
        assert f"serves {answer['model']}" in err
        code, out, err = reload(tmp_path / "nowhere", "--timeout-s", "20")
        assert code == 1 and "does not exist" in err and f"keeps {slot.model_id}" in err and out == ""
        rig.send_grasp(records["steel_ball_bearing"], "g-after")
        final = [m.body for m in rig.collect("g-after") if m.type == "estimate"][-1]
    finally:
        rig.close()
    assert final["model"] == slot.model_id and final["E_pa"] == pytest.approx(second_e, rel=1e-5)
    # No service there: it says so, without a traceback.
    code = estimator.cli.main(["reload", "--model", str(tmp_path / "b"), "--control", command, "--estimate-pub",
                               nobody, "--timeout-s", "1"])
    err = capsys.readouterr().err
    assert code == 2 and "no answer to load_model" in err and nobody in err and "Traceback" not in err
    deadline = time.monotonic() + 5.0
    while True:  # the last reload's socket lets go of the port a moment after it closed
        try:
            console = Publisher(command, lossless=True, source="operator")
            break
        except BusError:
            if time.monotonic() > deadline:
                raise
            time.sleep(0.05)
    with console:  # another reload holds the control endpoint
        code = estimator.cli.main(["reload", "--model", str(tmp_path / "b"), "--control", command, "--estimate-pub",
                                   nobody, "--timeout-s", "1"])
    err = capsys.readouterr().err
    assert code == 2 and f"cannot send on the control endpoint {command}" in err and "another" in err


def test_estimator_serve_names_the_missing_file_of_a_folder_that_is_not_a_model(tmp_path, capsys):
    import estimator.cli

    (tmp_path / "half").mkdir()
    (tmp_path / "half" / "model.onnx").write_bytes(b"")
    code = estimator.cli.main(["serve", "--model", str(tmp_path / "half"), "--duration-s", "0.1"])
    err = capsys.readouterr().err
    assert code == 2 and f"{tmp_path / 'half'} is not a model folder: it has no metadata.json" in err
    assert "Traceback" not in err


# --------------------------------------------------------------------------- the loading end marker


def until_loading_end(record: GraspRecord) -> tuple[list[tuple[float, str, dict]], float, tuple[float, float]]:
    """What the robot node publishes up to a grasp's loading-end marker: the data captured up to
    the stop, in capture order; the stop time; and the width read at the stop, ``(t_s, m)``: the
    record's next read, which the simulated gripper hands out then with its recorded stamp."""
    stop_s = record.events["grasp_done"]
    after = int(np.flatnonzero(record.width_m.t_s > stop_s)[0])
    stop_read = (float(record.width_m.t_s[after]), float(record.width_m.value[after]))
    return [item for item in in_capture_order(record) if item[0] <= stop_s], stop_s, stop_read


def after_stop(record: GraspRecord, stop_s: float, stop_read: tuple[float, float]) -> list[tuple[float, str, dict]]:
    """What the node publishes after the marker: the rest of the record but the stop's read, already out."""
    return [(t, kind, body) for t, kind, body in in_capture_order(record)
            if t > stop_s and not (kind == "width" and t == stop_read[0])]


def feed_to_peak_frame(stream: GraspStream, record: GraspRecord, stop_s: float,
                       stop_read: tuple[float, float]) -> float:
    """After the marker, what the node publishes next until the loading is complete: up to the first
    frame captured after the force peak. Returns that frame's capture time."""
    for t, kind, body in after_stop(record, stop_s, stop_read):
        if feed(stream, kind, body, t) and stream.loading_complete():
            return t
    raise AssertionError("the loading never completed")


def test_loading_end_marker_ends_loading_at_the_peak_frame_and_the_model_input_comes_from_the_cache(
        settings, calibration, records, monkeypatch):
    import estimator.stream
    from estimator.inference.hybrid import HybridEstimator
    from estimator.inference.infer import CompliancePredictor, default_model_dir
    from estimator.inference.sampling import sample_grasp, sample_stream

    items, stop_s, stop_read = until_loading_end(records["stress_ball"])
    stream = GraspStream(settings=settings, calibration=calibration, methods=METHODS)
    for t, kind, body in items:
        if feed(stream, kind, body, t) and stream.segment():
            stream.estimate()  # as the provisional estimates do: every frame's depth is cached
            stream.reduce_depths((64, 88))  # and, with a model, reduced to its input size
    assert not stream.loading_complete()  # the force has not settled past its peak yet
    stream.add_width(np.array([stop_read[0]]), np.array([stop_read[1]]))
    stream.mark_loading_end(stop_s)
    assert stream.loading_end_s == stop_s
    assert not stream.loading_complete()  # no frame shows the peak state yet
    peak_frame_s = feed_to_peak_frame(stream, records["stress_ball"], stop_s, stop_read)
    segment = stream.segment()
    # The peak frame came a frame period or less after the stop, with no force sample after it yet.
    assert segment and segment.t_peak_s < segment.frame_t_s[-1] == peak_frame_s < stop_s + 1 / 25
    assert stream.newest_force_s < peak_frame_s
    assert stream.last_loading_frame_s(segment) == peak_frame_s
    with pytest.raises(PerceptionError, match="finite"):
        stream.mark_loading_end(math.nan)

    record = stream.to_record()
    stream.measure_frames(segment)  # as the final estimate finds them: every frame since contact measured
    with monkeypatch.context() as patched:  # the model's input from the cache: no frame is measured again
        patched.setattr(estimator.stream, "measure_frame", lambda *a, **k: pytest.fail("a frame measured again"))
        from_cache = {n: sample_stream(stream, n_frames=n, size_px=size) for n, size in ((3, (64, 88)), (5, None))}
    for n_frames, size_px in ((3, (64, 88)), (5, None)):
        cached = from_cache[n_frames]
        measured = sample_grasp(record, settings=settings, calibration=calibration, n_frames=n_frames,
                                size_px=size_px)
        assert cached and measured
        np.testing.assert_array_equal(cached.depth_m, measured.depth_m)
        np.testing.assert_array_equal(cached.force_n, measured.force_n)
        np.testing.assert_array_equal(cached.width_m, measured.width_m)
        assert cached.measurements.calibration_smoothing_px == measured.measurements.calibration_smoothing_px == 0.0
        assert all(same(a, b) for a, b in zip(cached.estimates, measured.estimates, strict=True))
    # The shipped model answers the same from the cache as from the grasp as received.
    model = HybridEstimator(CompliancePredictor(default_model_dir()), settings=settings, calibration=calibration)
    assert same(model.estimate_stream(stream, mode="auto"), model.estimate(record, mode="auto"))
    # Before contact there is nothing to sample, and the reason says why.
    empty = GraspStream(settings=settings, calibration=calibration, methods=METHODS)
    assert not sample_stream(empty, n_frames=3, size_px=None) and sample_stream(empty, n_frames=3, size_px=None).reason


def test_a_model_answers_from_the_stream_as_from_the_record_of_it(settings, calibration, records):
    # The service's model never measures through a record: a grasp that can be sampled, one whose
    # frames were lost from the contact on (auto: force and width only), and a marker variant's
    # other finger all come from the stream, as from the record of what it received.
    from estimator.inference.hybrid import HybridEstimator
    from estimator.inference.infer import CompliancePredictor, default_model_dir
    from estimator.inference.sampling import sample_grasp, sample_stream

    record = records["stress_ball"]
    t_contact = measure_grasp(record, settings=settings, tactile=False).segment.t_contact_s
    full = GraspStream(settings=settings, calibration=calibration, methods=METHODS)
    lost = GraspStream(settings=settings, calibration=calibration, methods=METHODS)
    for t, kind, body in in_capture_order(record):
        feed(full, kind, body, t)
        if not (kind == "frame" and body["finger"] == settings.sensing.finger and t >= t_contact):
            feed(lost, kind, body, t)
    model = HybridEstimator(CompliancePredictor(default_model_dir()), settings=settings, calibration=calibration)
    for stream in (full, lost):
        for mode in ("auto", "model"):
            assert same(model.estimate_stream(stream, mode=mode), model.estimate(stream.to_record(), mode=mode))
    said = model.estimate_stream(lost, mode="auto")
    assert said and "no tactile sample" in said.reason and "no_tactile" in said.reason
    assert not model.estimate_stream(lost, mode="model")
    options = dict(n_frames=3, size_px=(32, 44), markers=True, rgb=True)
    from_stream = sample_stream(full, **options)
    from_record = sample_grasp(full.to_record(), settings=settings, calibration=calibration, **options)
    for name in ("depth_m", "depth_markers_m", "rgb_diff", "rgb_diff_markers", "force_n", "width_m"):
        np.testing.assert_array_equal(getattr(from_stream, name), getattr(from_record, name), err_msg=name)
    assert from_stream.depth_markers_m.shape == (3, 32, 44)


def test_service_publishes_the_final_estimate_on_the_loading_end_marker(rig, settings, calibration, records,
                                                                         tmp_path):
    record = records["stress_ball"]
    items, stop_s, stop_read = until_loading_end(record)
    rig.robot.send("grasp_event", t_capture_s=0.0, event="start", grasp_id="g-mark", object_name=None)
    for t, kind, body in items:
        rig.robot.send(kind, t_capture_s=t, grasp_id="g-mark", **body)
    rig.robot.send("width", t_capture_s=stop_read[0], grasp_id="g-mark", t_s=[stop_read[0]], value_m=[stop_read[1]])
    rig.robot.send("grasp_event", t_capture_s=stop_s, event="loading_end", grasp_id="g-mark", object_name=None)
    for t, kind, body in after_stop(record, stop_s, stop_read):  # the peak frame, the hold, the release
        rig.robot.send(kind, t_capture_s=t, grasp_id="g-mark", **body)
    rig.robot.send("grasp_event", t_capture_s=record.force_n.t_s[-1], event="end", grasp_id="g-mark")
    got = rig.collect("g-mark")

    # The same data, fed up to the marker, give the final estimate and the provisional count.
    stream = GraspStream(settings=settings, calibration=calibration, methods=METHODS)
    provisional = 0
    for t, kind, body in items:
        provisional += bool(feed(stream, kind, body, t) and stream.segment())
    stream.add_width(np.array([stop_read[0]]), np.array([stop_read[1]]))
    stream.mark_loading_end(stop_s)
    peak_frame_s = feed_to_peak_frame(stream, record, stop_s, stop_read)
    segment = stream.segment()
    expected = stream.estimate(segment).estimate
    estimates = [m for m in got if m.type == "estimate"]
    assert [m.body["provisional"] for m in estimates] == [True] * provisional + [False]
    final = estimates[-1]
    assert (final.body["method"], final.body["state"], final.body["E_pa"]) == (expected.method, expected.state,
                                                                               expected.e_pa)
    assert final.t_capture_s == segment.frame_t_s[-1] == peak_frame_s  # the last loading frame
    report = json.loads((tmp_path / "estimator.jsonl").read_text().splitlines()[-1])
    assert report["final_by"] == "loading_end" and report["t_loading_end_s"] == stop_s
    assert report["t_last_loading_frame_s"] == final.t_capture_s and report["final_compute_s"] > 0
    assert rig.service.stats.bad_messages == 0 and rig.service.stats.final == 1


def test_a_stop_before_the_force_shows_contact_waits_for_the_load_cell(settings, calibration, records):
    record = records["steel_ball_bearing"]
    items, stop_s, _ = until_loading_end(record)
    stream = GraspStream(settings=settings, calibration=calibration, methods=METHODS)
    for t, kind, body in items:  # the load cell lags: its readings up to the stop stay below contact
        if kind != "force" or body["value_n"][0] < 0.5 * estimator_settings(settings).contact_force_n:
            feed(stream, kind, body, t)
    stream.mark_loading_end(stop_s)
    assert not stream.segment() and not stream.loading_complete()  # not an air grasp yet
    later = [(t, body) for t, kind, body in in_capture_order(record) if kind == "force" and t > stop_s]
    feed(stream, "force", later[0][1], later[0][0])
    assert stream.segment()  # the next reading shows the contact: a grasp, not an air grasp
    # An air grasp: force readings run on past the stop without reaching contact.
    air = GraspStream(settings=settings, calibration=calibration, methods=METHODS)
    air.add_force(np.array([stop_s - 0.5, stop_s]), np.array([0.0, 0.1]))
    air.mark_loading_end(stop_s)
    assert not air.loading_complete()
    air.add_force(np.array([stop_s + PEAK_FRAME_WINDOW_S]), np.array([0.1]))
    assert air.loading_complete() and not air.segment()


def test_a_follow_grasp_streams_provisional_estimates_until_its_end(rig, settings, calibration, tmp_path):
    # An operator drives the fingers (the robot says "following"): no loading-end marker, pauses and
    # back-offs; every frame from contact on gives a provisional estimate, the final one comes at the end.
    objects = {o.name: o for o in load_catalogue(CONFIG_DIR / "objects.toml")}
    record = simulate_grasp(objects["rubber_duck"], settings=settings, rng=np.random.default_rng(3),
                            operator="sim")[0]
    stream = GraspStream(settings=settings, calibration=calibration, methods=METHODS)
    stream.mark_follow()
    provisional = 0
    for t, kind, body in in_capture_order(record):
        is_frame = feed(stream, kind, body, t)
        assert not stream.loading_complete()
        provisional += bool(is_frame and body["finger"] == "left" and stream.segment())
    final = stream.estimate().estimate
    assert stream.to_record().provenance.style == "operator"

    rig.robot.send("robot_state", t_capture_s=0.0, mode="following", grasp_id="g-follow", target_width_m=0.08,
                   enable=True)
    rig.send_grasp(record, "g-follow")
    estimates = [m for m in rig.collect("g-follow") if m.type == "estimate"]
    assert [m.body["provisional"] for m in estimates] == [True] * provisional + [False]
    assert provisional > 5
    last = estimates[-1].body
    assert (last["method"], last["state"], last["E_pa"]) == (final.method, final.state, final.e_pa)
    report = json.loads((tmp_path / "estimator.jsonl").read_text().splitlines()[-1])
    assert report["final_by"] == "grasp_end"
