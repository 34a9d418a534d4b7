"""What ``teleop report`` gathers of a grasp (:mod:`teleop.system.report_data`): a second start event
without a name, a start at time zero, and the log's calibrations read back through temporary folders
that are removed, or refused naming the folder they could not be made in."""

from __future__ import annotations

import errno
import tempfile
from pathlib import Path
from types import SimpleNamespace

import pytest
from support.session_logs import ListedLog, logged

import teleop.system.report_data as report_data
from teleop.settings import load_settings
from teleop.system.report_data import (
    EstimatePoint,
    GraspView,
    ReportError,
    grasp_messages,
    log_calibrations,
)


def test_a_start_event_without_an_object_name_keeps_the_name_an_earlier_start_gave():
    reader = ListedLog([logged("grasp_event", 1.0, event="start", object_name="duck"),
                      logged("grasp_event", 2.0, event="start", object_name=None)])
    views, recorded = grasp_messages(reader)
    assert views["g"].object_name == "duck" and recorded is False


def test_an_estimates_interval_keeps_its_low_and_high_ends_in_order():
    reader = ListedLog([logged("estimate", 1.5, E_pa=2e6, interval_pa=[1e6, 4e6], state="ok", reason="",
                              provisional=False, method="auto")])
    (view,) = grasp_messages(reader)[0].values()
    assert view.estimates[0].interval_pa == (1e6, 4e6)


def test_a_start_event_at_time_zero_is_the_time_origin():
    view = GraspView("g", start_s=0.0)
    view.estimates = [EstimatePoint(5.0, 1e6, (None, None), "ok", "", False, "auto")]
    assert view.t0_s == 0.0


@pytest.fixture(scope="module")
def settings():
    return load_settings()


def _attachments(settings) -> dict[str, bytes]:
    return {f"calibration/{s.finger}/{Path(s.calibration).name}": Path(s.calibration).read_bytes()
            for s in settings.sensors}


def test_the_logs_calibrations_are_read_back_through_temporary_folders_that_are_removed(settings, tmp_path,
                                                                                        monkeypatch):
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    found = log_calibrations(SimpleNamespace(attachments=_attachments(settings)), settings)
    assert sorted(found) == sorted(s.finger for s in settings.sensors)
    assert not any(isinstance(c, str) for c in found.values())
    assert list(tmp_path.iterdir()) == []


def test_a_finger_whose_calibration_the_log_lacks_is_named_and_the_other_is_read(settings):
    attachments = _attachments(settings)
    dropped = next(name for name in attachments if name.startswith("calibration/right/"))
    del attachments[dropped]
    found = log_calibrations(SimpleNamespace(attachments=attachments), settings)
    assert found["right"] == "the log carries no calibration for finger 'right'"
    assert not isinstance(found["left"], str)


def test_a_temporary_folder_that_cannot_be_made_is_a_report_error_naming_where(settings, monkeypatch):
    def full(prefix=None, **_):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(report_data.tempfile, "mkdtemp", full)
    with pytest.raises(ReportError, match=r"cannot make a temporary folder for the log's calibration "
                                          r"calibration/left/.* \(in .*\): No space left on device"):
        log_calibrations(SimpleNamespace(attachments=_attachments(settings)), settings)
