"""An attachment whose bytes changed (its CRC-32 fails) is damage: said, refused by export, and copied
by recover with its stored CRC-32, so the copy's readers see the damage too."""

from __future__ import annotations

import json
import struct
from pathlib import Path

import pytest
from mcap.reader import make_reader
from mcap.records import Attachment
from mcap.writer import Writer

from teleop.catalogue import default_catalogue_path
from teleop.cli import main
from teleop.errors import SessionLogError
from teleop.session import LogReader, export_session, recover
from teleop.session.label import label_session
from teleop.session.logfile import SETTINGS_ATTACHMENT
from teleop.session.recover import RECOVERY_METADATA
from teleop.settings import default_settings_path


def _damage_attachment(source: Path, out: Path, prefix: str) -> tuple[Path, str, bytes]:
    """``source`` with one byte in the middle of the data of the first attachment named ``prefix...`` flipped:
    the copy, the attachment's name and its damaged data."""
    with source.open("rb") as f:
        index = next(a for a in make_reader(f).get_summary().attachment_indexes if a.name.startswith(prefix))
    data = bytearray(source.read_bytes())
    at = index.offset + 9 + 16  # opcode, length, log and create times
    at += 4 + struct.unpack_from("<I", data, at)[0]  # the name
    at += 4 + struct.unpack_from("<I", data, at)[0]  # the media type
    size = struct.unpack_from("<Q", data, at)[0]
    start = at + 8
    data[start + size // 2] ^= 0xFF
    out.write_bytes(bytes(data))
    return out, index.name, bytes(data[start : start + size])


@pytest.fixture
def damaged_calibration(recorded, tmp_path):
    return _damage_attachment(recorded.path, tmp_path / "calibration.mcap", "calibration/left/")


def test_a_damaged_attachment_is_damage_and_kept_out_of_the_attachments(damaged_calibration):
    path, name, _ = damaged_calibration
    reader = LogReader(path)
    info = reader.info()
    assert not info.complete and reader.damaged and not reader.stopped
    assert f"attachment {name!r} at bytes " in info.damage and "CRC-32" in info.damage
    assert name not in info.attachments and name in info.damaged_attachments
    assert SETTINGS_ATTACHMENT in info.attachments  # the others are intact


def test_export_refuses_a_log_whose_calibration_attachment_is_damaged(damaged_calibration, tmp_path):
    path, name, _ = damaged_calibration
    with pytest.raises(SessionLogError, match="damaged") as caught:
        export_session(path, tmp_path / "out")
    assert str(path) in str(caught.value) and repr(name) in str(caught.value)
    assert not (tmp_path / "out").exists()


def test_recover_copies_a_damaged_attachment_with_its_stored_crc_and_says_so(damaged_calibration, tmp_path,
                                                                             capsys):
    path, name, data = damaged_calibration
    fixed = tmp_path / "fixed.mcap"
    report = recover(path, fixed)
    assert not report.complete and report.damaged and report.damaged_attachments == [name]
    with fixed.open("rb") as f:
        metadata = {m.name: m.metadata for m in make_reader(f).iter_metadata()}
    assert json.loads(metadata[RECOVERY_METADATA]["damaged_attachments"]) == [name]
    reader = LogReader(fixed)
    info = reader.info()
    assert not info.complete and name in info.damaged_attachments  # the copy's CRC is not a fresh one
    records = [r for r in reader.records() if isinstance(r, Attachment) and r.name == name]
    assert [bytes(r.data) for r in records] == [data]  # nothing of it lost
    assert main(["recover", str(path), "--out", str(tmp_path / "cli.mcap")]) == 0
    err = capsys.readouterr().err
    assert "complete" not in err and f"damaged (attachment {name!r}" in err and "stored CRC-32" in err


def test_a_damaged_settings_attachment_is_named_when_the_settings_are_read(recorded, tmp_path):
    path, name, _ = _damage_attachment(recorded.path, tmp_path / "settings.mcap", SETTINGS_ATTACHMENT)
    info = LogReader(path).info()
    with pytest.raises(SessionLogError, match=f"attachment '{name}' at bytes .* is damaged"):
        info.settings()
    with pytest.raises(SessionLogError, match="pass --settings") as caught:
        export_session(path, tmp_path / "out")
    assert str(path) in str(caught.value) and repr(name) in str(caught.value)


def test_a_log_with_a_damaged_attachment_is_labelled_and_keeps_its_damage(damaged_calibration, tmp_path):
    # A damaged attachment made the log "cut short" to label, which advised a recover that keeps it.
    path, name, _ = damaged_calibration
    (tmp_path / "labels.csv").write_text("grasp_id,object\ng0,stress_ball\n")
    report = label_session(path, tmp_path / "labels.csv")
    assert [label["grasp_id"] for label in report.labels] == ["g0"]
    info = LogReader(path).info()
    assert name in info.damaged_attachments and not info.mendable  # copied as stored: still found damaged


def test_a_damaged_catalogue_attachment_is_named_to_label_and_passed_over_with_objects(recorded, tmp_path):
    path, name, _ = _damage_attachment(recorded.path, tmp_path / "catalogue.mcap", "catalogue.")
    (tmp_path / "labels.csv").write_text("grasp_id,object\ng0,stress_ball\n")
    with pytest.raises(SessionLogError, match="pass --objects CATALOGUE") as caught:
        label_session(path, tmp_path / "labels.csv")
    assert repr(name) in str(caught.value) and "teleop recover" not in str(caught.value)
    assert label_session(path, tmp_path / "labels.csv", catalogue=default_catalogue_path()).labels


def test_export_of_a_log_whose_damage_recover_cannot_mend_does_not_advise_it(damaged_calibration, tmp_path, capsys):
    path, name, _ = damaged_calibration
    out = tmp_path / "out"
    code = main(["export", str(path), "--out", str(out), "--settings", str(default_settings_path()), "--json"])
    captured = capsys.readouterr()
    report = json.loads(captured.out)
    assert code == 0 and report["exported"] and report["complete"] is False and report["mendable"] is False
    assert repr(name) in captured.err and "FIXED.mcap" not in captured.err


def _log_with_note(path: Path, data: bytes) -> Path:
    with path.open("wb") as f:
        writer = Writer(f)
        writer.start("compliance-teleop.session", "test")
        writer.add_attachment(1, 1, "notes.txt", "text/plain", data)
        writer.finish()
    return path


def _attachment_index(path: Path):
    with path.open("rb") as f:
        return make_reader(f).get_summary().attachment_indexes[0]


def test_a_damaged_attachment_is_placed_at_the_bytes_of_its_record(tmp_path):
    path = _log_with_note(tmp_path / "att.mcap", b"hello attachment " * 8)
    index = _attachment_index(path)
    data = bytearray(path.read_bytes())
    data[data.index(b"hello attachment")] ^= 0x01
    path.write_bytes(bytes(data))
    said = LogReader(path).info().damaged_attachments["notes.txt"]
    assert f"at bytes {index.offset} to {index.offset + index.length} " in said


def test_an_attachment_stored_without_a_crc_reads_as_intact(tmp_path):
    """MCAP: a CRC of 0 means none was computed; the attachment is not damaged."""
    path = _log_with_note(tmp_path / "nocrc.mcap", b"kept as it is")
    index = _attachment_index(path)
    data = bytearray(path.read_bytes())
    crc_at = index.offset + index.length - 4
    data[crc_at : crc_at + 4] = bytes(4)
    path.write_bytes(bytes(data))
    info = LogReader(path).info()
    assert info.attachments == {"notes.txt": b"kept as it is"} and info.damaged_attachments == {}
