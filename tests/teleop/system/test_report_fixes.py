"""``teleop report``: odd grasp ids and object names, a second report into a folder, its signed felt
error and units, and what --screenshot may and may not write over."""

from __future__ import annotations

import hashlib
import html
import importlib.util
from pathlib import Path

import cv2
import numpy as np
import pytest

import teleop.cli
import teleop.system.report as report_module
from teleop.catalogue import load_catalogue
from teleop.settings import load_settings
from teleop.sim.grasp import simulate_grasp
from teleop.system.report import ReportError, _anchor, build_report, screenshot
from teleop.system.report_data import EstimatePoint, GraspView
from teleop.system.report_figures import predictions_figure

_spec = importlib.util.spec_from_file_location("_report_tests", Path(__file__).with_name("test_report.py"))
_report_tests = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(_report_tests)
_Page = _report_tests._Page

LONG_ID = "s" * 240 + "-001"  # a grasp id of a scene file named with 240 characters
ODD_IDS = ("a.1", "a 1", "$x^{$", LONG_ID)


def _small_items(grasp_id: str = "g", object_name: str = "rubber_duck"):
    return [(1.0, 0, "grasp_event", {"grasp_id": grasp_id, "event": "start", "object_name": object_name}),
            (1.5, 3, "estimate", {"grasp_id": grasp_id, "method": "auto", "E_pa": 2e6, "interval_pa": [1e6, 4e6],
                                  "state": "ok", "reason": "test", "provisional": False, "latency_s": 0.0}),
            (2.0, 5, "grasp_event", {"grasp_id": grasp_id, "event": "end", "object_name": None})]


@pytest.fixture(scope="module")
def small_log(tmp_path_factory) -> Path:
    """One grasp of a rubber duck, estimated at 2e6 Pa, without frames (no grasp figures)."""
    return _report_tests._record(tmp_path_factory.mktemp("small") / "small.mcap", _small_items(), load_settings())


@pytest.fixture(scope="module")
def small_report(small_log, tmp_path_factory):
    return build_report(small_log, tmp_path_factory.mktemp("small-report") / "report")


@pytest.fixture(scope="module")
def odd_report(tmp_path_factory):
    """One simulated duck grasped under each of :data:`ODD_IDS`: ids that clean to one anchor, mathtext,
    and an id too long for a file name."""
    settings = load_settings()
    duck = next(o for o in load_catalogue() if o.name == "rubber_duck")
    record, _ = simulate_grasp(duck, settings=settings, rng=np.random.default_rng(1), seed=1)
    items = []
    for k, grasp_id in enumerate(ODD_IDS):
        items += _report_tests._grasp_messages(record, grasp_id, 100.0 + 10 * k,
                                               [(2e6 * (k + 1), [1e6, 9e6], "ok", False)], display=False)
    folder = tmp_path_factory.mktemp("odd")
    log = _report_tests._record(folder / "odd.mcap", items, settings)
    return build_report(log, folder / "report")


@pytest.mark.slow
def test_distinct_odd_and_long_grasp_ids_get_their_own_figures_and_anchors(odd_report):
    page = _Page(odd_report.index.read_text(encoding="utf-8"))
    _, *rows = page.rows["summary"]
    assert [row[0] for row in rows] == list(ODD_IDS)
    timelines = sorted(name for name in odd_report.figures if name.endswith("-timeline.png"))
    assert len(timelines) == len(ODD_IDS)  # none drawn over another's
    for name in odd_report.figures:
        assert len(name.encode()) < 120 and (odd_report.index.parent / name).is_file(), name
    anchors = [link for link in page.links if link.startswith("#")]
    assert len(set(anchors)) == len(ODD_IDS)
    long_anchor = _anchor(GraspView(LONG_ID))
    assert long_anchor.startswith("grasp-" + "s" * 60)  # still readable
    assert hashlib.sha256(LONG_ID.encode()).hexdigest()[:10] in long_anchor
    # the four final estimates (2, 4, 6, 8 MPa), one to each grasp's own timeline
    assert [row[3] for row in rows] == ["2e+06 Pa", "4e+06 Pa", "6e+06 Pa", "8e+06 Pa"]


