"""Export: the grasps of a recorded session as grasp records equal to the streams that were sent."""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path

import numpy as np
import pytest
from mcap.writer import Writer

from teleop.bus import Publisher
from teleop.catalogue import default_catalogue_path, load_catalogue
from teleop.errors import SessionLogError
from teleop.record import read_record
from teleop.session import SessionRecorder, export_session, session_grasps
from teleop.settings import CONFIG_DIR, load_settings
from teleop.sim.grasp import simulate_grasp


def _sent_grasp(sent, grasp_id):
    """The source streams of one grasp, straight from the messages as sent."""
    start = next(
        i for i, m in enumerate(sent) if m.type == "grasp_event" and m.body["grasp_id"] == grasp_id
    )
    end = next(
        i
        for i, m in enumerate(sent)
        if m.type == "grasp_event" and m.body["event"] == "end" and m.body["grasp_id"] == grasp_id
    )
    inside = sent[start + 1 : end]
    frames = {}
    for finger in ("left", "right"):
        messages = [m for m in inside if m.type == "frame" and m.body["finger"] == finger]
        frames[finger] = (
            [m.t_capture_s for m in messages],
            [m.body["data"].tobytes() for m in messages],
        )
    force = [m for m in inside if m.type == "force"]
    width = [m for m in inside if m.type == "width"]
    return {
        "start": sent[start],
        "end": sent[end],
        "frames": frames,
        "force": (
            np.concatenate([m.body["t_s"] for m in force]),
            np.concatenate([m.body["value_n"] for m in force]),
        ),
        "width": (
            np.concatenate([m.body["t_s"] for m in width]),
            np.concatenate([m.body["value_m"] for m in width]),
        ),
    }


@pytest.fixture(scope="module")
def exported(recorded, tmp_path_factory):
    out = tmp_path_factory.mktemp("export")
    return out, export_session(recorded.path, out)


def test_each_complete_grasp_becomes_a_record_and_the_unfinished_one_a_reason(exported):
    _, results = exported
    assert [(r.grasp_id, bool(r)) for r in results] == [("g0", True), ("g1", True), ("g2", False)]
    assert "before the grasp's end" in results[2].reason and results[2].path is None


@pytest.mark.parametrize("grasp_id", ["g0", "g1"])
def test_records_equal_the_source_streams(recorded, exported, grasp_id):
    _, results = exported
    result = next(r for r in results if r.grasp_id == grasp_id)
    record = read_record(result.path)
    source = _sent_grasp(recorded.sent, grasp_id)
    for finger, encoding in (("left", "jpeg"), ("right", "png")):
        stream = record.stream(finger)
        t_s, data = source["frames"][finger]
        assert stream.encoding == encoding
        assert np.array_equal(stream.t_s, t_s)
        assert stream.encoded == tuple(data)  # the camera's bytes, untouched
        assert stream.shape == (24, 32, 3)
    assert np.array_equal(record.force_n.t_s, source["force"][0])
    assert np.array_equal(record.force_n.value, source["force"][1].astype(np.float64))
    assert np.array_equal(record.width_m.t_s, source["width"][0])
    assert np.array_equal(record.width_m.value, source["width"][1])
    assert record.events == {
        "grasp_start": source["start"].t_capture_s,
        "grasp_end": source["end"].t_capture_s,
    }
    assert record.provenance.source == "simulated"
    assert record.provenance.extra["session"] == str(recorded.path.resolve())
    assert record.provenance.extra["grasp_id"] == grasp_id


def test_the_named_object_is_labelled_from_the_stored_catalogue(exported, helpers):
    _, results = exported
    obj = next(o for o in load_catalogue() if o.name == helpers.object_name)
    labelled = read_record(results[0].path).label
    assert (labelled.object_name, labelled.modulus_pa, labelled.material) == (
        obj.name,
        obj.modulus_pa,
        obj.material,
    )
    assert read_record(results[1].path).label is None  # hardware-like: no object named


