"""``teleop report`` (:mod:`teleop.system.report`): the felt error of an estimate shown unknown, notes
on the page, what a report draws and lets go of per grasp, a log without a started grasp, a write that
fails, and headless Chromium killed, slow or silent, and the screenshot's folder, crop and warning."""

from __future__ import annotations

import errno
import html
import importlib.util
import logging
import stat
from pathlib import Path
from types import SimpleNamespace

import cv2
import numpy as np
import pytest

import teleop.cli
import teleop.system.report as report_module
from estimator.evaluation.metrics import felt_pa
from haptics.settings import display_range_pa
from teleop.errors import SessionLogError
from teleop.settings import load_settings
from teleop.system.report import (
    Report,
    ReportError,
    _felt_cell,
    _felt_pa,
    _grasp_section,
    build_report,
    screenshot,
)
from teleop.system.report_data import EstimatePoint, GraspView

_spec = importlib.util.spec_from_file_location("_report_tests", Path(__file__).with_name("test_report.py"))
_report_tests = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(_report_tests)

RANGE = (5e3, 6.75e6)  # the shipped display's (e_soft_pa, e_rigid_pa)


def _finished(e_pa, interval, state="ok", **view) -> GraspView:
    grasp = GraspView("g", **view)
    grasp.estimates = [EstimatePoint(1.0, e_pa, interval, state, "test", False, "auto")]
    return grasp


# --------------------------------------------------------------------------- cells and sections


def test_without_the_display_an_estimate_whose_interval_spans_its_range_is_felt_unknown():
    wide = _finished(1e5, (1e3, 1e8), label_pa=1e5)
    assert _felt_pa(wide, False, RANGE) is None and _felt_cell(wide, False, RANGE) == "shown unknown"
    bound = _finished(6.75e6, (6.75e6, None), "lower_bound", label_pa=2e11)
    expected = felt_pa({"state": "lower_bound", "e_pa": 6.75e6, "low_pa": 6.75e6, "high_pa": None},
                       display_range_pa=RANGE)
    assert _felt_pa(bound, False, RANGE) == pytest.approx(expected)


def test_a_grasps_notes_are_on_its_section():
    view = GraspView("g", notes=["finger 'left': no frame before the contact onset"])
    section = html.unescape(_grasp_section(view, {}, recorded=True, display_range=RANGE))
    assert "<p class=\"note\">finger 'left': no frame before the contact onset</p>" in section


# --------------------------------------------------------------------------- build


_fixes_spec = importlib.util.spec_from_file_location("_report_fixes", Path(__file__).with_name("test_report_fixes.py"))
_fixes = importlib.util.module_from_spec(_fixes_spec)
_fixes_spec.loader.exec_module(_fixes)
small_log = _fixes.small_log  # one grasp of a rubber duck, estimated at 2e6 Pa, without frames


class _Drawing:
    """Stand-ins for the report's data and figures: one grasp with a record; what each was given."""

    def __init__(self, monkeypatch, *, moments: bool):
        self.record = SimpleNamespace(label=None, events={"grasp_start": 1.0})
        self.calls: list[tuple[str, object]] = []
        self.predictions: dict = {}
        self.moments = moments
        monkeypatch.setattr(report_module, "session_grasps",
                            lambda log, catalogue=None: [SimpleNamespace(grasp_id="g", record=self.record, reason="")])
        monkeypatch.setattr(report_module, "tactile_moments", self.tactile_moments)
        monkeypatch.setattr(report_module, "tactile_figure", self.figure("tactile"))
        monkeypatch.setattr(report_module, "timeline_figure", self.figure("timeline"))
        monkeypatch.setattr(report_module, "predictions_figure", self.predictions_figure)

    def tactile_moments(self, view, *, settings, calibrations):
        if self.moments:
            view.moments = ["a moment"]

    def figure(self, kind):
        def draw(view, path, **_):
            self.calls.append((kind, view.record))
            Path(path).write_bytes(b"png")
            return 10, 10
        return draw

    def predictions_figure(self, views, path, **options):
        self.predictions = options
        Path(path).write_bytes(b"png")
        return 10, 10


def test_a_grasp_without_tactile_moments_gets_a_timeline_and_no_tactile_sheet(small_log, tmp_path, monkeypatch):
    drawing = _Drawing(monkeypatch, moments=False)
    report = build_report(small_log, tmp_path / "report")
    assert [kind for kind, _ in drawing.calls] == ["timeline"]
    assert sorted(report.figures) == ["grasp-g-timeline.png", "predictions.png"]


def test_a_drawn_grasp_lets_go_of_its_frames_and_moments(small_log, tmp_path, monkeypatch):
    drawing = _Drawing(monkeypatch, moments=True)
    report = build_report(small_log, tmp_path / "report")
    assert drawing.calls == [("tactile", drawing.record), ("timeline", drawing.record)]
    (view,) = report.views
    assert view.record is None and view.moments == []


def test_the_predictions_figure_is_titled_with_the_log_and_drawn_on_the_displays_range(small_log, tmp_path,
                                                                                       monkeypatch):
    drawing = _Drawing(monkeypatch, moments=False)
    build_report(small_log, tmp_path / "report")
    settings = load_settings()
    assert drawing.predictions == {"session": "small.mcap", "display_range_pa": display_range_pa(settings)}


def test_a_figure_that_cannot_be_written_is_a_report_error_and_the_earlier_report_stays(small_log, tmp_path,
                                                                                      monkeypatch):
    out = tmp_path / "report"
    build_report(small_log, out)
    before = {p.name: p.read_bytes() for p in out.iterdir()}

    def full(views, path, **options):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(report_module, "predictions_figure", full)
    with pytest.raises(ReportError, match=f"cannot write the report into {out}: No space left on device"):
        build_report(small_log, out)
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before


