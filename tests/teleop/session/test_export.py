"""Export: the grasps of a recorded session as grasp records equal to the streams that were sent."""

from __future__ import annotations

import dataclasses
import hashlib
import json
import time
import zipfile
from pathlib import Path

import numpy as np
import pytest
from mcap.writer import Writer

from teleop.bus import Publisher
from teleop.catalogue import default_catalogue_path, load_catalogue
from teleop.errors import SessionLogError
from teleop.record import Label, read_record
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


def test_sensors_come_from_the_stored_settings_and_carry_the_stored_calibration(recorded, exported):
    out, results = exported
    record = read_record(results[0].path)
    assert [s.finger for s in record.sensors] == [s.finger for s in recorded.settings.sensors]
    left, original = record.sensor("left"), recorded.settings.sensor("left")
    assert (
        left.warp_corners_px == original.warp_corners_px
        and left.gel_modulus_pa == original.gel_modulus_pa
    )
    # The calibration file travels inside the record (format version 3), not beside it.
    header = json.loads(zipfile.ZipFile(results[0].path).read("record.json"))
    assert header["version"] == 3
    assert header["calibration_files"] == {"left": "sensors/left/left_cal.npz"}
    assert header["sensors"][0]["calibration"] == "sensors/left/left_cal.npz"
    with open(original.calibration, "rb") as f:
        assert record.calibration_files["left"] == f.read()
        f.seek(0)
        assert Path(left.calibration).read_bytes() == f.read()  # the reader's copy of it
    assert not (out / "calibration").exists()
    assert record.sensor("right") == recorded.settings.sensor("right")  # names no calibration


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
    with pytest.raises(SessionLogError, match="no settings.json attachment: pass --settings"):
        list(session_grasps(path))


def test_a_failed_export_leaves_no_new_folder(tmp_path, capsys):
    from teleop.cli import main

    out = tmp_path / "new" / "records"
    assert main(["export", str(tmp_path / "missing.mcap"), "--out", str(out)]) == 2
    assert "cannot read session log" in capsys.readouterr().err
    assert not (tmp_path / "new").exists()
    bare = tmp_path / "bare.mcap"  # readable, but refused once its grasps are read: no settings
    with bare.open("wb") as f:
        writer = Writer(f)
        writer.start()
        writer.finish()
    with pytest.raises(SessionLogError, match="no settings.json attachment"):
        export_session(bare, tmp_path / "out")
    assert not (tmp_path / "out").exists()
    (tmp_path / "mine").mkdir()  # a folder that was there before stays
    with pytest.raises(SessionLogError, match="no settings.json attachment"):
        export_session(bare, tmp_path / "mine")
    assert (tmp_path / "mine").is_dir()


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


@pytest.fixture(scope="module")
def sim_session(tmp_path_factory, helpers):
    """A simulated grasp of the catalogue's stress ball streamed on the bus and recorded with the
    shipped settings (their calibration files stored in the log): (log, the grasp's record)."""
    settings = load_settings()
    obj = next(o for o in load_catalogue() if o.name == helpers.object_name)
    source, _ = simulate_grasp(obj, settings=settings, rng=np.random.default_rng(0), seed=0)
    path = tmp_path_factory.mktemp("sim") / "sim.mcap"
    with (
        Publisher("tcp://127.0.0.1:*", lossless=True, source="robot") as pub,
        helpers.recording(
            path, [pub.endpoint], settings=settings, catalogue=default_catalogue_path()
        ) as recorder,
    ):
        pub.wait_for_subscriber("")
        sent = _publish_record(pub, source, "sim-0")
        helpers.wait_for(lambda: recorder.stats.messages == len(sent), what="the grasp recorded")
    return path, source


def test_a_simulated_grasp_streamed_recorded_and_exported_is_the_same_record(tmp_path, sim_session):
    path, source = sim_session
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
    # Export puts each sensor's calibration inside the record; the reader names a copy of it.
    for sent_sensor, got_sensor in zip(source.sensors, exported.sensors, strict=True):
        assert dataclasses.replace(got_sensor, calibration="") == dataclasses.replace(
            sent_sensor, calibration=""
        )
        shipped = CONFIG_DIR / sent_sensor.calibration
        assert Path(got_sensor.calibration).read_bytes() == shipped.read_bytes()
        assert exported.calibration_files[got_sensor.finger] == shipped.read_bytes()
    assert exported.provenance.source == "simulated"


