"""``teleop report``: a session log as a web page to look at and share.

``teleop report LOG --out DIR`` writes ``DIR/index.html`` and, beside it, the PNG figures it
shows through relative links: the folder is the report (copy or zip it whole; a single PNG can
be shared on its own), it needs no network and no JavaScript, and the page stays small and
quick to open however many grasps the session has (inline base64 would make it a third larger
and the figures harder to pass around alone).

The page starts with a summary table (one row per grasp: object, label E, final estimate,
interval, state, what the display rendered, the felt error) and the final estimates against their
labels (log-log, factor-2 band); then, per grasp, the final state and its reason, the tactile
frames of each finger before contact, mid-loading and at the peak force with the depth the
estimator's perception reconstructs from them (:mod:`teleop.system.report_data`), and force,
width, the provisional and final estimates with their intervals, and what the display rendered
(``display`` messages; older logs have none, and the page says so) over time
(:mod:`teleop.system.report_figures`).

``--screenshot PNG`` also renders the written page in headless Chromium, the whole page (blank
rows below the content cut off), so the report can be checked or shared as one picture.
"""

from __future__ import annotations

import argparse
import hashlib
import html
import logging
import re
import shutil
import subprocess
import tempfile
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from estimator.evaluation.metrics import felt_log10_offset, felt_pa
from estimator.settings import estimator_settings
from haptics.settings import display_range_pa
from teleop.errors import SessionLogError
from teleop.progress import progress_bar
from teleop.session.export import session_grasps
from teleop.session.logfile import LogReader
from teleop.staging import staged, staged_dir
from teleop.system.demo_table import felt_figures, felt_text, rigid_pa, signed_decades
from teleop.system.outcome import display_felt_pa
from teleop.system.report_data import (
    GraspView,
    ReportError,
    grasp_messages,
    log_calibrations,
    tactile_moments,
)
from teleop.system.report_figures import predictions_figure, tactile_figure, timeline_figure

__all__ = ["Report", "ReportError", "build_report", "check_screenshot_path", "find_chromium", "run_chromium",
           "screenshot"]

CHROMIUM_NAMES = ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable")
CHROMIUM_FLAGS = ("--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
                  "--disable-component-update", "--disable-sync", "--no-first-run", "--hide-scrollbars")
MAX_SCREENSHOT_PX = 32000  # the tallest window tried (Chromium 150 renders it whole, ~10 s); a longer page is cut
_BOUND = {"lower_bound": "\u2265 ", "upper_bound": "\u2264 "}
DASH, INFINITY = "\u2013", "\u221e"
# The names of the files a report writes into its folder (a screenshot is never one of them). An
# earlier report's figures are not kept beside a new one: only those its index.html shows go.
_OWN_FILE = re.compile(r"index\.html|predictions\.png|grasp-.*\.png")
_PAGE_TITLE = "<title>Grasp report: "
_IMG_SRC = re.compile(r'<img src="([^"]*)"')
_PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
# A grasp's anchor (and the start of its figures' names) keeps at most this many characters of its id.
_ANCHOR_CHARS = 64


log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Report:
    """A written report: its page, its figures (name: (width, height) px) and its grasps."""

    index: Path
    figures: dict[str, tuple[int, int]]
    views: list[GraspView]
    log: Path | None = None


# --------------------------------------------------------------------------- cells


def _pa(value: float | None) -> str:
    return DASH if value is None else f"{value:.3g}"


def _final_cell(view: GraspView) -> str:
    final = view.final
    if final is None:
        return "no final estimate"
    return DASH if final.e_pa is None else f"{_BOUND.get(final.state, '')}{_pa(final.e_pa)} Pa"


def _interval_cell(view: GraspView) -> str:
    final = view.final
    if final is None or final.interval_pa == (None, None):
        return DASH
    low, high = final.interval_pa
    return f"[{'0' if low is None else _pa(low)}, {INFINITY if high is None else _pa(high)}] Pa"


