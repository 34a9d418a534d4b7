"""Grasp records: writing safely, the calibration cache, the reader's limits and header values, as a mutation
audit found them untested."""

from __future__ import annotations

import dataclasses
import json
import os
import stat
import zipfile

import numpy as np
import pytest

import teleop.record
from teleop.record import (
    FrameStream,
    calibration_cache,
    calibration_copy,
    read_record,
    write_record,
)
from tests.teleop.test_record import edit_header, fails, make_record, with_calibration_files


@pytest.fixture
def record_path(tmp_path):
    return write_record(make_record("png"), tmp_path / "good.grasp")


def header_of(path) -> dict:
    with zipfile.ZipFile(path) as zf:
        return json.loads(zf.read("record.json"))


# --------------------------------------------------------------------------- writing


def test_event_times_of_numpy_types_are_written_as_numbers(tmp_path):
    record = dataclasses.replace(make_record("png"), events={"contact": np.float32(0.5), "release": np.int64(2)})
    back = read_record(write_record(record, tmp_path / "r.grasp"))
    assert back.events == {"contact": 0.5, "release": 2.0}


def test_a_record_with_a_nan_event_is_refused_and_leaves_the_earlier_record_whole(tmp_path):
    path = write_record(make_record("png"), tmp_path / "r.grasp")
    before = path.read_bytes()
    bad = dataclasses.replace(make_record("png"), events={"contact": float("nan")})
    with pytest.raises(ValueError, match="Out of range float values are not JSON compliant"):
        write_record(bad, path)
    assert path.read_bytes() == before and sorted(p.name for p in tmp_path.iterdir()) == ["r.grasp"]


def test_a_write_that_fails_midway_keeps_the_record_already_at_that_path(tmp_path, monkeypatch):
    path = write_record(make_record("png"), tmp_path / "r.grasp")
    before = path.read_bytes()

    def interrupt(*_args):
        raise KeyboardInterrupt

    monkeypatch.setattr(teleop.record, "_npy_bytes", interrupt)
    with pytest.raises(KeyboardInterrupt):
        write_record(make_record("jpeg"), path)
    assert path.read_bytes() == before and sorted(p.name for p in tmp_path.iterdir()) == ["r.grasp"]


def test_a_calibration_file_of_a_sensor_naming_none_is_stored_as_calibration_npz(tmp_path, monkeypatch):
    record, data = with_calibration_files(make_record("png"), tmp_path)
    sensors = tuple(dataclasses.replace(s, calibration="") for s in record.sensors)
    path = write_record(dataclasses.replace(record, sensors=sensors), tmp_path / "v3.grasp")
    assert header_of(path)["calibration_files"] == {"left": "sensors/left/calibration.npz"}
    monkeypatch.setattr(teleop.record, "_CACHE", [tmp_path / "cache"])
    assert read_record(path).calibration_files == {"left": data}


# --------------------------------------------------------------------------- the calibration cache


@pytest.fixture
def fresh_cache(tmp_path, monkeypatch):
    """calibration_cache as in a new process whose temporary folder is ``tmp_path``; the root it prefers."""
    monkeypatch.setattr(teleop.record, "_CACHE", [])
    monkeypatch.setattr(teleop.record.tempfile, "tempdir", str(tmp_path))
    return tmp_path / f"compliance-teleop-{os.getuid()}"


def test_the_calibration_cache_is_a_private_folder_of_the_user(fresh_cache):
    assert calibration_cache() == fresh_cache / "calibration"
    assert stat.S_IMODE(fresh_cache.stat().st_mode) == 0o700
    assert calibration_cache() == fresh_cache / "calibration"  # chosen once


def test_a_cache_root_others_may_write_to_is_not_used(fresh_cache):
    fresh_cache.mkdir(mode=0o700)
    fresh_cache.chmod(0o777)
    folder = calibration_cache()
    assert not folder.is_relative_to(fresh_cache) and stat.S_IMODE(folder.stat().st_mode) == 0o700


def test_a_cache_root_of_another_user_is_not_used(fresh_cache, monkeypatch):
    other = os.getuid() + 4242
    root = fresh_cache.with_name(f"compliance-teleop-{other}")
    root.mkdir(mode=0o700)  # owned by this user, named for the other
    monkeypatch.setattr(teleop.record.os, "getuid", lambda: other)
    assert not calibration_cache().is_relative_to(root)


def test_calibrations_of_one_name_but_other_contents_are_kept_apart(tmp_path, monkeypatch):
    """Two records' calibrations named alike: each sensor must keep naming its own bytes."""
    monkeypatch.setattr(teleop.record, "_CACHE", [tmp_path / "cache"])
    first, second = calibration_copy(b"first", "cal.npz"), calibration_copy(b"second", "cal.npz")
    assert first != second and first.read_bytes() == b"first" and second.read_bytes() == b"second"
    assert calibration_copy(b"first", "cal.npz") == first and first.name == "cal.npz"

def test_a_failed_calibration_copy_leaves_no_temporary(tmp_path, monkeypatch):
    monkeypatch.setattr(teleop.record, "_CACHE", [tmp_path / "cache"])

    def full(*_args):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(teleop.record.os, "replace", full)
    with pytest.raises(OSError, match="No space left"):
        calibration_copy(b"table", "cal.npz")
    assert [p for p in (tmp_path / "cache").rglob("*") if p.is_file()] == []