def test_anchors_of_ids_that_clean_alike_differ():
    ids = ["a.1", "a 1", "a_1", "a\u00e41", "a\u00f61", "g-duck", "x" * 300, "x" * 300 + "y"]
    anchors = [_anchor(GraspView(i)) for i in ids]
    assert len(set(anchors)) == len(ids)
    assert _anchor(GraspView("g-duck")) == "grasp-g-duck" and _anchor(GraspView("a_1")) == "grasp-a_1"
    assert all(len(a) < 90 for a in anchors)


def test_ids_that_differ_only_in_case_get_figures_of_their_own_on_any_file_system():
    ids = ["g-A", "g-a", "G-a"]
    names = {f"{_anchor(GraspView(i))}-timeline.png".casefold() for i in ids}  # macOS, Windows: one file
    assert len(names) == len(ids)
    assert _anchor(GraspView("g-a")) == "grasp-g-a"  # a lower-case id stays as it is


def test_dollar_signs_in_object_names_are_drawn_as_text(tmp_path):
    views = []
    for k, name in enumerate(("$x^{$", "$\\frac$", "price $5 and $6")):
        view = GraspView(f"$g{k}$", object_name=name, label_pa=1e6 * (k + 1))
        view.estimates.append(EstimatePoint(1.0, 2e6, (1e6, 4e6), "ok", "test", False, "auto"))
        views.append(view)
    width, height = predictions_figure(views, tmp_path / "predictions.png")
    assert cv2.imread(str(tmp_path / "predictions.png")).shape[:2] == (height, width)


@pytest.mark.slow
def test_the_felt_error_is_signed_and_label_e_has_its_unit(odd_report):
    text = odd_report.index.read_text(encoding="utf-8")
    _, *rows = _Page(text).rows["summary"]
    assert {row[2] for row in rows} == {"3.61e+06 Pa"}  # label E, as the neighbouring columns: with its unit
    felt = [row[7] for row in rows]
    assert all(f == format(float(f), "+.2f") for f in felt), felt
    assert float(felt[0]) < 0 < float(felt[1])  # 2e6 Pa felt softer than the duck's 3.61e6, 4e6 Pa stiffer
    assert "live session's final estimates" in html.unescape(text)


def test_a_second_report_does_not_keep_another_reports_figures(small_log, tmp_path):
    out = tmp_path / "report"
    out.mkdir()
    for name in ("grasp-other-log-timeline.png", "grasp-other-log-tactile.png", "predictions.png"):
        (out / name).write_bytes(b"another log's report")
    (out / "index.html").write_text(_earlier_page("grasp-other-log-timeline.png", "grasp-other-log-tactile.png",
                                                  "predictions.png"), encoding="utf-8")
    (out / "notes.txt").write_text("mine")
    build_report(small_log, out)
    assert sorted(p.name for p in out.iterdir()) == ["index.html", "notes.txt", "predictions.png"]
    assert (out / "notes.txt").read_text() == "mine"


def _earlier_page(*figures: str) -> str:
    """An earlier report's index.html (of another log) showing ``figures``."""
    images = "".join(report_module._figure(name, (10, 10), name, name) for name in figures)
    return (f'<!DOCTYPE html><html lang="en"><head><meta charset="utf-8"><title>Grasp report: other.mcap</title>'
            f"</head><body>{images}</body></html>")


def test_a_report_keeps_the_users_files_that_merely_look_like_its_figures(small_log, tmp_path, capsys):
    out = tmp_path / "report"
    out.mkdir()
    (out / "grasp-notes.png").write_bytes(b"the user's own picture")
    (out / "grasp-old-timeline.png").write_bytes(b"an earlier report's figure")
    (out / "index.html").write_text(_earlier_page("grasp-old-timeline.png"), encoding="utf-8")
    build_report(small_log, out)
    assert sorted(p.name for p in out.iterdir()) == ["grasp-notes.png", "index.html", "predictions.png"]
    assert (out / "grasp-notes.png").read_bytes() == b"the user's own picture"
    build_report(small_log, out)  # again, over its own report
    assert sorted(p.name for p in out.iterdir()) == ["grasp-notes.png", "index.html", "predictions.png"]
    with pytest.raises(SystemExit):
        teleop.cli.main(["report", "--help"])
    assert "keeps every other file" in " ".join(capsys.readouterr().out.split())