def _display_cell(view: GraspView, recorded: bool, display_range: tuple[float, float]) -> str:
    """What the display settled on for the grasp: ``unknown (free)``, ``rigid`` at the rigid end of
    its range ``display_range`` (as ``teleop demo`` shows it: :func:`~teleop.system.demo_table.rigid_pa`),
    or the fraction of its range with the modulus it stands for; ``not recorded`` for a log without
    display messages."""
    if not recorded:
        return "not recorded"
    d = view.rendered
    if d is None:
        return "nothing for this grasp"
    if d.unknown:
        return "unknown (free)"
    if d.rigid:
        return f"rigid (\u2265 {_pa(rigid_pa(display_range))} Pa)"
    return f"{d.stiffness:.2f} of range" + ("" if d.e_pa is None else f" (~{_pa(d.e_pa)} Pa)")


def _felt_pa(view: GraspView, recorded: bool, display_range: tuple[float, float]) -> float | None:
    """The modulus the operator felt for the grasp. With the display recorded: what it rendered
    (:attr:`GraspView.rendered`, read as ``teleop demo`` reads it: a rigid rendering at the rigid end
    of ``display_range``); None when it rendered nothing for the grasp or showed the modulus unknown.
    Without: the display's mapping of the final estimate (as ``estimator evaluate`` scores it); None
    without a final estimate, for a refusal and when shown unknown."""
    if recorded:
        rendered = view.rendered
        if rendered is None:
            return None
        if rendered.rigid and not rendered.unknown:  # its last message may still be ramping up to the end
            return rigid_pa(display_range)
        return display_felt_pa(rendered.e_pa, unknown=rendered.unknown, e_soft_pa=display_range[0])
    final = view.final
    if final is None or final.e_pa is None:
        return None
    row = {"state": final.state, "e_pa": final.e_pa, "low_pa": final.interval_pa[0], "high_pa": final.interval_pa[1]}
    return felt_pa(row, display_range_pa=display_range)


def _felt_cell(view: GraspView, recorded: bool, display_range: tuple[float, float]) -> str:
    if not view.label_pa:
        return DASH
    if recorded and view.rendered is None:
        return "not rendered"
    if not recorded and (view.final is None or view.final.e_pa is None):
        return DASH
    felt = _felt_pa(view, recorded, display_range)
    if felt is None:
        return "shown unknown"
    return signed_decades(felt_log10_offset(felt, view.label_pa, display_range_pa=display_range))  # as the demo's


def _felt_line(views: Sequence[GraspView], recorded: bool, display_range: tuple[float, float]) -> str:
    """What the operator felt over the labelled grasps: the demo's closing line; without the display
    recorded, it says the felt errors are the mapping's of the final estimates."""
    labelled = [v for v in views if v.label_pa]
    felt = [(v.label_pa, f) for v in labelled if (f := _felt_pa(v, recorded, display_range)) is not None]
    line = felt_text(felt_figures(felt, display_range, grasps=len(labelled)))
    if not recorded:
        line += "; the log has no display messages: felt as the display's mapping renders the final estimates"
    return f"<p>{_e(line[:1].upper() + line[1:])}.</p>" if labelled else ""


# --------------------------------------------------------------------------- page

_CSS = """
body { font-family: system-ui, sans-serif; color: #222; background: #fff; max-width: 1320px;
       margin: 1.5em auto; padding: 0 1em; }
h1 { margin-bottom: 0.2em; } h2 { margin-top: 2em; border-bottom: 1px solid #ccc; }
table { border-collapse: collapse; margin: 0.8em 0; font-size: 14px; }
th, td { border: 1px solid #ccc; padding: 4px 8px; text-align: left; vertical-align: top; }
th { background: #f2f2f2; } td.num { text-align: right; font-variant-numeric: tabular-nums; }
table.facts th { width: 12em; } .reason { max-width: 70em; font-size: 13px; }
img { max-width: 100%; height: auto; display: block; margin: 0.5em 0; }
.note { color: #8a4b00; } .meta { color: #555; font-size: 13px; }
figure { margin: 1em 0; } figcaption { color: #555; font-size: 13px; }
"""


