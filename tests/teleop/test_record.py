"""Grasp records: bit-exact round trip and every reader error path."""

from __future__ import annotations

import io
import json
import re
import zipfile
from pathlib import Path

import numpy as np
import pytest

import teleop.record
from teleop.errors import RecordError
from teleop.record import (
    FORMAT_NAME,
    FORMAT_VERSION,
    FrameStream,
    GraspRecord,
    Label,
    Provenance,
    Samples,
    read_record,
    write_record,
)
from teleop.settings import load_settings


def make_record(encoding: str, n_frames: int = 3) -> GraspRecord:
    rng = np.random.default_rng(7)
    sensors = load_settings().sensors
    frames = []
    for sensor in sensors:
        images = rng.integers(0, 256, (n_frames, 24, 32, 3), dtype=np.uint8)
        t_s = 0.0331 * np.arange(n_frames) + rng.uniform(0, 1e-3)
        frames.append(FrameStream.from_frames(sensor.finger, t_s, images, encoding=encoding, jpeg_quality=85))
    return GraspRecord(
        sensors=sensors,
        frames=tuple(frames),
        force_n=Samples(np.sort(rng.uniform(0, 2, 17)), rng.normal(5.0, 3.0, 17)),
        width_m=Samples(np.sort(rng.uniform(0, 2, 5)), rng.uniform(0.02, 0.08, 5)),
        provenance=Provenance(source="simulated", seed=1234, model="test model", created_utc="2025-01-01T00:00:00+00:00",
                              extra={"noise": 0.5, "tags": ["a", "b"]}),
        label=Label("rubber_duck", 3.61e6, "rubber", "irregular", {"source": "Gent", "shore_a": 60}),
        events={"contact": 0.12345678901234, "release": 1.75},
        calibration={"background": rng.integers(0, 256, (24, 32, 3), dtype=np.uint8),
                     "gradient_lut": rng.normal(size=(8, 8, 2)).astype(np.float32)},
    )


@pytest.fixture
def record_path(tmp_path) -> Path:
    return write_record(make_record("png"), tmp_path / "good.grasp")


@pytest.mark.parametrize("encoding", ["jpeg", "png"])
def test_round_trip_is_bit_exact(tmp_path, encoding):
    record = make_record(encoding)
    path = write_record(record, tmp_path / "r.grasp")
    assert path.exists() and not list(tmp_path.glob("*.partial"))
    back = read_record(path)

    assert back.sensors == record.sensors
    for a, b in zip(record.frames, back.frames, strict=True):
        assert (b.finger, b.encoding, b.jpeg_quality, b.shape) == (a.finger, a.encoding, a.jpeg_quality, a.shape)
        assert b.encoded == a.encoded
        assert b.t_s.dtype == np.float64 and np.array_equal(b.t_s, a.t_s)
        np.testing.assert_array_equal(b.frames(), a.frames())
    for name in ("force_n", "width_m"):
        a, b = getattr(record, name), getattr(back, name)
        assert np.array_equal(a.t_s, b.t_s) and np.array_equal(a.value, b.value)
        assert b.value.dtype == np.float64
    assert back.label == record.label
    assert back.provenance == record.provenance
    assert back.events == record.events
    assert back.calibration.keys() == record.calibration.keys()
    for key, array in record.calibration.items():
        assert back.calibration[key].dtype == array.dtype
        np.testing.assert_array_equal(back.calibration[key], array)


def test_png_frames_are_lossless_and_jpeg_keeps_its_quality(tmp_path):
    images = np.random.default_rng(1).integers(0, 256, (2, 16, 20, 3), dtype=np.uint8)
    png = FrameStream.from_frames("left", [0.0, 0.1], images, encoding="png")
    np.testing.assert_array_equal(png.frames(), images)
    jpeg = FrameStream.from_frames("left", [0.0, 0.1], images, encoding="jpeg", jpeg_quality=95)
    assert jpeg.jpeg_quality == 95 and jpeg.frames().shape == images.shape


def test_unlabelled_record_round_trips(tmp_path):
    record = make_record("png")
    record = GraspRecord(record.sensors, record.frames, record.force_n, record.width_m,
                         Provenance(source="hardware"))
    back = read_record(write_record(record, tmp_path / "u.grasp"))
    assert back.label is None and back.events == {} and back.calibration == {}