def test_sensors_come_from_the_stored_settings_with_the_stored_calibration(recorded, exported):
    out, results = exported
    record = read_record(results[0].path)
    assert [s.finger for s in record.sensors] == [s.finger for s in recorded.settings.sensors]
    left, original = record.sensor("left"), recorded.settings.sensor("left")
    assert (
        left.warp_corners_px == original.warp_corners_px
        and left.gel_modulus_pa == original.gel_modulus_pa
    )
    copy = out / "calibration" / "left" / "left_cal.npz"
    assert left.calibration == str(copy.resolve())
    with open(original.calibration, "rb") as f:
        assert copy.read_bytes() == f.read()
    assert record.sensor("right") == recorded.settings.sensor("right")


def test_only_a_stray_end_event_is_warned_about(recorded, caplog):
    assert len(list(session_grasps(recorded.path))) == 3  # every end was announced twice
    assert "never started" not in caplog.text


def test_explicit_source_and_catalogue_override_the_log(recorded, object_table):
    grasps = list(session_grasps(recorded.path, source="hardware", catalogue=object_table))
    record = grasps[0].record
    assert record.provenance.source == "hardware"
    assert (
        record.label.object_name == "stress_ball" and record.label.modulus_pa is None
    )  # not in that table


def test_a_log_without_settings_needs_them_given(tmp_path):
    path = tmp_path / "bare.mcap"
    with path.open("wb") as f:
        writer = Writer(f)
        writer.start()
        writer.finish()
    with pytest.raises(SessionLogError, match="no settings.json"):
        list(session_grasps(path))


def _record_one_grasp(path, frames_for, helpers):
    """Record a one-grasp session in process (open, poll, close); frames by ``frames_for(pub)``."""
    with (
        Publisher("tcp://127.0.0.1:*", lossless=True, source="robot") as pub,
        SessionRecorder(path, [pub.endpoint]) as recorder,
    ):
        pub.wait_for_subscriber("")
        sent = [pub.send("grasp_event", t_capture_s=1.0, event="start", grasp_id="a")]
        sent += frames_for(pub)
        sent.append(pub.send("force", t_capture_s=1.1, t_s=[1.05, 1.1], value_n=[1.0, 2.0]))
        sent.append(pub.send("width", t_capture_s=1.1, t_s=[1.0], value_m=[0.04]))
        sent.append(pub.send("grasp_event", t_capture_s=2.0, event="end", grasp_id="a"))
        deadline = time.monotonic() + 5.0
        while recorder.stats.messages < len(sent) and time.monotonic() < deadline:
            recorder.poll(0.1)
    assert recorder.stats.messages == len(sent)
    return sent


def test_raw_frames_are_exported_as_lossless_png(tmp_path, helpers):
    rng = np.random.default_rng(5)
    images = [rng.integers(0, 256, (20, 30, 3), dtype=np.uint8) for _ in range(3)]
    path = tmp_path / "raw.mcap"
    _record_one_grasp(
        path,
        lambda pub: [
            pub.send(
                "frame",
                t_capture_s=1.0 + i / 30,
                finger="left",
                index=i,
                encoding="raw",
                data=image,
            )
            for i, image in enumerate(images)
        ],
        helpers,
    )
    (grasp,) = export_session(path, tmp_path / "out")
    stream = read_record(grasp.path).stream("left")
    assert stream.encoding == "png"
    assert np.array_equal(stream.frames(), np.stack(images))
    assert np.array_equal(stream.t_s, [1.0 + i / 30 for i in range(3)])