def test_a_log_whose_grasps_never_started_is_refused_with_its_name(tmp_path):
    items = [item for item in _fixes._small_items() if item[2] == "estimate"]
    log = _report_tests._record(tmp_path / "ghosts.mcap", items, load_settings())
    with pytest.raises(SessionLogError, match=r"ghosts\.mcap: no grasp in the log"):
        build_report(log, tmp_path / "report")
    assert not (tmp_path / "report").exists()


# --------------------------------------------------------------------------- chromium


def _fake(tmp_path: Path, script: str) -> str:
    fake = tmp_path / "chromium"
    fake.write_text("#!/bin/sh\n" + script)
    fake.chmod(fake.stat().st_mode | stat.S_IXUSR)
    page = tmp_path / "index.html"
    page.write_text("<p>page</p>", encoding="utf-8")
    return str(fake)


def test_chromium_killed_by_a_signal_is_a_report_error(tmp_path):
    fake = _fake(tmp_path, "kill -9 $$\n")
    with pytest.raises(ReportError, match="exited with -9"):
        report_module.run_chromium(tmp_path / "index.html", "--dump-dom", chromium=fake)


def test_chromiums_error_shows_the_end_of_a_long_stderr(tmp_path):
    fake = _fake(tmp_path, "printf '%0800d' 0 >&2\necho 'cannot open display' >&2\nexit 1\n")
    with pytest.raises(ReportError, match="exited with 1: 0+cannot open display$") as caught:
        report_module.run_chromium(tmp_path / "index.html", "--dump-dom", chromium=fake)
    assert "0" * 481 in str(caught.value) and "0" * 482 not in str(caught.value)  # its last 500 characters


def test_chromium_running_past_its_time_is_a_report_error(tmp_path):
    fake = _fake(tmp_path, "exec sleep 30\n")
    with pytest.raises(ReportError, match=r"headless Chromium .* failed: .*timed out after 0\.3 seconds"):
        report_module.run_chromium(tmp_path / "index.html", "--dump-dom", chromium=fake, timeout_s=0.3)


def _report(tmp_path: Path, grasps: int = 1) -> Report:
    index = tmp_path / "report" / "index.html"
    index.parent.mkdir(parents=True)
    index.write_text("<title>Grasp report: s.mcap</title>", encoding="utf-8")
    return Report(index, {"predictions.png": (650, 550)}, [GraspView(f"g{k}") for k in range(grasps)])


def _chromium_writing(monkeypatch, image: np.ndarray | None) -> None:
    def run(page, *args, chromium=None, timeout_s=120.0):
        shot = next(a for a in args if a.startswith("--screenshot=")).removeprefix("--screenshot=")
        if image is not None:
            cv2.imwrite(shot, image)
        return ""
    monkeypatch.setattr(report_module, "run_chromium", run)


def test_chromium_writing_no_screenshot_is_a_report_error_and_the_earlier_one_stays(tmp_path, monkeypatch):
    earlier = tmp_path / "page.png"
    cv2.imwrite(str(earlier), np.zeros((10, 10, 3), np.uint8))
    before = earlier.read_bytes()
    _chromium_writing(monkeypatch, None)
    with pytest.raises(ReportError, match="wrote no readable screenshot for .*page.png"):
        screenshot(_report(tmp_path), earlier)
    assert earlier.read_bytes() == before


def test_a_screenshot_goes_into_a_folder_made_for_it(tmp_path, monkeypatch):
    _chromium_writing(monkeypatch, np.full((300, 200, 3), 200, np.uint8))
    shot = screenshot(_report(tmp_path), tmp_path / "new" / "deeper" / "page.png")
    assert shot == (tmp_path / "new" / "deeper" / "page.png").resolve()
    assert cv2.imread(str(shot)).shape == (300, 200, 3)


def test_the_screenshot_is_cut_below_the_content_even_under_a_dark_header(tmp_path, monkeypatch):
    image = np.full((1000, 200, 3), 255, np.uint8)
    image[:50] = 40  # a dark band at the top of the page
    image[100:300] = 30  # the content ends at row 299; white below
    _chromium_writing(monkeypatch, image)
    shot = screenshot(_report(tmp_path), tmp_path / "page.png")
    assert cv2.imread(str(shot)).shape[:2] == (299 + 40, 200)


def test_a_page_taller_than_the_screenshot_window_is_warned_about(tmp_path, monkeypatch, caplog):
    _chromium_writing(monkeypatch, np.full((300, 200, 3), 200, np.uint8))
    with caplog.at_level(logging.WARNING, logger=report_module.__name__):
        screenshot(_report(tmp_path, grasps=200), tmp_path / "tall.png")
    assert f"taller than the screenshot's {report_module.MAX_SCREENSHOT_PX} px" in caplog.text
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger=report_module.__name__):
        screenshot(_report(tmp_path / "short"), tmp_path / "short.png")
    assert "taller than" not in caplog.text


@pytest.mark.parametrize("shot", ["report", "."])
def test_a_screenshot_at_the_reports_folder_to_be_is_refused_before_the_report_is_drawn(small_log, tmp_path,
                                                                                       capsys, shot):
    out = tmp_path / "new" / "report"
    code = teleop.cli.main(["report", str(small_log), "--out", str(out), "--screenshot", str(out / ".." / shot)])
    err = capsys.readouterr().err
    assert code == 2 and "--screenshot" in err and "is the report's folder" in err and "expected" in err
    assert not (tmp_path / "new").exists()
