"""``teleop report``'s felt error: what the display rendered for each grasp, as ``teleop demo`` scores
it; a grasp it rendered nothing for is not rendered, however good its final estimate; a rigid rendering
is shown and felt at the display range's rigid end."""

from __future__ import annotations

import html
import importlib.util
from pathlib import Path

import numpy as np
import pytest

from teleop.catalogue import load_catalogue
from teleop.settings import load_settings
from teleop.sim.grasp import simulate_grasp
from teleop.system.report import _display_cell, _felt_pa, build_report
from teleop.system.report_data import DisplayPoint, GraspView

_spec = importlib.util.spec_from_file_location("_report_tests", Path(__file__).with_name("test_report.py"))
_report_tests = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(_report_tests)


def _report(folder: Path, *, display: bool):
    """Two ducks with a final estimate of 3e6 Pa each: the display rendered the first (when ``display``
    is set, at 3e6 Pa), and nothing for the second (the renderer was gone)."""
    settings = load_settings()
    duck = next(o for o in load_catalogue() if o.name == "rubber_duck")
    record, _ = simulate_grasp(duck, settings=settings, rng=np.random.default_rng(1), seed=1)
    items = _report_tests._grasp_messages(record, "g-shown", 100.0, [(3e6, [1.5e6, 6e6], "ok", False)],
                                          display=display)
    items += _report_tests._grasp_messages(record, "g-unshown", 110.0, [(3e6, [1.5e6, 6e6], "ok", False)],
                                           display=False)
    report = build_report(_report_tests._record(folder / "felt.mcap", items, settings), folder / "report")
    text = html.unescape(report.index.read_text(encoding="utf-8"))
    _, *rows = _report_tests._Page(report.index.read_text(encoding="utf-8")).rows["summary"]
    return {row[0]: row for row in rows}, text


@pytest.mark.slow  # a whole report: 2.5 s
def test_a_grasp_the_display_rendered_nothing_for_has_no_felt_error(tmp_path):
    rows, text = _report(tmp_path, display=True)
    offset = f"{np.log10(3e6 / 3.61e6):+.2f}"
    assert rows["g-shown"][6:] == ["0.30 of range (~3e+06 Pa)", offset]
    assert rows["g-unshown"][3] == "3e+06 Pa"  # a final estimate, never rendered
    assert rows["g-unshown"][6:] == ["nothing for this grasp", "not rendered"]
    assert (f"Felt (display against the label on its range): mean error {abs(float(offset)):.2f} decades, "
            "1 of 2 within a factor 2, 0 dangerous misses, 1 not rendered.") in text


@pytest.mark.slow  # a whole report: 2.5 s
def test_without_display_messages_the_felt_error_is_the_mappings_and_says_so(tmp_path):
    rows, text = _report(tmp_path, display=False)
    offset = f"{np.log10(3e6 / 3.61e6):+.2f}"
    assert [row[6:] for row in rows.values()] == [["not recorded", offset]] * 2
    assert ("2 of 2 within a factor 2, 0 dangerous misses; the log has no display messages: felt as the "
            "display's mapping renders the final estimates.") in text


def test_a_rigid_rendering_still_ramping_when_the_grasp_ends_is_shown_and_felt_at_the_rigid_end():
    """The renderer's last active message of a rigid grasp may be mid-ramp (stiffness 0.9992, E 6.716e6
    Pa): the report shows and scores the rigid end, as the demo's table does (``rigid >=6.75e+06``)."""
    display_range = (5e3, 6.75e6)
    view = GraspView("g-steel", label_pa=2e11)
    view.display = [DisplayPoint(1.0, "active", 0.9992, 6.716e6, True, False, False),
                    DisplayPoint(1.5, "fading", 0.4, None, False, False, False)]
    assert _display_cell(view, True, display_range) == "rigid (\u2265 6.75e+06 Pa)"
    assert _felt_pa(view, True, display_range) == 6.75e6  # exact for a steel ball: +0.00 decades