def _e(text: object) -> str:
    return html.escape(str(text))


def _figure(name: str, size: tuple[int, int], alt: str, caption: str) -> str:
    return (f'<figure><img src="{_e(name)}" width="{size[0]}" height="{size[1]}" alt="{_e(alt)}">'
            f"<figcaption>{_e(caption)}</figcaption></figure>")


def _summary(views: Sequence[GraspView], recorded: bool, display_range: tuple[float, float]) -> str:
    head = ("grasp", "object", "label E", "final estimate", "interval", "state", "display rendered",
            "felt error (dec)")
    rows = []
    for v in views:
        final = v.final
        cells = (f'<a href="#{_e(_anchor(v))}">{_e(v.grasp_id)}</a>', _e(v.object_name or DASH),
                 _e(DASH if v.label_pa is None else f"{_pa(v.label_pa)} Pa"), _e(_final_cell(v)), _e(_interval_cell(v)),
                 _e(final.state if final else DASH), _e(_display_cell(v, recorded, display_range)),
                 _e(_felt_cell(v, recorded, display_range)))
        rows.append("<tr>" + "".join(
            f'<td class="num">{c}</td>' if i in (2, 3, 7) else f"<td>{c}</td>" for i, c in enumerate(cells)
        ) + "</tr>")
    return ('<table class="summary"><thead><tr>' + "".join(f"<th>{_e(h)}</th>" for h in head)
            + "</tr></thead><tbody>" + "".join(rows) + "</tbody></table>" + _felt_line(views, recorded, display_range))


def _anchor(view: GraspView) -> str:
    """``grasp-<id>``, the page's anchor of a grasp and the start of its figures' names. An id that
    is not all lower-case ASCII letters, digits, ``_`` and ``-``, or longer than :data:`_ANCHOR_CHARS`, has the
    rest replaced by ``_``, is cut, and gets ``.`` and a short hash of the whole id (``.`` never
    stays in a cleaned id), so that distinct ids (``a.1``, ``a 1``, ``a_1``) never share one."""
    grasp_id = view.grasp_id
    clean = re.sub(r"[^A-Za-z0-9_-]+", "_", grasp_id)
    # a capital too: on a case-blind file system (macOS, Windows) g-A's figures would overwrite g-a's
    if clean == grasp_id.lower() and len(clean) <= _ANCHOR_CHARS:
        return f"grasp-{clean}"
    digest = hashlib.sha256(grasp_id.encode("utf-8", "surrogateescape")).hexdigest()[:10]
    return f"grasp-{clean[:_ANCHOR_CHARS]}.{digest}"


def _grasp_section(view: GraspView, figures: dict[str, tuple[int, int]], recorded: bool,
                   display_range: tuple[float, float]) -> str:
    anchor, final = _anchor(view), view.final
    label = f"{_pa(view.label_pa)} Pa ({view.label_source})" if view.label_pa else f"{DASH} (no label)"
    facts = [("label E", label),
             ("final estimate", _final_cell(view) + (f" ({final.method})" if final else "")),
             ("interval", _interval_cell(view)),
             ("final state", final.state if final else "no final estimate"),
             ("reason", final.reason if final else DASH),
             ("display rendered", _display_cell(view, recorded, display_range)),
             ("estimates", f"{len(view.estimates)} ({sum(e.provisional for e in view.estimates)} provisional)")]
    parts = [f'<section id="{_e(anchor)}"><h2>Grasp {_e(view.grasp_id)}: {_e(view.object_name or "unnamed")}</h2>',
             '<table class="facts">' + "".join(
                 f'<tr><th>{_e(k)}</th><td{" class=reason" if k == "reason" else ""}>{_e(v)}</td></tr>'
                 for k, v in facts) + "</table>"]
    if view.reason:
        parts.append(f'<p class="note">No frames, force or width to show: {_e(view.reason)}.</p>')
    parts += [f'<p class="note">{_e(note)}</p>' for note in view.notes]
    if f"{anchor}-tactile.png" in figures:
        parts.append(_figure(f"{anchor}-tactile.png", figures[f"{anchor}-tactile.png"], "tactile frames and depth",
                             "Each finger's frame (warped and cropped onto the depth grid) and the depth the "
                             "estimator's perception reconstructs from it with the calibration the log carries."))
    if f"{anchor}-timeline.png" in figures:
        shown = ("What the display rendered: the bottom panel (fraction of its range) and the orange step "
                 "in the estimate panel (the modulus that fraction stands for)." if view.display
                 else "What the display rendered: " + _display_cell(view, recorded, display_range) + ".")
        parts.append(_figure(f"{anchor}-timeline.png", figures[f"{anchor}-timeline.png"], "force, width, estimates",
                             "Force and width; provisional (small) and final (large) estimates with their "
                             "intervals on a log scale against the label (dashed). " + shown))
    return "".join(parts) + "</section>"