def test_a_calibration_that_cannot_be_copied_is_a_record_error_naming_the_member(tmp_path, monkeypatch):
    record, _ = with_calibration_files(make_record("png"), tmp_path)
    path = write_record(record, tmp_path / "v3.grasp")
    monkeypatch.setattr(teleop.record, "_CACHE", [tmp_path / "cache"])

    def denied(*_args):
        raise PermissionError(13, "Permission denied")

    monkeypatch.setattr(teleop.record, "calibration_copy", denied)
    fails(path, "cannot copy member 'sensors/left/left_cal.npz'", "finger 'left'", "Permission denied")


# --------------------------------------------------------------------------- size limits


def test_the_inflation_allowance_comes_on_top_of_the_files_own_size(record_path, monkeypatch):
    with zipfile.ZipFile(record_path) as zf:
        declared = sum(info.file_size for info in zf.infolist())
    over = declared - record_path.stat().st_size
    assert over > 0
    monkeypatch.setattr(teleop.record, "_MAX_INFLATION_BYTES", over)
    read_record(record_path)  # exactly at the limit: read
    monkeypatch.setattr(teleop.record, "_MAX_INFLATION_BYTES", over - 1)
    fails(record_path, "the archive's members declare", "refused before reading")


def test_a_member_read_again_and_again_counts_against_the_archive_limit(record_path, monkeypatch):
    """A header naming one array many times must not inflate it without end."""
    path = edit_header(record_path, lambda h: h.update(calibration=["background"] * 50))
    read_record(path)  # under the shipped limits it reads (the array is small)
    with zipfile.ZipFile(path) as zf:
        spare = sum(info.file_size for info in zf.infolist()) - path.stat().st_size
        array = zf.getinfo("calibration/background.npy").file_size
    monkeypatch.setattr(teleop.record, "_MAX_INFLATION_BYTES", spare + 10 * array)  # the archive once, then some
    fails(path, "member 'calibration/background.npy'", "more than the limit of")


def test_a_member_one_byte_over_its_limit_is_refused_before_it_is_opened(record_path, monkeypatch):
    size = zipfile.ZipFile(record_path).getinfo("record.json").file_size
    monkeypatch.setattr(teleop.record, "_MAX_HEADER_BYTES", size - 1)
    opened = []
    monkeypatch.setattr(zipfile.ZipFile, "open", lambda self, name, *a, **k: opened.append(name) or 1 / 0)
    fails(record_path, f"member 'record.json' declares {size} bytes, more than the limit of {size - 1} bytes")
    assert opened == []


def test_frame_timestamps_are_held_to_the_array_limit_not_the_frame_limit(tmp_path, monkeypatch):
    record = make_record("png")
    t_s = np.arange(200) * 0.033
    frames = tuple(FrameStream.from_frames(s.finger, t_s, np.zeros((200, 4, 4, 3), np.uint8)) for s in record.sensors)
    path = write_record(dataclasses.replace(record, frames=frames), tmp_path / "long.grasp")
    assert zipfile.ZipFile(path).getinfo("frames/left/t_s.npy").file_size > 1000
    monkeypatch.setattr(teleop.record, "_MAX_FRAME_BYTES", 1000)
    assert len(read_record(path).stream("left")) == 200


# --------------------------------------------------------------------------- header values


@pytest.mark.parametrize("value", [None, 5, "background", {"background": 1}, [5]])
def test_a_calibration_list_of_another_type_is_named(record_path, value):
    fails(edit_header(record_path, lambda h: h.update(calibration=value)),
          f"record.json: header.calibration must be a list of array names, got {value!r}")


def test_a_record_without_a_calibration_list_reads_none(record_path):
    assert read_record(edit_header(record_path, lambda h: h.pop("calibration"))).calibration == {}


def test_a_version_of_true_is_not_read_as_version_1(record_path):
    fails(edit_header(record_path, lambda h: h.update(version=True)), "header.version must be int, got True")


def test_a_gripper_that_is_not_a_table_is_named(record_path):
    fails(edit_header(record_path, lambda h: h.update(gripper="stiff")),
          "record.json: gripper is invalid (expected a table of gripper settings, got 'stiff')")


def test_event_times_written_as_whole_numbers_read_as_floats(record_path):
    events = read_record(edit_header(record_path, lambda h: h["events"].update(release=2))).events
    assert events["release"] == 2.0 and type(events["release"]) is float



def test_a_finger_entry_that_is_not_a_table_is_named(record_path):
    fails(edit_header(record_path, lambda h: h["fingers"].update(left=5)), "record.json: fingers.left.encoding is missing")


def test_a_label_modulus_too_large_for_a_float_is_named(record_path):
    fails(edit_header(record_path, lambda h: h["label"].update(modulus_pa=10**400)), "record.json: label is invalid")


def test_a_label_whose_object_name_is_not_text_is_named(record_path):
    fails(edit_header(record_path, lambda h: h["label"].update(object_name=5)), "record.json: label.object_name must be str, got 5")
