"""The live estimator: incremental estimation of a grasp (GraspStream) and the estimator service on the bus."""

from __future__ import annotations

import dataclasses
import json
import logging
import math

import cv2
import numpy as np
import pytest
from support.bus import raw_publisher, wait_subscribed
from support.live import METHODS, Rig, expected_final, feed, in_capture_order, same

from estimator.errors import CalibrationError, FitError, PerceptionError
from estimator.estimate import Estimate, choose_estimate
from estimator.measure import estimate_grasp, measure_grasp
from estimator.segment import PEAK_FRAME_WINDOW_S, segment_grasp
from estimator.settings import estimator_settings
from estimator.stream import GraspStream
from teleop.catalogue import load_catalogue
from teleop.errors import SettingsError
from teleop.record import GraspRecord
from teleop.settings import CONFIG_DIR, default_settings_path, load_settings
from teleop.sim.grasp import simulate_grasp

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
    with pytest.raises(PerceptionError, match="declares 64x48 px, expected 640x480 px"):  # not the sensor's size
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
        GraspStream(settings=settings, calibration=calibration, methods=("series", "magic"))
    small = dataclasses.replace(calibration, image_shape=(10, 10))
    stream = GraspStream(settings=settings, calibration=small)  # checked when first used (offline: a frame measured)
    with pytest.raises(CalibrationError, match="calibration is for"):
        stream.warm_up()  # as the service does when it starts


def test_the_settings_refuse_a_configured_method_they_do_not_know(settings, tmp_path):
    from estimator.settings import configured_methods

    assert configured_methods(settings) == estimator_settings(settings).methods
    text = default_settings_path().read_text().replace('methods = ["series", "hertz"', 'methods = ["series", "hertzz"')
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
    refusal = Estimate.refuse("series", "no frames")
    bound = Estimate.at_least("hertz", 1e6, "stiff")
    ok = Estimate.ok("elastic", 2e6, 1e6, 4e6)
    assert choose_estimate([refusal, bound, ok]) is bound
    everything_refuses = choose_estimate([refusal, Estimate.refuse("hertz", "flat")])
    assert not everything_refuses and "series: no frames" in everything_refuses.reason and "hertz: flat" in everything_refuses.reason
    with pytest.raises(FitError):
        choose_estimate([])


# --------------------------------------------------------------------------- the service on the bus


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
    rogue, rogue_endpoint = raw_publisher()
    rig = Rig(settings, calibration, extra_endpoint=rogue_endpoint)
    try:
        wait_subscribed(rogue, "frame")  # the service's subscription reached the rogue publisher
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


def test_a_grasp_that_sent_no_data_gets_a_refusal_and_the_next_is_estimated(settings, calibration, records,
                                                                            tmp_path):
    # Start then end with nothing between (an operator's g then s): its final had no data time, its
    # publication failed, and with --report the service then refused every later grasp.
    rig = Rig(settings, calibration, report=tmp_path / "estimator.jsonl")
    try:
        rig.robot.send("grasp_event", t_capture_s=1.0, event="start", grasp_id="empty", object_name=None)
        rig.robot.send("grasp_event", t_capture_s=1.2, event="end", grasp_id="empty")
        got = rig.collect("empty")
        (final,) = [m for m in got if m.type == "estimate" and not m.body["provisional"]]
        assert final.body["state"] == "insufficient_data" and final.t_capture_s == 1.2
        rig.send_grasp(records["steel_ball_bearing"], "next")
        assert any(m.type == "estimate" and not m.body["provisional"] for m in rig.collect("next"))
        assert rig.service.stats.bad_messages == 0
    finally:
        rig.close()


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
    import estimator.frame_perception
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
        patched.setattr(estimator.frame_perception, "measure_frame", lambda *a, **k: pytest.fail("a frame measured again"))
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


def test_a_rigid_object_seen_by_force_and_width_alone_is_said_not_rendered(settings, calibration, records):
    # With no tactile frame (a dead camera, or one too slow for the loading), force and width read the
    # steel ball as soft, ok (the gel's own compliance): auto says the reading in a refusal.
    from estimator.inference.hybrid import HybridEstimator
    from estimator.inference.infer import CompliancePredictor, default_model_dir
    from estimator.measurements import estimate_measurements

    stream = GraspStream(settings=settings, calibration=calibration, methods=METHODS)
    for t, kind, body in in_capture_order(records["steel_ball_bearing"]):
        if kind != "frame":
            feed(stream, kind, body, t)
    alone = estimate_measurements(stream.measurements(tactile=False), "no_tactile")
    assert alone.state == "ok" and alone.e_pa < 1e7  # what it would have rendered: a rigid ball, soft
    model = HybridEstimator(CompliancePredictor(default_model_dir()), settings=settings, calibration=calibration)
    said = model.estimate_stream(stream, mode="auto")
    assert not said and f"reads {alone.e_pa:.3g} Pa" in said.reason


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
    said = model.estimate_stream(lost, mode="auto")  # force and width alone: said, not rendered
    assert not said and "no tactile sample" in said.reason and "no_tactile" in said.reason and "reads" in said.reason
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