@pytest.mark.parametrize(
    ("frames_for", "reason"),
    [
        (
            lambda pub: [
                pub.send(
                    "frame",
                    t_capture_s=1.0,
                    finger="left",
                    index=0,
                    encoding="raw",
                    data=np.zeros((4, 4, 3), np.uint16),
                )
            ],
            "16-bit raw frames",
        ),
        (lambda pub: [], "no tactile frames"),
        (
            lambda pub: [
                pub.send(
                    "frame",
                    t_capture_s=1.0,
                    finger="thumb",
                    index=0,
                    encoding="raw",
                    data=np.zeros((4, 4, 3), np.uint8),
                )
            ],
            "finger 'thumb'",
        ),
    ],
)
def test_grasps_that_cannot_be_records_say_why(tmp_path, helpers, frames_for, reason):
    path = tmp_path / "bad.mcap"
    _record_one_grasp(path, frames_for, helpers)
    (grasp,) = list(session_grasps(path))
    assert not grasp and reason in grasp.reason


def _publish_record(pub, record, grasp_id):
    """Stream a grasp record onto the bus as the robot node would, in capture-time order."""
    items = [
        (
            record.events["command_grasp"],
            0,
            "grasp_event",
            {"event": "start", "object_name": record.label.object_name},
        )
    ]
    for stream in record.frames:
        for i, (t, data) in enumerate(zip(stream.t_s, stream.encoded, strict=True)):
            items.append(
                (
                    t,
                    1,
                    "frame",
                    {"finger": stream.finger, "index": i, "encoding": "jpeg", "data": data},
                )
            )
    for start in range(0, len(record.force_n), 8):  # HX711 readings go out in bursts of 8
        t_s, value = record.force_n.t_s[start : start + 8], record.force_n.value[start : start + 8]
        items.append((t_s[-1], 1, "force", {"t_s": t_s, "value_n": value}))
    for t, value in zip(record.width_m.t_s, record.width_m.value, strict=True):
        items.append((t, 1, "width", {"t_s": [t], "value_m": [value]}))
    end_s = max(record.events["command_release"], *(t for t, *_ in items))
    items.append(
        (end_s + 0.01, 2, "grasp_event", {"event": "end", "object_name": record.label.object_name})
    )
    return [
        pub.send(kind, t_capture_s=float(t), grasp_id=grasp_id, **body)
        for t, _, kind, body in sorted(items, key=lambda item: item[:2])
    ]


def test_a_simulated_grasp_streamed_recorded_and_exported_is_the_same_record(tmp_path, helpers):
    settings = load_settings()
    obj = next(o for o in load_catalogue() if o.name == helpers.object_name)
    source, _ = simulate_grasp(obj, settings=settings, rng=np.random.default_rng(0), seed=0)
    path = tmp_path / "sim.mcap"
    with (
        Publisher("tcp://127.0.0.1:*", lossless=True, source="robot") as pub,
        helpers.recording(
            path, [pub.endpoint], settings=settings, catalogue=default_catalogue_path()
        ) as recorder,
    ):
        pub.wait_for_subscriber("")
        sent = _publish_record(pub, source, "sim-0")
        helpers.wait_for(lambda: recorder.stats.messages == len(sent), what="the grasp recorded")
    (grasp,) = export_session(path, tmp_path / "out")
    exported = read_record(grasp.path)
    for stream in source.frames:
        copy = exported.stream(stream.finger)
        assert copy.encoded == stream.encoded and np.array_equal(copy.t_s, stream.t_s)
        assert copy.shape == stream.shape
    for name in ("force_n", "width_m"):
        assert np.array_equal(getattr(exported, name).t_s, getattr(source, name).t_s)
        assert np.array_equal(getattr(exported, name).value, getattr(source, name).value)
    assert exported.label == source.label
    # Export copies each sensor's calibration beside the records and points the sensor at the copy.
    for sent_sensor, got_sensor in zip(source.sensors, exported.sensors, strict=True):
        assert dataclasses.replace(got_sensor, calibration="") == dataclasses.replace(
            sent_sensor, calibration=""
        )
        shipped = CONFIG_DIR / sent_sensor.calibration
        assert Path(got_sensor.calibration).read_bytes() == shipped.read_bytes()
    assert exported.provenance.source == "simulated"