# --------------------------------------------------------------------------- error paths


def members_of(path: Path) -> dict[str, bytes]:
    with zipfile.ZipFile(path) as zf:
        return {name: zf.read(name) for name in zf.namelist()}


def rebuild(path: Path, members: dict[str, bytes]) -> Path:
    with zipfile.ZipFile(path, "w") as zf:
        for name, data in members.items():
            zf.writestr(name, data)
    return path


def header_of(members: dict[str, bytes]) -> dict:
    return json.loads(members["record.json"])


def npy(array: np.ndarray, *, allow_pickle: bool = False) -> bytes:
    buf = io.BytesIO()
    np.save(buf, array, allow_pickle=allow_pickle)
    return buf.getvalue()


def fails(path: Path, *expected: str) -> str:
    with pytest.raises(RecordError) as info:
        read_record(path)
    message = str(info.value)
    assert message.startswith(f"{path}: ") and f"{path}: {path}" not in message, message  # not named twice
    for part in expected:
        assert part in message, message
    return message


def test_missing_file_not_a_zip_and_truncated_zip(tmp_path, record_path):
    fails(tmp_path / "absent.grasp", "no such grasp record")
    text = tmp_path / "text.grasp"
    text.write_text("hello")
    fails(text, "not a readable ZIP")
    truncated = tmp_path / "truncated.grasp"
    truncated.write_bytes(record_path.read_bytes()[: record_path.stat().st_size // 2])
    fails(truncated, "not a readable ZIP")
    fails(tmp_path, "not a readable ZIP")  # a directory


def corrupt_member(path: Path, member: str) -> None:
    """Flip one byte inside ``member``'s stored data, leaving the ZIP structure intact."""
    with zipfile.ZipFile(path) as zf:
        info = zf.getinfo(member)
    data = bytearray(path.read_bytes())
    name_len = int.from_bytes(data[info.header_offset + 26 : info.header_offset + 28], "little")
    extra_len = int.from_bytes(data[info.header_offset + 28 : info.header_offset + 30], "little")
    start = info.header_offset + 30 + name_len + extra_len
    data[start + info.compress_size // 2] ^= 0xFF
    path.write_bytes(bytes(data))


@pytest.mark.parametrize("member", ["frames/left/000001.png", "force/value_n.npy", "record.json"])
def test_crc_corrupted_member_is_named(record_path, member):
    corrupt_member(record_path, member)
    fails(record_path, repr(member))


@pytest.mark.parametrize(
    "member", ["record.json", "force/value_n.npy", "width/t_s.npy", "frames/right/t_s.npy",
               "frames/left/000002.png", "calibration/background.npy"],
)
def test_missing_member_is_named(record_path, member):
    members = members_of(record_path)
    del members[member]
    fails(rebuild(record_path, members), repr(member), "missing")


def test_training_sample_is_named_not_called_an_incomplete_record(tmp_path, record_path):
    from estimator.training.samples import TrainingSample, save_sample

    sample = TrainingSample("apple", 0, 0, np.zeros((3, 4, 5, 3), np.float32), np.zeros((3, 4, 5), np.float32),
                            np.array([1.0, 2.0, 3.0]), np.array([0.03, 0.03, 0.03]))
    npz = save_sample(sample, tmp_path / "augmentation=0.npz")
    for path in (npz, tmp_path / "renamed.grasp"):  # recognised by its members, whatever its name
        path.write_bytes(npz.read_bytes())
        message = fails(path, "training sample", "import-dataset --layout preprocessed", "expected a .grasp record",
                        "--layout raw")
        assert "incomplete" not in message and "record.json" not in message
    # Any other .npz is not a record either; a .grasp without record.json is still an incomplete record.
    other = tmp_path / "other.npz"
    np.savez(other, a=np.arange(3))
    assert "incomplete" not in fails(other, "an .npz archive, not a grasp record")
    members = members_of(record_path)
    del members["record.json"]
    assert "training sample" not in fails(rebuild(record_path, members), "'record.json'", "incomplete")


def edit_header(path: Path, change) -> Path:
    members = members_of(path)
    header = header_of(members)
    change(header)
    members["record.json"] = json.dumps(header).encode()
    return rebuild(path, members)


def test_invalid_json_and_header_fields(record_path):
    members = members_of(record_path)
    members["record.json"] = b'{"format": "compliance-teleop.grasp", '
    fails(rebuild(record_path, members), "record.json is not valid JSON")
    members["record.json"] = b"\xff\xfe not utf-8"
    fails(rebuild(record_path, members), "record.json is not valid JSON")
    members["record.json"] = b"[1, 2]"
    fails(rebuild(record_path, members), "expected a JSON object")


@pytest.mark.parametrize(
    ("change", "expected"),
    [
        (lambda h: h.update(format="something.else"), "format is 'something.else'"),
        (lambda h: h.pop("format"), "header.format is missing"),
        (lambda h: h.update(version=FORMAT_VERSION + 1), f"version {FORMAT_VERSION + 1} is not supported"),
        (lambda h: h.update(version="1"), "header.version must be int"),
        (lambda h: h.update(sensors="left"), "header.sensors must be list"),
        (lambda h: h["sensors"][0].update(gel_poisson=2.0), "sensors[0] is invalid"),
        (lambda h: h["sensors"][0].update(colour="red"), "sensors[0] is invalid"),
        (lambda h: h["sensors"].__setitem__(1, "right"), "sensors[1] is invalid"),
        (lambda h: h["fingers"]["left"].update(encoding="gif"), "fingers.left.encoding 'gif'"),
        (lambda h: h["fingers"]["left"].pop("count"), "fingers.left.count is missing"),
        (lambda h: h["fingers"]["left"].update(count=5), "header says 5 frames"),
        (lambda h: h["fingers"]["left"].update(shape=7), "fingers.left.shape must be [rows, columns, 3]"),
        (lambda h: h["fingers"].update(middle=h["fingers"]["left"]), "'frames/middle/t_s.npy'"),
        (lambda h: h["label"].update(modulus_pa=-3.0), "label is invalid"),
        (lambda h: h["label"].update(modulus_pa="soft"), "label.modulus_pa must be a number (Pa) or null, got 'soft'"),
        (lambda h: h["label"].pop("object_name"), "label.object_name is missing"),
        (lambda h: h.update(label=["duck"]), "label.object_name is missing"),
        (lambda h: h["provenance"].update(source="dreamt"), "provenance is invalid"),
        (lambda h: h["provenance"].update(colour="red"), "provenance is invalid"),
        (lambda h: h.update(provenance="sim"), "header.provenance must be dict"),
        (lambda h: h["events"].update(contact="early"), "events.contact must be a time in seconds"),
        (lambda h: h["events"].update(contact=True), "events.contact must be a time in seconds"),
        (lambda h: h.update(calibration=["missing_array"]), "'calibration/missing_array.npy' is missing"),
    ],
)
def test_bad_header_fields_are_named(record_path, change, expected):
    fails(edit_header(record_path, change), expected)


@pytest.mark.parametrize(
    ("change", "expected"),
    [
        (lambda h: h["events"].update(grasp_done=float("nan")), "events.grasp_done must be a time in seconds"),
        (lambda h: h["events"].update(contact=float("inf")), "events.contact must be a time in seconds"),
        (lambda h: h["events"].update(contact=10**400), "events.contact must be a time in seconds"),
        (lambda h: h["label"].update(modulus_pa=True), "label.modulus_pa must be a number (Pa) or null, got True"),
        (lambda h: h["sensors"].append(dict(h["sensors"][0])),
         "sensors[2].finger 'left' is also sensors[0]'s: expected one sensor per finger"),
        *[(lambda h, v=v: h["fingers"]["left"].update(shape=v),
           f"fingers.left.shape must be [rows, columns, 3] (positive integers: frames decode to H x W x 3 BGR) "
           f"or null, got {v!r}")
          for v in ("abc", [24, 32], [24, 0, 3], [24, 32.0, 3], [24, 32, True], [24, 32, 4])],
        *[(lambda h, v=v: h["fingers"]["left"].update(jpeg_quality=v),
           f"fingers.left.jpeg_quality must be an integer from 1 to 100 or null, got {v!r}")
          for v in ("high", 0, 101, 85.0, True)],
    ],
)
def test_header_values_outside_the_format_are_refused(record_path, change, expected):
    """Values the writer never writes (a NaN time, a bool for a number, ...) are named, not read as others."""
    fails(edit_header(record_path, change), "record.json: " + expected)


def test_the_header_values_the_writer_writes_read_back(tmp_path):
    jpeg = read_record(write_record(make_record("jpeg"), tmp_path / "jpeg.grasp"))
    assert {s.jpeg_quality for s in jpeg.frames} == {85} and {s.shape for s in jpeg.frames} == {(24, 32, 3)}
    empty = read_record(write_record(make_record("png", n_frames=0), tmp_path / "empty.grasp"))
    assert {(s.jpeg_quality, s.shape) for s in empty.frames} == {(None, None)}


def test_nan_label_modulus_is_refused(record_path):
    members = members_of(record_path)
    header = header_of(members)
    text = json.dumps(header).replace('"modulus_pa": 3610000.0', '"modulus_pa": NaN')
    assert "NaN" in text
    members["record.json"] = text.encode()
    fails(rebuild(record_path, members), "label is invalid")


def test_frames_for_a_finger_without_a_sensor(record_path):
    def drop_right_sensor(h):
        h["sensors"] = [s for s in h["sensors"] if s["finger"] != "right"]

    fails(edit_header(record_path, drop_right_sensor), "no sensor on it")


@pytest.mark.parametrize(
    ("member", "data", "expected"),
    [
        ("force/t_s.npy", npy(np.zeros(17, dtype=np.float32)), "expected 1-D float64, got 1-D float32"),
        ("force/value_n.npy", npy(np.zeros((17, 1))), "expected 1-D float64, got 2-D float64"),
        ("width/value_m.npy", npy(np.array([{"a": 1}], dtype=object), allow_pickle=True), "not a readable .npy"),
        ("calibration/background.npy", npy(np.array([None], dtype=object), allow_pickle=True), "not a readable .npy"),
        ("width/t_s.npy", b"garbage, not npy", "not a readable .npy"),
        ("force/value_n.npy", npy(np.zeros(16)), "force: 17 timestamps but 16 values"),
        ("frames/left/t_s.npy", npy(np.zeros(2)), "has 2 timestamps, header says 3 frames"),
    ],
)
def test_bad_arrays_are_named(record_path, member, data, expected):
    members = members_of(record_path)
    members[member] = data
    message = fails(rebuild(record_path, members), expected)
    if "readable" in expected or "expected 1-D" in expected:
        assert repr(member) in message


def test_pickled_npy_member_runs_nothing(tmp_path, record_path):
    marker = tmp_path / "pwned"

    class RunsCode:
        def __reduce__(self):
            import os

            return os.system, (f"touch {marker}",)

    members = members_of(record_path)
    members["force/t_s.npy"] = npy(np.array([RunsCode()], dtype=object), allow_pickle=True)
    fails(rebuild(record_path, members), "'force/t_s.npy'")
    assert not marker.exists()


def test_format_constants():
    assert FORMAT_NAME == "compliance-teleop.grasp" and FORMAT_VERSION == 3


def test_style_round_trips_and_scripted_records_stay_version_1(tmp_path):
    import dataclasses

    record = make_record("png")
    scripted = write_record(record, tmp_path / "script.grasp")
    header = json.loads(zipfile.ZipFile(scripted).read("record.json"))
    assert header["version"] == 1 and "style" not in header["provenance"]  # as older readers read it
    assert read_record(scripted).provenance.style == "script"
    operated = dataclasses.replace(record, provenance=dataclasses.replace(record.provenance, style="operator"))
    path = write_record(operated, tmp_path / "operator.grasp")
    header = json.loads(zipfile.ZipFile(path).read("record.json"))
    assert header["version"] == 2 and header["provenance"]["style"] == "operator"
    assert read_record(path).provenance == operated.provenance
    with pytest.raises(ValueError, match="Provenance.style 'person'"):
        dataclasses.replace(record.provenance, style="person")
    members = members_of(scripted)
    header = json.loads(members["record.json"])
    header["provenance"]["style"] = "operator"
    members["record.json"] = json.dumps(header).encode()
    fails(rebuild(scripted, members), "provenance.style is a version-2 field")


def test_find_records_lists_grasps_under_a_folder_or_says_what_is_wrong(tmp_path):
    from teleop.errors import RecordError
    from teleop.record import find_records

    (tmp_path / "b" / "deep").mkdir(parents=True)
    for name in ("b/deep/two.grasp", "one.grasp", "notes.txt"):
        (tmp_path / name).write_bytes(b"")
    assert find_records(tmp_path) == [tmp_path / "b" / "deep" / "two.grasp", tmp_path / "one.grasp"]
    with pytest.raises(RecordError, match="--records .*: not a directory"):
        find_records(tmp_path / "one.grasp", name="--records")
    (tmp_path / "empty").mkdir()
    with pytest.raises(RecordError, match="no .grasp records found"):
        find_records(tmp_path / "empty")


# --------------------------------------------------------------------------- labels' provenance


def test_a_catalogue_label_is_written_as_before_and_other_sources_round_trip(tmp_path):
    import dataclasses

    record = make_record("png")
    assert record.label.source == "catalogue" and record.label.detail == ""
    path = write_record(record, tmp_path / "catalogue.grasp")
    header = json.loads(zipfile.ZipFile(path).read("record.json"))
    # The defaults are not written: records labelled from a catalogue keep their bytes (version 1).
    assert sorted(header["label"]) == ["extra", "material", "modulus_pa", "object_name", "shape"]
    assert header["version"] == 1
    assert read_record(path).label == record.label
    measured = dataclasses.replace(record.label, source="durometer", detail="Shore 00 30 -> 62 kPa")
    path = write_record(dataclasses.replace(record, label=measured), tmp_path / "durometer.grasp")
    header = json.loads(zipfile.ZipFile(path).read("record.json"))
    assert header["version"] == 1  # older readers read it and ignore the two keys
    assert (header["label"]["source"], header["label"]["detail"]) == ("durometer", "Shore 00 30 -> 62 kPa")
    assert read_record(path).label == measured


def test_a_label_source_outside_the_list_is_refused(tmp_path, record_path):
    with pytest.raises(ValueError, match="source 'guess' is not one of catalogue, durometer"):
        Label("duck", 1e6, source="guess")
    fails(edit_header(record_path, lambda h: h["label"].update(source="guess")), "label is invalid")
    fails(edit_header(record_path, lambda h: h["label"].update(detail=7)), "label is invalid")


# --------------------------------------------------------------------------- calibration files inside


def with_calibration_files(record: GraspRecord, tmp_path: Path) -> tuple[GraspRecord, bytes]:
    import dataclasses

    data = npy(np.arange(12.0))  # any bytes: the record keeps them as they are
    cal = tmp_path / "elsewhere" / "left cal.npz"
    sensors = tuple(dataclasses.replace(s, calibration=str(cal)) if s.finger == "left" else s
                    for s in record.sensors)
    return dataclasses.replace(record, sensors=sensors, calibration_files={"left": data}), data


def test_calibration_files_travel_inside_the_record(tmp_path, monkeypatch):
    import teleop.record as record_module

    record, data = with_calibration_files(make_record("png"), tmp_path)
    path = write_record(record, tmp_path / "v3.grasp")
    header = json.loads(zipfile.ZipFile(path).read("record.json"))
    assert header["version"] == FORMAT_VERSION == 3
    assert header["calibration_files"] == {"left": "sensors/left/left_cal.npz"}
    left = next(s for s in header["sensors"] if s["finger"] == "left")
    assert left["calibration"] == "sensors/left/left_cal.npz"  # no path outside the record
    assert str(tmp_path) not in zipfile.ZipFile(path).read("record.json").decode()
    # Read in a fresh cache: the reader's sensor names a copy of the bytes, wherever the record is.
    monkeypatch.setattr(record_module, "_CACHE", [tmp_path / "cache"])
    moved = tmp_path / "moved" / "v3.grasp"
    moved.parent.mkdir()
    path.rename(moved)
    back = read_record(moved)
    copy = Path(back.sensor("left").calibration)
    assert copy.is_relative_to(tmp_path / "cache") and copy.name == "left_cal.npz"
    assert copy.read_bytes() == data and back.calibration_files == {"left": data}
    assert back.sensor("right") == record.sensor("right")
    # Written again, it is the same file.
    again = write_record(back, tmp_path / "again.grasp")
    assert again.read_bytes() == moved.read_bytes()
    # A copy changed in the cache is put right on the next read.
    copy.write_bytes(b"tampered")
    assert Path(read_record(moved).sensor("left").calibration).read_bytes() == data


def test_calibration_files_errors_are_named(tmp_path):
    record, _ = with_calibration_files(make_record("png"), tmp_path)
    path = write_record(record, tmp_path / "v3.grasp")
    fails(edit_header(path, lambda h: h.update(version=2)), "calibration_files is a version-3 field")
    path = write_record(record, tmp_path / "v3.grasp")
    fails(edit_header(path, lambda h: h["calibration_files"].update(left="../x.npz")),
          "calibration_files.left must name a member sensors/left/<file>")
    path = write_record(record, tmp_path / "v3.grasp")
    fails(edit_header(path, lambda h: h["calibration_files"].update(thumb="sensors/thumb/x.npz")),
          "no sensor on finger 'thumb'")
    path = write_record(record, tmp_path / "v3.grasp")
    members = members_of(path)
    del members["sensors/left/left_cal.npz"]
    fails(rebuild(path, members), "'sensors/left/left_cal.npz'", "missing")
    import dataclasses

    with pytest.raises(ValueError, match="calibration file for finger 'thumb'"):
        dataclasses.replace(record, calibration_files={"thumb": b""})


# --------------------------------------------------------------------------- size limits (ZIP bombs)


def deflated(path: Path, members: dict[str, bytes]) -> Path:
    with zipfile.ZipFile(path, "w", compression=zipfile.ZIP_DEFLATED) as zf:
        for name, data in members.items():
            zf.writestr(name, data)
    return path


@pytest.fixture
def header_bomb(tmp_path, record_path) -> tuple[Path, int]:
    """A record whose record.json (still valid JSON) inflates from a few KB to 300 KB of spaces; its size."""
    members = members_of(record_path)
    members["record.json"] += b" " * 300_000
    path = deflated(tmp_path / "bomb.grasp", members)
    assert path.stat().st_size < 50_000
    return path, len(members["record.json"])


def test_a_header_inflating_past_its_limit_is_refused_before_it_is_read(header_bomb, monkeypatch):
    path, size = header_bomb
    read_record(path)  # under the shipped limits it is a record
    monkeypatch.setattr(teleop.record, "_MAX_HEADER_BYTES", 100_000, raising=False)  # absent: no limit
    opened = []
    monkeypatch.setattr(zipfile.ZipFile, "open", lambda self, name, *a, **k: opened.append(name) or 1 / 0)
    fails(path, "member 'record.json' declares", f"{size} bytes", "limit of 100000 bytes")
    assert opened == []


def test_a_header_understating_its_size_is_not_read_past_it(header_bomb, monkeypatch):
    """A lying size header: the central directory says 1000 bytes, the data inflates to 300 KB."""
    path, size = header_bomb
    data = bytearray(path.read_bytes())
    entry = int.from_bytes(data[-6:-2], "little")  # the central directory; record.json is its first entry
    assert data[entry:entry + 4] == b"PK\x01\x02" and data[entry + 46:entry + 57] == b"record.json"
    assert int.from_bytes(data[entry + 24:entry + 28], "little") == size
    data[entry + 24:entry + 28] = (1000).to_bytes(4, "little")
    path.write_bytes(data)
    monkeypatch.setattr(teleop.record, "_MAX_HEADER_BYTES", 100_000, raising=False)  # absent: no limit
    fails(path, "member 'record.json'")


def test_a_frame_past_its_limit_is_refused(record_path, monkeypatch):
    monkeypatch.setattr(teleop.record, "_MAX_FRAME_BYTES", 1000, raising=False)  # absent: no limit
    message = fails(record_path, "limit of 1000 bytes")
    assert re.search(r"member 'frames/\w+/000000\.png' declares \d{4} bytes", message), message


def test_an_archive_inflating_past_its_total_is_refused_before_any_member_is_read(tmp_path, record_path,
                                                                                   monkeypatch):
    members = members_of(record_path)
    members["force/t_s.npy"] = members["force/value_n.npy"] = npy(np.zeros(400_000))  # 3.2 MB each, deflated ~3 KB
    path = deflated(tmp_path / "big.grasp", members)
    assert len(read_record(path).force_n.t_s) == 400_000  # under the shipped limits it is a record
    monkeypatch.setattr(teleop.record, "_MAX_INFLATION_BYTES", 1_000_000, raising=False)  # absent: no limit
    message = fails(path, "the archive's members declare", "more than the limit of", "refused before reading")
    assert re.search(r"member 'force/(t_s|value_n)\.npy' 3200128\)", message), message