def force_peak_s(settings, calibration, record: GraspRecord) -> float:
    """The force peak (s) of the record's segmentation."""
    segment = GraspStream.from_record(record, settings=settings, calibration=calibration, methods=METHODS).segment()
    assert segment and np.isfinite(segment.t_peak_s)
    return float(segment.t_peak_s)


def fed_except(settings, calibration, record: GraspRecord, held_back) -> GraspStream:
    """A stream fed the record in capture order but the messages ``held_back(t, kind)`` names."""
    stream = GraspStream(settings=settings, calibration=calibration, methods=METHODS)
    for t, kind, body in in_capture_order(record):
        if not held_back(t, kind):
            feed(stream, kind, body, t)
    return stream


def first_frame_after(stream: GraspStream, record: GraspRecord, t_s: float) -> tuple[float, dict]:
    """The record's first frame of the stream's finger captured after ``t_s``: its time and message body."""
    return next((t, body) for t, kind, body in in_capture_order(record)
                if kind == "frame" and body["finger"] == stream.finger and t > t_s)


def test_without_a_marker_loading_waits_for_a_width_sample_after_the_peak(settings, calibration, records):
    record = dataclasses.replace(records["steel_ball_bearing"], events={})
    peak = force_peak_s(settings, calibration, record)
    stream = fed_except(settings, calibration, record, lambda t, kind: kind == "width" and t >= peak)
    assert stream.segment() and stream.newest_force_s > peak + 0.5  # settled long since, frames came
    assert not stream.loading_complete()  # no width after the peak frame yet
    last = max(t for t, kind, _ in in_capture_order(record) if kind == "width")
    stream.add_width(np.array([last]), record.width_m.value[record.width_m.t_s == last])
    assert stream.loading_complete()


def test_without_a_marker_loading_waits_for_a_frame_after_the_peak(settings, calibration, records):
    record = dataclasses.replace(records["steel_ball_bearing"], events={})
    peak = force_peak_s(settings, calibration, record)
    stream = fed_except(settings, calibration, record, lambda t, kind: kind == "frame" and t > peak)
    assert stream.segment() and stream.newest_force_s > peak + 0.5  # settled long since, widths came
    assert not stream.loading_complete()  # the peak frame is still to come
    t, body = first_frame_after(stream, record, peak)
    feed(stream, "frame", body, t)
    assert stream.loading_complete()


def test_after_the_marker_a_frame_stamped_at_the_peak_is_not_the_peak_frame(settings, calibration, records):
    record = records["steel_ball_bearing"]
    peak = force_peak_s(settings, calibration, record)
    stream = fed_except(settings, calibration, record, lambda t, kind: t > peak or (kind == "frame" and t == peak))
    stream.mark_loading_end(min(record.events["grasp_done"], peak))
    assert stream.segment().t_peak_s == peak
    t, body = first_frame_after(stream, record, peak)
    feed(stream, "frame", body, peak)  # a frame captured at the very time of the peak
    assert stream.newest_force_s < peak + PEAK_FRAME_WINDOW_S
    assert not stream.loading_complete()  # the peak frame is the first captured after the peak
    feed(stream, "frame", body, t)
    assert stream.loading_complete()


def test_a_stream_for_another_finger_keeps_the_loading_end_marker(settings, calibration, records):
    # A marker-finger model measures such a twin: the same grasp, its loading over at the same marker.
    record = records["steel_ball_bearing"]
    items, stop_s, _ = until_loading_end(record)
    stream = GraspStream(settings=settings, calibration=calibration, methods=METHODS)
    for t, kind, body in items:
        feed(stream, kind, body, t)
    stream.mark_loading_end(stop_s)
    other = next(s.finger for s in stream.sensors if s.finger != stream.finger)
    twin = stream.for_finger(other, calibration=None)
    assert twin.loading_end_s == stop_s and twin.to_record().events == stream.to_record().events


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