def _page(log: Path, info_lines: Sequence[str], views: Sequence[GraspView], figures: dict[str, tuple[int, int]],
          recorded: bool, display_range: tuple[float, float]) -> str:
    return "".join([
        '<!DOCTYPE html><html lang="en"><head><meta charset="utf-8">',
        f"<title>Grasp report: {_e(log.name)}</title><style>{_CSS}</style></head><body>",
        f"<h1>Grasp report: {_e(log.name)}</h1>",
        '<p class="meta">' + "<br>".join(_e(line) for line in info_lines) + "</p>",
        "<h2>Summary</h2>",
        '<p class="meta">The estimates are the live session\'s final estimates, as the estimator published '
        "them during the session (`estimator estimate` on the exported records may differ). Felt error: "
        "decades from the label (clipped to the display's range) to what the display rendered"
        + ("" if recorded else " (not recorded: its mapping of the final estimate)")
        + "; negative: felt softer than the label.</p>",
        _summary(views, recorded, display_range),
        _figure("predictions.png", figures["predictions.png"], "predictions versus label",
                "Final estimates against their labels (log-log); grey: within a factor 2."),
        *(_grasp_section(v, figures, recorded, display_range) for v in views),
        "</body></html>\n",
    ])


# --------------------------------------------------------------------------- build