# --------------------------------------------------------------------------- names, overwrite, labels


def _record_session(path, helpers, settings, *, then=lambda pub: []):
    """The synthetic session of conftest recorded at full speed, then the messages ``then(pub)``."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with (
        Publisher("tcp://127.0.0.1:*", lossless=True, source="robot") as pub,
        helpers.recording(
            path, [pub.endpoint], settings=settings, catalogue=default_catalogue_path()
        ) as recorder,
    ):
        pub.wait_for_subscriber("")
        sent = helpers.publish_session(pub)
        sent += then(pub)
        helpers.wait_for(lambda: recorder.stats.messages == len(sent), what="the session recorded")
    return path


def _checksums(folder):
    return {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in folder.glob("*.grasp")}


def test_two_sessions_with_the_same_grasp_ids_exported_into_one_folder_keep_every_record(
    recorded, session_settings, helpers, tmp_path
):
    out = tmp_path / "records"
    first = export_session(recorded.path, out)
    before = _checksums(out)
    assert len(before) == 2
    # Another session, its log of the same name, its grasps of the same ids.
    second_log = _record_session(tmp_path / "again" / "session.mcap", helpers, session_settings)
    second = export_session(second_log, out)
    after = _checksums(out)
    assert len(after) == 4 and {k: after[k] for k in before} == before  # nothing replaced
    assert first.session_id != second.session_id
    for session in (first, second):
        for result in session:
            if result:
                assert result.path.name == f"session_{session.session_id}_{result.grasp_id}.grasp"
                assert read_record(result.path).provenance.extra["session_id"] == session.session_id


def test_an_export_never_replaces_a_record_unless_asked(recorded, tmp_path, capsys):
    from teleop.cli import main

    out = tmp_path / "records"
    results = export_session(recorded.path, out)
    before = _checksums(out)
    taken = next(r.path for r in results if r)
    with pytest.raises(SessionLogError, match="--overwrite") as info:
        export_session(recorded.path, out)
    assert str(taken) in str(info.value) or str(out / taken.name) in str(info.value)
    assert _checksums(out) == before and sorted(p.name for p in out.iterdir()) == sorted(before)
    assert main(["export", str(recorded.path), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "already exists" in err and "--overwrite" in err and "Traceback" not in err
    again = export_session(recorded.path, out, overwrite=True)
    assert [r.path.name for r in again if r] == [r.path.name for r in results if r]
    assert not [p for p in out.iterdir() if p.name.startswith(".")]  # no staged file left


def test_one_session_exported_from_two_logs_keeps_each_grasp_once(recorded, tmp_path, capsys):
    # A log cut short is exported, then the log `teleop recover` made of it (another file name, the
    # same session): its grasps are in the folder already.
    from teleop.cli import main

    out = tmp_path / "records"
    first = export_session(recorded.path, out)
    before = _checksums(out)
    fixed = tmp_path / "fixed.mcap"
    fixed.write_bytes(recorded.path.read_bytes())
    with pytest.raises(SessionLogError, match="--overwrite") as info:
        export_session(fixed, out)
    taken = next(r.path for r in first if r)
    assert str(taken) in str(info.value) and f"fixed_{first.session_id}_" in str(info.value)
    assert _checksums(out) == before and sorted(p.name for p in out.iterdir()) == sorted(before)
    assert main(["export", str(fixed), "--out", str(out)]) == 2
    assert "count it twice" in capsys.readouterr().err
    again = export_session(fixed, out, overwrite=True)
    assert sorted(p.name for p in out.iterdir()) == sorted(r.path.name for r in again if r)
    assert sorted(again.replaced) == sorted(r.path for r in first if r)
    assert all(p.name.startswith("fixed_") for p in out.iterdir())


def test_export_names_untagged_data_captured_before_a_grasp_it_dropped(session_settings, helpers, tmp_path,
                                                                       capsys):
    from teleop.cli import main

    def late_frames(pub):  # captured in g0, sent while g2 (the last, never ended) is open
        return [pub.send("frame", t_capture_s=100.0 + k / 30, finger="right", index=k, encoding="png",
                         data=helpers.jpeg(np.random.default_rng(k), ".png")) for k in range(3)]

    path = _record_session(tmp_path / "late.mcap", helpers, session_settings, then=late_frames)
    assert main(["export", str(path), "--out", str(tmp_path / "records"), "--json"]) == 0
    captured = capsys.readouterr()
    report = json.loads(captured.out.strip().splitlines()[-1])
    assert report["dropped"] == [{"grasp_id": "g2", "stream": "frame/right", "count": 3}]
    assert "dropped 3 frame/right message(s) of grasp g2" in captured.err


def test_export_json_says_what_was_written_and_what_was_skipped(recorded, tmp_path, capsys):
    from teleop.cli import main

    out = tmp_path / "records"
    assert main(["export", str(recorded.path), "--out", str(out), "--json"]) == 0
    report = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert report["exported"] == 2 and report["complete"] and report["error"] is None
    assert sorted(report["records"]) == sorted(str(p) for p in out.glob("*.grasp"))
    written = {w["grasp_id"]: w for w in report["written"]}
    assert written["g0"]["object"] == "stress_ball" and written["g0"]["label_source"] == "catalogue"
    assert written["g0"]["modulus_pa"] > 0 and written["g1"]["object"] is None
    assert [(u["grasp_id"], "names no object" in u["reason"]) for u in report["unlabelled"]] == [
        ("g1", True)
    ]
    assert [s["grasp_id"] for s in report["skipped"]] == ["g2"]
    assert "before the grasp's end event" in report["skipped"][0]["reason"]


def test_exporting_a_cut_log_that_yields_nothing_fails_and_names_recover(recorded, tmp_path, capsys):
    from mcap.records import Metadata

    from teleop.cli import main
    from teleop.session import LogReader

    reader = LogReader(recorded.path)
    cut_at = next(  # just after the settings and the session metadata, inside the first chunk
        reader.good_bytes
        for record in reader.records(emit_chunks=True)
        if isinstance(record, Metadata) and record.name == "rig"
    )
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(recorded.path.read_bytes()[: cut_at + 500])
    assert main(["export", str(cut), "--out", str(tmp_path / "out"), "--json"]) == 1
    captured = capsys.readouterr()
    assert f"teleop recover {cut}" in captured.err
    report = json.loads(captured.out.strip().splitlines()[-1])
    assert report["exported"] == 0 and not report["complete"] and "teleop recover" in report["error"]


def test_a_log_cut_before_its_session_metadata_says_so(recorded, tmp_path, capsys):
    from mcap.records import Metadata

    from teleop.cli import main
    from teleop.session import LogReader

    reader, before = LogReader(recorded.path), 0
    for record in reader.records(emit_chunks=True):
        if isinstance(record, Metadata) and record.name == "session":
            break
        before = reader.good_bytes
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(recorded.path.read_bytes()[: before + 10])  # the attachments, not the metadata
    for command in (["export", str(cut), "--out", str(tmp_path / "out")], ["report", str(cut), "--out",
                                                                          str(tmp_path / "page")]):
        assert main(command) != 0
        assert f"{cut} is cut short before its session metadata" in capsys.readouterr().err


def test_a_complete_log_without_a_grasp_fails(recorded, tmp_path, capsys):
    from teleop.cli import main

    path = tmp_path / "idle.mcap"
    with (
        Publisher("tcp://127.0.0.1:*", lossless=True, source="robot") as pub,
        SessionRecorder(path, [pub.endpoint], settings=recorded.settings) as recorder,
    ):
        pub.wait_for_subscriber("")
        pub.send("force", t_capture_s=1.0, t_s=[1.0], value_n=[0.0])
        deadline = time.monotonic() + 5.0
        while recorder.stats.messages < 1 and time.monotonic() < deadline:
            recorder.poll(0.1)
    assert main(["export", str(path), "--out", str(tmp_path / "out"), "--source", "simulated"]) == 1
    assert "holds no complete grasp" in capsys.readouterr().err


def test_labels_in_the_log_win_over_the_catalogue(session_settings, helpers, tmp_path):
    catalogue = {o.name: o for o in load_catalogue()}

    def labels(pub):
        def label(gid, name, modulus, source="measured", detail=""):
            return pub.send("label", t_capture_s=200.0, grasp_id=gid, object_name=name,
                            modulus_pa=modulus, source=source, detail=detail)

        return [
            label("g0", "rubber_duck", 1.0e6, "datasheet"),  # replaced by the next one
            label("g0", helpers.object_name, 6.2e4, "durometer", "Shore 00 30"),
            label("g1", helpers.object_name, None, "catalogue"),  # nil: the catalogue's modulus
            label("g2", helpers.object_name, 5e4),  # g2 never ends: no record to label
            label("g9", helpers.object_name, 5e4),  # no such grasp
        ]

    path = _record_session(tmp_path / "labelled.mcap", helpers, session_settings, then=labels)
    results = export_session(path, tmp_path / "out")
    g0, g1, g2 = results
    assert read_record(g0.path).label == Label(
        helpers.object_name, 6.2e4, catalogue[helpers.object_name].material,
        catalogue[helpers.object_name].shape, source="durometer", detail="Shore 00 30",
    )
    obj = catalogue[helpers.object_name]
    assert read_record(g1.path).label == Label(obj.name, obj.modulus_pa, obj.material, obj.shape)
    assert not g0.unlabelled and not g1.unlabelled and not g2
    assert len(results.stray_labels) == 1 and "'g9'" in results.stray_labels[0]


def test_a_label_without_a_modulus_for_an_unknown_object_leaves_the_record_unlabelled(
    session_settings, helpers, tmp_path
):
    def labels(pub):
        return [pub.send("label", t_capture_s=200.0, grasp_id="g1", object_name="mystery_foam",
                         modulus_pa=None, source="catalogue", detail="")]

    path = _record_session(tmp_path / "mystery.mcap", helpers, session_settings, then=labels)
    g1 = next(r for r in export_session(path, tmp_path / "out") if r.grasp_id == "g1")
    label = read_record(g1.path).label
    assert label.object_name == "mystery_foam" and label.modulus_pa is None
    assert "'mystery_foam' without a modulus" in g1.unlabelled


def test_an_exported_folder_moved_elsewhere_builds_a_dataset(sim_session, tmp_path, monkeypatch, capsys):
    import shutil

    import teleop.record as record_module
    from estimator.cli import main as estimator

    path, _ = sim_session
    out = tmp_path / "exported"
    (grasp,) = export_session(path, out)
    header = json.loads(zipfile.ZipFile(grasp.path).read("record.json"))
    assert all(not Path(s["calibration"]).is_absolute() for s in header["sensors"])
    moved = tmp_path / "elsewhere" / "records"
    moved.parent.mkdir()
    shutil.move(out, moved)
    # A fresh cache: whatever the records need comes from inside them.
    monkeypatch.setattr(record_module, "_CACHE", [tmp_path / "fresh-cache"])
    dataset = tmp_path / "dataset"
    argv = ["build-dataset", "--records", str(moved), "--out", str(dataset), "--size", "32x44",
            "--shifts", "1", "--json"]
    assert estimator(argv) == 0, capsys.readouterr().err
    manifest = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert manifest["grasps_used"] == 1 and sum(manifest["samples"].values()) == 1
    assert manifest["skipped"] == []


def test_settings_given_to_the_export_carry_the_calibration_they_name(recorded, tmp_path):
    newer = tmp_path / "cal" / "left_cal.npz"  # recalibrated since, under the same name
    newer.parent.mkdir()
    np.savez(newer, gain=np.arange(7.0))
    sensors = tuple(
        dataclasses.replace(s, calibration=str(newer)) if s.finger == "left" else s
        for s in recorded.settings.sensors
    )
    settings = dataclasses.replace(recorded.settings, sensors=sensors)
    results = export_session(recorded.path, tmp_path / "out", settings=settings)
    record = read_record(results[0].path)
    assert record.calibration_files["left"] == newer.read_bytes()
