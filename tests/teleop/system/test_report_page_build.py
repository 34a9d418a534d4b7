"""``teleop report`` as a whole page and a command: estimates of a grasp the log never started get a
row of their own, the page says whether the display was recorded, a page that is not a report keeps
its pictures, and the screenshot's window, crop, Chromium's failure and the width limit."""

from __future__ import annotations

import argparse
import html
import importlib.util
import stat
from pathlib import Path

import cv2
import numpy as np
import pytest

import teleop.system.report as report_module
from teleop.errors import SessionLogError
from teleop.settings import load_settings
from teleop.system.report import (
    MAX_SCREENSHOT_PX,
    Report,
    ReportError,
    build_report,
    run_chromium,
    screenshot,
)
from teleop.system.report_data import GraspView

_spec = importlib.util.spec_from_file_location("_report_tests", Path(__file__).with_name("test_report.py"))
_report_tests = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(_report_tests)


def _estimate(t_s: float, grasp_id: str, e_pa: float = 2e6) -> tuple:
    return (t_s, 3, "estimate", {"grasp_id": grasp_id, "method": "auto", "E_pa": e_pa,
                                 "interval_pa": [e_pa / 2, e_pa * 2], "state": "ok", "reason": "test",
                                 "provisional": False, "latency_s": 0.0})


def _grasp(grasp_id: str, start_s: float) -> list[tuple]:
    return [(start_s, 0, "grasp_event", {"grasp_id": grasp_id, "event": "start", "object_name": "rubber_duck"}),
            _estimate(start_s + 0.5, grasp_id),
            (start_s + 1.0, 5, "grasp_event", {"grasp_id": grasp_id, "event": "end", "object_name": None})]


def test_estimates_and_renderings_of_a_grasp_the_log_never_started_are_shown_and_said_to_be(tmp_path):
    items = _grasp("g", 1.0) + [_estimate(3.5, "ghost", 5e5), (3.6, 4, "display", {
        "grasp_id": "ghost", "phase": "active", "stiffness": 0.5, "uncertainty_decades": 0.5, "rigid": False,
        "unknown": False, "provisional": False, "E_pa": 5e5, "level": 50, "level_max": 100})]
    log = _report_tests._record(tmp_path / "ghost.mcap", items, load_settings())
    report = build_report(log, tmp_path / "report")
    assert [v.grasp_id for v in report.views] == ["g", "ghost"]
    text = report.index.read_text(encoding="utf-8")
    _, *rows = _report_tests._Page(text).rows["summary"]
    assert [row[0] for row in rows] == ["g", "ghost"]
    assert rows[1][3] == "5e+05 Pa" and rows[1][6] == "0.50 of range (~5e+05 Pa)"
    page = html.unescape(text)
    assert "No frames, force or width to show: the log has no grasp_event start for this grasp id." in page
    assert "2 grasps; depth on the estimator's grid" in page and "display messages recorded" in page


def test_the_page_says_when_the_log_recorded_no_display_messages(tmp_path):
    log = _report_tests._record(tmp_path / "old.mcap", _grasp("g", 1.0), load_settings())
    page = html.unescape(build_report(log, tmp_path / "report").index.read_text(encoding="utf-8"))
    assert "display messages not recorded (the log has none)" in page
    assert "(not recorded: its mapping of the final estimate)" in page


def test_a_page_that_is_no_report_keeps_the_pictures_it_shows(tmp_path):
    log = _report_tests._record(tmp_path / "s.mcap", _grasp("g", 1.0), load_settings())
    out = tmp_path / "site"
    out.mkdir()
    (out / "grasp-photo.png").write_bytes(b"the user's photo")
    (out / "index.html").write_text('<html><head><title>My grasps</title></head><body><img src="grasp-photo.png">'
                                    "</body></html>", encoding="utf-8")
    build_report(log, out)
    assert (out / "grasp-photo.png").read_bytes() == b"the user's photo"


def _report(tmp_path: Path, figures: dict[str, tuple[int, int]], grasps: int) -> Report:
    return Report(tmp_path / "index.html", figures, [GraspView(f"g{k}") for k in range(grasps)])


def test_the_screenshot_window_is_the_figures_shown_heights_plus_room_for_text(tmp_path):
    figures = {"predictions.png": (650, 550), "grasp-g0-timeline.png": (2600, 1000)}
    # at 1000 px the content is 940 px wide: the wide figure is shown scaled down, the narrow one as it is
    expected = int(1.2 * (550 + 1000 * 940 / 2600) + 900 + 500 * 2)
    assert report_module._page_height_px(_report(tmp_path, figures, 2), 1000) == expected
    # at 1400 px the page's content stops at 1320 px
    expected = int(1.2 * (550 + 1000 * 1320 / 2600) + 900 + 500 * 2)
    assert report_module._page_height_px(_report(tmp_path, figures, 2), 1400) == expected
    assert report_module._page_height_px(_report(tmp_path, figures, 200), 1400) == MAX_SCREENSHOT_PX


def test_the_screenshot_cuts_the_blank_rows_below_the_page_leaving_a_margin(tmp_path, monkeypatch):
    report = _report(tmp_path, {"predictions.png": (650, 550)}, 1)
    report.index.write_text("<title>Grasp report: s.mcap</title>", encoding="utf-8")
    windows = []

    def chromium(page, *args, chromium=None, timeout_s=120.0):
        windows.append(next(a for a in args if a.startswith("--window-size=")))
        shot = next(a for a in args if a.startswith("--screenshot=")).removeprefix("--screenshot=")
        image = np.full((1000, 200, 3), 255, np.uint8)
        image[100:300] = 30  # the page's content ends at row 299
        cv2.imwrite(shot, image)
        return ""

    monkeypatch.setattr(report_module, "run_chromium", chromium)
    shot = screenshot(report, tmp_path / "page.png", width_px=800)
    image = cv2.imread(str(shot))
    assert image.shape[:2] == (299 + 40, 200)
    assert windows == [f"--window-size=800,{report_module._page_height_px(report, 800)}"]


def test_chromium_exiting_with_an_error_is_a_report_error_with_its_message(tmp_path):
    fake = tmp_path / "chromium"
    fake.write_text("#!/bin/sh\necho 'cannot open display' >&2\nexit 3\n")
    fake.chmod(fake.stat().st_mode | stat.S_IXUSR)
    page = tmp_path / "index.html"
    page.write_text("<p>page</p>", encoding="utf-8")
    with pytest.raises(ReportError, match="exited with 3: cannot open display"):
        run_chromium(page, "--dump-dom", chromium=str(fake))
    fake.write_text("#!/bin/sh\necho \"$@\"\n")
    said = run_chromium(page, "--dump-dom", chromium=str(fake))
    assert said.split()[-2:] == ["--dump-dom", page.resolve().as_uri()] and "--headless" in said


def test_the_screenshot_width_is_at_least_400_px(tmp_path):
    def args(width: int) -> argparse.Namespace:
        return argparse.Namespace(log=str(tmp_path / "missing.mcap"), out=str(tmp_path / "out"), objects=None,
                                  screenshot=None, width=width)

    with pytest.raises(ReportError, match="--width 399: expected at least 400 px"):
        report_module.run(args(399))
    with pytest.raises(SessionLogError):  # 400 px is enough: on to the (missing) log
        report_module.run(args(400))