def build_report(
    log: str | Path, out: str | Path, *, catalogue: str | Path | None = None, progress: bool = False
) -> Report:
    """Write the report of session log ``log`` into the directory ``out`` (created).

    Parameters
    ----------
    log : str or Path
        A session log (MCAP) written by ``teleop record`` or ``teleop demo``.
    out : str or Path
        Directory for ``index.html`` and its PNGs; files of the same names are replaced, and the
        figures an earlier report's ``index.html`` there showed are removed; other files stay.
    catalogue : str or Path, optional
        Object catalogue for the labels; default: the one stored in the log.
    progress : bool
        Show a progress bar over the grasps.

    Raises
    ------
    SessionLogError
        The log is missing, not a session log, holds no settings or no grasp.
    ReportError
        ``out`` cannot be created or written.
    """
    log, out = Path(log), Path(out)
    reader = LogReader(log)
    info = reader.info()
    if info.damage and not info.attachments:
        raise SessionLogError(f"{log}: the session log is damaged before its settings: {info.damage}")
    settings = info.settings()
    messages, recorded = grasp_messages(reader)
    calibrations = log_calibrations(info, settings)
    if out.exists() and not out.is_dir():
        raise ReportError(f"--out {out}: is a file; expected a folder for the report (made if missing)")
    views, figures = [], {}
    grasps = session_grasps(log, catalogue=catalogue)
    # Drawn in a folder beside ``out`` and swapped in for it only once index.html is written (the
    # files of ``out`` this report does not rewrite are carried over, except the figures the earlier
    # report's page showed): an interrupted or failed run leaves the earlier report as it was, and
    # no empty ``out`` (nor its parents) where there was none.
    made = _missing_folders(out.parent)
    try:
        for folder in reversed(made):
            folder.mkdir()
        earlier = _earlier_figures(out)
        with staged_dir(out, drop=earlier.__contains__) as folder:
            for grasp in progress_bar(grasps, desc=f"report {log.name}", unit="grasp", total=len(messages),
                              enabled=progress):
                view = messages.pop(grasp.grasp_id, None) or GraspView(grasp.grasp_id)
                view.take(grasp.record, grasp.reason)
                views.append(view)
                if view.record is None:
                    continue
                tactile_moments(view, settings=settings, calibrations=calibrations)
                anchor = _anchor(view)
                if view.moments:
                    figures[f"{anchor}-tactile.png"] = tactile_figure(view, folder / f"{anchor}-tactile.png")
                figures[f"{anchor}-timeline.png"] = timeline_figure(view, folder / f"{anchor}-timeline.png",
                                                                    display_recorded=recorded)
                view.record, view.moments = None, []  # drawn: a long session's frames need not stay in memory
            if not views:
                raise SessionLogError(f"{log}: no grasp in the log (no grasp_event start message): nothing to report")
            for view in messages.values():  # estimates or renderings of grasps the log never started
                view.reason = "the log has no grasp_event start for this grasp id"
                views.append(view)
            figures["predictions.png"] = predictions_figure(views, folder / "predictions.png", session=log.name,
                                                            display_range_pa=display_range_pa(settings))
            session = info.session
            lines = [f"log {log.resolve()}",
                     f"scene {session.get('scene') or '-'}, {session.get('source', 'unknown source')}, "
                     f"recorded {session.get('start_utc', 'at an unknown time')} with compliance-teleop "
                     f"{session.get('software_version', '?')} on {session.get('host', '?')}",
                     f"{len(views)} grasps; depth on the estimator's grid (binning {estimator_settings(settings).depth_binning}, "
                     "1 for fingers with markers); display messages "
                     + ("recorded" if recorded else "not recorded (the log has none)")]
            if info.damage:  # a recovered log's earlier losses, or a damaged attachment: recover cannot mend those
                lines.append(f"the log is damaged: {info.damage}; grasps in the damaged part are missing or skipped"
                             + (f". `teleop recover {log} --out FIXED.mcap` rewrites the readable part as a "
                                "complete log" if info.mendable else ""))
            index = folder / "index.html"
            index.write_text(_page(log, lines, views, figures, recorded, display_range_pa(settings)), encoding="utf-8")
    except BaseException as exc:
        for folder in made:  # innermost first; only the ones still empty
            try:
                folder.rmdir()
            except OSError:
                break
        if isinstance(exc, OSError):
            raise ReportError(f"cannot write the report into {out}: {exc.strerror or exc}") from exc
        raise
    return Report(out / "index.html", figures, views, log)


def _earlier_figures(out: Path) -> frozenset[str]:
    """The figures an earlier report wrote into ``out``: the report's own names (predictions.png,
    grasp-*.png) that ``out/index.html``, when it is a report's page, shows. Other files (a user's
    ``grasp-notes.png`` beside the report) are none of them."""
    try:
        page = (out / "index.html").read_text(encoding="utf-8", errors="replace")
    except OSError:  # none, or unreadable: nothing is known to be an earlier report's
        return frozenset()
    if _PAGE_TITLE not in page:
        return frozenset()
    names = (html.unescape(src) for src in _IMG_SRC.findall(page))
    return frozenset(n for n in names if "/" not in n and n != "index.html" and _OWN_FILE.fullmatch(n))


def _missing_folders(path: Path) -> list[Path]:
    """``path`` and its ancestors that do not exist, innermost first."""
    missing = []
    while not path.exists() and not path.is_symlink() and path != path.parent:
        missing.append(path)
        path = path.parent
    return missing


# --------------------------------------------------------------------------- chromium


def find_chromium() -> str | None:
    """The first Chromium (or Chrome) executable on PATH, or None."""
    return next((path for name in CHROMIUM_NAMES if (path := shutil.which(name))), None)


