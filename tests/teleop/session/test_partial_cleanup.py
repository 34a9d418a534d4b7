"""An interrupt (Ctrl-C, or SIGTERM under the commands) leaves no temporary file behind: a record being
written, a log being recovered, an export's folder made for it."""

from __future__ import annotations

import importlib

import pytest

import teleop.record
from teleop.record import write_record
from teleop.session import export_session, recover

RECOVER = importlib.import_module("teleop.session.recover")  # the package's `recover` is the function


def _interrupt(*args, **kwargs):
    raise KeyboardInterrupt


def test_an_interrupted_record_leaves_no_temporary(tmp_path, monkeypatch):
    from tests.teleop.test_record import make_record

    record = make_record("png")
    monkeypatch.setattr(teleop.record, "_npy_bytes", _interrupt)  # mid-write: the zip is open
    with pytest.raises(KeyboardInterrupt):
        write_record(record, tmp_path / "a.grasp")
    assert list(tmp_path.iterdir()) == []


def test_an_interrupted_recovery_leaves_no_temporary(tmp_path, recorded, monkeypatch):
    real = RECOVER._copy

    def copy_then_interrupt(reader, writer, report, bar):
        real(reader, writer, report, bar)  # the temporary is written, then Ctrl-C
        raise KeyboardInterrupt

    monkeypatch.setattr(RECOVER, "_copy", copy_then_interrupt)
    with pytest.raises(KeyboardInterrupt):
        recover(recorded.path, tmp_path / "fixed.mcap")
    assert list(tmp_path.iterdir()) == []


def test_an_interrupted_export_leaves_no_temporary_nor_the_folder_it_made(tmp_path, recorded, monkeypatch):
    monkeypatch.setattr(teleop.record, "_npy_bytes", _interrupt)
    with pytest.raises(KeyboardInterrupt):
        export_session(recorded.path, tmp_path / "ex")
    assert list(tmp_path.iterdir()) == []