def test_a_calibration_that_cannot_be_written_to_a_temporary_folder_is_a_report_error(small_log, tmp_path,
                                                                                       monkeypatch):
    import errno

    def file_too_large(self, data):
        raise OSError(errno.EFBIG, "File too large")

    monkeypatch.setattr(Path, "write_bytes", file_too_large)
    with pytest.raises(ReportError, match="calibration .* temporary folder .*teleop-report-calibration-.*File too large"):
        build_report(small_log, tmp_path / "report")
    assert list(tmp_path.iterdir()) == []


def test_a_failed_report_leaves_no_empty_folder(small_log, tmp_path):
    out = tmp_path / "new" / "deeper" / "report"
    with pytest.raises(Exception, match="nonexistent"):
        build_report(small_log, out, catalogue=tmp_path / "nonexistent.toml")
    assert list(tmp_path.iterdir()) == []


def test_out_naming_a_file_is_a_clear_error(small_log, tmp_path):
    (tmp_path / "afile").write_text("x")
    with pytest.raises(ReportError, match="--out .*afile.*expected a folder"):
        build_report(small_log, tmp_path / "afile")
    assert (tmp_path / "afile").read_text() == "x"


def _fake_chromium(monkeypatch, *, fail: bool = False):
    def run(page, *args, chromium=None, timeout_s=120.0):
        if fail:
            raise ReportError("headless Chromium failed (test)")
        shot = next(a for a in args if a.startswith("--screenshot=")).removeprefix("--screenshot=")
        cv2.imwrite(shot, np.full((300, 200, 3), 200, np.uint8))
        return ""
    monkeypatch.setattr(report_module, "run_chromium", run)


def test_a_screenshot_never_writes_over_the_log_the_page_or_other_files(small_log, small_report, tmp_path,
                                                                         monkeypatch):
    _fake_chromium(monkeypatch)
    log_bytes, page_bytes = small_log.read_bytes(), small_report.index.read_bytes()
    other = tmp_path / "notes.txt"
    other.write_text("mine")
    for target, reason in ((small_log, "session log"), (small_report.index, "report's own files"),
                           (small_report.index.parent / "predictions.png", "report's own files"),
                           (other, "not a PNG")):
        with pytest.raises(ReportError, match=f"--screenshot .*{reason}"):
            screenshot(small_report, target)
    assert small_log.read_bytes() == log_bytes and small_report.index.read_bytes() == page_bytes
    assert other.read_text() == "mine"
    shot = screenshot(small_report, tmp_path / "page.png")
    assert cv2.imread(str(shot)) is not None
    assert sorted(p.name for p in tmp_path.iterdir()) == ["notes.txt", "page.png"]  # no temporaries left


def test_a_failed_screenshot_leaves_the_earlier_one(small_report, tmp_path, monkeypatch):
    earlier = tmp_path / "page.png"
    cv2.imwrite(str(earlier), np.zeros((10, 10, 3), np.uint8))
    before = earlier.read_bytes()
    _fake_chromium(monkeypatch, fail=True)
    with pytest.raises(ReportError, match="failed"):
        screenshot(small_report, earlier)
    assert earlier.read_bytes() == before


def test_bad_screenshot_paths_are_clear_errors(small_report, small_log, tmp_path, capsys):
    (tmp_path / "afile").write_text("x")
    (tmp_path / "adir").mkdir()
    for target, expected in ((tmp_path / "afile" / "page.png", "is a file, not a folder"),
                             (tmp_path / "adir", "is a folder")):
        with pytest.raises(ReportError, match=f"--screenshot .*{expected}.*expected"):
            screenshot(small_report, target)
    # the command checks it before drawing the report: nothing is written
    out = tmp_path / "report"
    assert teleop.cli.main(["report", str(small_log), "--out", str(out), "--screenshot",
                            str(out / "index.html")]) == 2
    err = capsys.readouterr().err
    assert "--screenshot" in err and "Traceback" not in err and not out.exists()