def run_chromium(page: Path, *args: str, chromium: str | None = None, timeout_s: float = 120.0) -> str:
    """Run headless Chromium on ``page`` with ``args`` added to :data:`CHROMIUM_FLAGS` (a throw-away
    profile, no network services); returns its stdout.

    Raises
    ------
    ReportError
        No Chromium is installed (and ``chromium`` names none), it fails or it runs past ``timeout_s``.
    """
    chromium = chromium or find_chromium()
    if chromium is None:
        raise ReportError("no Chromium found (looked for " + ", ".join(CHROMIUM_NAMES) + " on PATH): install it, "
                          "e.g. `apt-get install -y chromium` (or `make browser`)")
    with tempfile.TemporaryDirectory(prefix="teleop-report-chromium-") as profile:
        command = [chromium, *CHROMIUM_FLAGS, f"--user-data-dir={profile}", *args, Path(page).resolve().as_uri()]
        try:
            done = subprocess.run(command, capture_output=True, text=True, timeout=timeout_s, check=False)
        except (OSError, subprocess.TimeoutExpired) as exc:
            raise ReportError(f"headless Chromium ({chromium}) on {page} failed: {exc}") from exc
    if done.returncode != 0:
        raise ReportError(f"headless Chromium ({chromium}) on {page} exited with {done.returncode}: "
                          f"{done.stderr.strip()[-500:]}")
    return done.stdout


def _page_height_px(report: Report, width_px: int) -> int:
    """More than the page's height at ``width_px``: the figures' shown heights plus room for text."""
    content = min(width_px - 60, 1320)
    figures = sum(h * min(1.0, content / w) for w, h in report.figures.values())
    return int(min(MAX_SCREENSHOT_PX, 1.2 * figures + 900 + 500 * len(report.views)))


def check_screenshot_path(png: str | Path, *, log: str | Path | None = None, out: str | Path | None = None,
                          figures: Sequence[str] = ()) -> Path:
    """``png`` resolved, once it is fit for a screenshot: not the session ``log``, not a folder (nor
    ``out``, the report's folder to be, or one above it), not under a file, not an existing file
    other than a PNG, and not one of the report's own files in ``out`` (index.html, predictions.png,
    grasp-*.png, ``figures``).

    Raises
    ------
    ReportError
        Naming --screenshot and what was expected.
    """
    given = png
    png = Path(png).resolve()
    expected = "expected a new or existing .png file outside the report's own files"
    if log is not None and png.exists() and Path(log).exists() and png.samefile(log):
        raise ReportError(f"--screenshot {given}: is the session log being reported; {expected}")
    if png.is_dir():
        raise ReportError(f"--screenshot {given}: is a folder; {expected}")
    if out is not None and (png == Path(out).resolve() or png in Path(out).resolve().parents):
        raise ReportError(f"--screenshot {given}: is the report's folder --out {out}, or one above it; {expected}")
    ancestor = png.parent
    while not ancestor.exists():
        ancestor = ancestor.parent
    if not ancestor.is_dir():
        raise ReportError(f"--screenshot {given}: {ancestor} is a file, not a folder; {expected}")
    if out is not None and png.parent == Path(out).resolve() and (
            _OWN_FILE.fullmatch(png.name) or png.name in figures):
        raise ReportError(f"--screenshot {given}: is one of the report's own files in {out}; {expected}")
    if png.exists():
        try:
            with png.open("rb") as file:
                head = file.read(len(_PNG_MAGIC))
        except OSError as exc:
            raise ReportError(f"--screenshot {given}: cannot be read ({exc.strerror or exc}); {expected}") from exc
        if head != _PNG_MAGIC:
            raise ReportError(f"--screenshot {given}: exists and is not a PNG image (it is left as it is); "
                              f"{expected}")
    return png


def screenshot(report: Report, png: str | Path, *, width_px: int = 1400, chromium: str | None = None) -> Path:
    """Render ``report``'s page in headless Chromium into ``png``: the whole page (up to
    :data:`MAX_SCREENSHOT_PX` tall) at ``width_px``, the blank rows below it cut off.

    Chromium writes into a temporary folder; ``png`` is replaced only once that reads back as an
    image (an earlier screenshot stays as it was when Chromium fails).

    Raises
    ------
    ReportError
        ``png`` is not fit for a screenshot (:func:`check_screenshot_path`), as :func:`run_chromium`,
        or Chromium wrote no image.
    """
    png = check_screenshot_path(png, log=report.log, out=report.index.parent, figures=list(report.figures))
    height = _page_height_px(report, width_px)
    if height == MAX_SCREENSHOT_PX:
        log.warning("the page may be taller than the screenshot's %d px: its end is cut off", height)
    with tempfile.TemporaryDirectory(prefix="teleop-report-screenshot-") as folder:
        shot = Path(folder) / "page.png"
        run_chromium(report.index, f"--screenshot={shot}", f"--window-size={width_px},{height}", chromium=chromium)
        image = cv2.imread(str(shot), cv2.IMREAD_COLOR)
    if image is None:
        raise ReportError(f"headless Chromium wrote no readable screenshot for {png} (left as it was)")
    rows = np.flatnonzero((image != image[-1:, :]).any(axis=(1, 2)))  # rows unlike the blank bottom one
    if rows.size and rows[-1] + 40 < image.shape[0]:
        image = image[: rows[-1] + 40]
    ok, encoded = cv2.imencode(".png", image)
    if not ok:
        raise ReportError(f"cannot encode the screenshot for {png}")
    try:
        png.parent.mkdir(parents=True, exist_ok=True)
        with staged(png) as temporary:
            temporary.write_bytes(encoded.tobytes())
    except OSError as exc:
        raise ReportError(f"--screenshot {png}: cannot be written: {exc.strerror or exc}") from exc
    return png


# --------------------------------------------------------------------------- command


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.description = (
        "Write a web page (DIR/index.html with its PNG figures beside it; no network, no JavaScript) "
        "for a session log: a summary table of the grasps (object, label E, final estimate, interval, "
        "state, what the display rendered, the felt error: that rendering against the label on the display's "
        "range) and the final estimates against their labels; "
        "per grasp, each finger's tactile frames before contact, mid-loading and at the peak force with the "
        "depth reconstructed from them (the log's calibration), force and width with the loading phase "
        "shaded, the provisional and final estimates with their intervals against the label, the final "
        "state and its reason, and what the display rendered (when the log recorded it). Open the page in "
        "any browser, or add --screenshot for one PNG of it (needs Chromium)."
    )
    parser.add_argument("log", metavar="LOG", help="session log (.mcap) written by `teleop record` or `teleop demo`")
    parser.add_argument("--out", required=True, metavar="DIR",
                        help="directory for index.html and its PNGs (created); replaces an earlier report there "
                             "(its index.html and the figures that page shows), keeps every other file")
    parser.add_argument("--objects", metavar="PATH", default=None,
                        help="object catalogue for the labels (default: the catalogue stored in the log)")
    parser.add_argument("--screenshot", metavar="PNG", default=None,
                        help="also render the page with headless Chromium into this PNG (whole page); it may "
                             "replace an earlier PNG, never the log, another file or the report's own files")
    parser.add_argument("--width", type=int, default=1400, metavar="PX", help="screenshot width in pixels")


def run(args: argparse.Namespace) -> int:
    if args.width < 400:
        raise ReportError(f"--width {args.width}: expected at least 400 px")
    if args.screenshot:  # before the report is drawn: a bad path fails at once
        check_screenshot_path(args.screenshot, log=args.log, out=args.out)
    report = build_report(args.log, args.out, catalogue=args.objects, progress=True)
    print(f"report: {report.index} ({len(report.views)} grasps, {len(report.figures)} figures)")
    if args.screenshot:
        print(f"screenshot: {screenshot(report, args.screenshot, width_px=args.width)}")
    return 0
