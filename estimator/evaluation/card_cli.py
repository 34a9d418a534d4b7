"""``estimator card``: write a model card's figures table from ``estimator evaluate --json`` outputs.

The table sits in the card between two marker lines, ``<!-- figures:begin -->`` and
``<!-- figures:end -->``; everything between them is this command's. Each source is one
``estimator evaluate --json`` output with a label (``--figures "LABEL=PATH"``); the table has a
row per source and method, the soft objects' figures first (labels at or below 3 MPa: the
objects the display scales, where rigid objects rendered rigid at zero error cannot hide a
miss), then every object's. Below it, each source with the command that made it (the JSON's
``command``, which ``estimator evaluate`` records).

The block also records its sources (a comment line holding the labels, paths relative to the
card, and the methods), so ``estimator card CARD`` alone writes the table again and ``--check``
says whether the card still says what its JSONs say (exit status 1, naming each figure that
differs). ``--keep DIR`` writes a small copy of each source (its figures, without the per-record
lists) into DIR and points the card at the copies: a card kept in git can then be checked
against the JSONs it came from (``tests/estimator/evaluation/test_card.py`` does so for the shipped card).
"""

from __future__ import annotations

import argparse
import json
import os
import re
import sys
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from estimator.errors import EstimatorError
from teleop.staging import staged

__all__ = ["BEGIN", "COLUMNS", "END", "SHIPPED_CARD", "Source", "add_arguments", "check_block", "kept_copy", "load_source", "render_block",
           "recorded_sources", "replace_block", "run", "table_rows"]

#: The shipped model's card (``estimator/models/default``; :func:`estimator.inference.infer.default_model_dir`).
SHIPPED_CARD = Path(__file__).resolve().parent.parent / "models" / "default" / "MODEL_CARD.md"
BEGIN = "<!-- figures:begin -->"
END = "<!-- figures:end -->"
_SOURCES = re.compile(r"^<!-- figures:sources (\{.*\}) -->$")
_PERCENT = "{:.1f} %"


def _share(value: Any) -> str:
    return "-" if value is None else _PERCENT.format(100 * value)


def _number(spec: str):
    return lambda value: "-" if value is None else format(value, spec)


def _coverage(entry: Mapping[str, Any], prefix: str) -> str:
    coverage = entry.get(f"{prefix}interval_coverage")
    if coverage is None:
        return "-"
    level = entry.get("interval_level")
    return f"{_share(coverage)} ({'-' if level is None else format(100 * level, '.0f') + ' %'})"


#: The card's columns after the source's label and the method: (heading, how to write the method's figures).
COLUMNS: tuple[tuple[str, Any], ...] = (
    ("soft n", lambda m: _number("d")(m.get("soft_n"))),
    ("soft felt err", lambda m: _number(".3f")(m.get("soft_felt_log10_error"))),
    ("soft within 2x", lambda m: _share(m.get("soft_felt_within_2x"))),
    ("soft coverage (stated)", lambda m: _coverage(m, "soft_")),
    ("soft width", lambda m: _number(".2f")(m.get("soft_interval_width_decades_median"))),
    ("n", lambda m: _number("d")(m.get("n"))),
    ("felt err", lambda m: _number(".3f")(m.get("felt_log10_error"))),
    ("within 2x", lambda m: _share(m.get("felt_within_2x"))),
    ("dangerous", lambda m: _number("d")(m.get("dangerous_misses"))),
    ("shown unknown", lambda m: _number("d")(m.get("shown_unknown"))),
    ("rigid shown rigid", lambda m: _share(m.get("rigid_shown_rigid"))),
    ("coverage (stated)", lambda m: _coverage(m, "")),
)
#: A method's fields a kept copy holds (the figures; not the per-material and per-shape breakdowns).
_KEPT_METHOD_FIELDS = ("n", "log10_error", "within_10x", "point_log10_error", "point_within_10x", "ok_only",
                       "felt_log10_error", "felt_within_2x", "dangerous_misses", "shown_unknown", "rigid_shown_rigid",
                       "interval_level", "interval_coverage", "interval_width_decades_median", "soft_n",
                       "soft_felt_log10_error", "soft_felt_within_2x", "soft_interval_coverage",
                       "soft_interval_width_decades_median", "states", "inputs", "model", "variant")
_KEPT_FIELDS = ("command", "dir", "records", "labelled", "display_range_pa", "models")


@dataclass(frozen=True)
class Source:
    """One labelled ``estimator evaluate --json`` output."""

    label: str
    path: Path
    result: Mapping[str, Any]


def _check_label(label: str) -> str:
    label = label.strip()
    if not label or any(mark in label for mark in ("|", "--", "=", "\n")):
        raise EstimatorError(f"figures label {label!r}: expected a non-empty label without '|', '--', '=' "
                             "or a line break")
    return label


def _no_constant(name: str) -> Any:
    raise ValueError(f"{name} is no figure evaluate writes")


def load_source(label: str, path: str | Path) -> Source:
    """Read one ``estimator evaluate --json`` output (the JSON object on its last non-empty line) or
    a kept copy of one (the file one JSON object)."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
        try:
            result = json.loads(text, parse_constant=_no_constant)
        except ValueError:
            result = json.loads([line for line in text.splitlines() if line.strip()][-1], parse_constant=_no_constant)
    except (OSError, IndexError, ValueError) as exc:
        raise EstimatorError(f"{path}: not an estimator evaluate --json output ({exc})") from None
    if not isinstance(result, dict) or not isinstance(result.get("methods"), dict):
        raise EstimatorError(f"{path}: not an estimator evaluate --json output (no 'methods' object)")
    display = result.get("display_range_pa")
    if display is not None and not (isinstance(display, list) and len(display) in (0, 2)
                                    and all(isinstance(v, int | float) for v in display)):
        raise EstimatorError(f"{path}: display_range_pa: expected [soft, rigid] pascals, got {display!r}")
    return Source(_check_label(label), path, result)


def method_name(name: str, entry: Mapping[str, Any]) -> str:
    """How the card names a method: a learned one by its model's folder (``hybrid (default)``)."""
    model = entry.get("model")
    if not model:
        return name
    return f"{name.split('[')[0]} ({Path(model).name})"


def _selected(methods: Mapping[str, Any], wanted: Sequence[str] | None) -> list[str]:
    """The methods of one source to show: all, or those ``wanted`` names (``hybrid`` also picks
    ``hybrid[variant]``), in the order given."""
    if not wanted:
        return list(methods)
    chosen = []
    for want in wanted:
        chosen += [name for name in methods if (name == want or name.startswith(want + "[")) and name not in chosen]
    return chosen


def table_rows(sources: Sequence[Source], methods: Sequence[str] | None = None) -> list[tuple[str, str, list[str]]]:
    """``(label, method, cells)`` per source and method: the table's rows, cells in :data:`COLUMNS` order."""
    rows = []
    for source in sources:
        entries = source.result["methods"]
        names = _selected(entries, methods)
        if not names:
            raise EstimatorError(f"{source.path}: none of the methods {', '.join(methods or [])} "
                                 f"(it has {', '.join(entries)})")
        for name in names:
            entry = entries[name]
            if not isinstance(entry, Mapping):
                raise EstimatorError(f"{source.path}: method {name!r}: expected an object of figures, "
                                     f"got {type(entry).__name__}")
            cells = []
            for heading, cell in COLUMNS:
                try:
                    cells.append(cell(entry))
                except (TypeError, ValueError) as exc:
                    raise EstimatorError(f"{source.path}: method {name!r}, column {heading!r}: expected a number "
                                         f"or null ({exc})") from None
            if not isinstance(entry.get("model"), str | None):
                raise EstimatorError(f"{source.path}: method {name!r}, model: expected a folder name or null, "
                                     f"got {entry['model']!r}")
            rows.append((source.label, method_name(name, entry), cells))
    return rows


def _relative(path: Path, card: Path) -> str:
    return Path(os.path.relpath(path.resolve(), card.resolve().parent)).as_posix()


def _range(display: Sequence[float] | None) -> str:
    if not display:
        return ""
    soft, rigid = display
    return f"; display {soft / 1e3:.3g} kPa to the {rigid / 1e6:.3g} MPa rigid end"


def render_block(sources: Sequence[Source], *, card: Path, methods: Sequence[str] | None = None) -> str:
    """The text between the markers (markers included) for ``sources``."""
    recorded = {"figures": [[s.label, _relative(s.path, card)] for s in sources], "methods": list(methods or [])}
    lines = [BEGIN,
             f"<!-- figures:sources {json.dumps(recorded)} -->",
             "<!-- Written by `estimator card`: edit the sources, not this table. -->",
             "",
             "| figures | method | " + " | ".join(heading for heading, _ in COLUMNS) + " |",
             "|---|---|" + "---|" * len(COLUMNS)]
    lines += [f"| {label} | {method} | " + " | ".join(cells) + " |" for label, method, cells in table_rows(sources, methods)]
    lines.append("")
    for s in sources:
        r = s.result
        command = r.get("command")
        made = f"; made by `{command}`" if command else ""
        lines.append(f"- {s.label}: `{_relative(s.path, card)}`, {r.get('labelled', '-')} grasps scored of "
                     f"{r.get('records', '-')} records{_range(r.get('display_range_pa'))}{made}.")
    lines.append(END)
    return "\n".join(lines)


def _split(text: str, card: Path) -> tuple[str, str, str]:
    """(before, block, after) of the card's text; the block includes both marker lines."""
    lines = text.splitlines(keepends=True)
    begins = [i for i, line in enumerate(lines) if line.strip() == BEGIN]
    ends = [i for i, line in enumerate(lines) if line.strip() == END]
    if len(begins) != 1 or len(ends) != 1 or ends[0] < begins[0]:
        raise EstimatorError(f"{card}: expected one '{BEGIN}' line and, after it, one '{END}' line "
                             f"(found {len(begins)} and {len(ends)})")
    b, e = begins[0], ends[0]
    return "".join(lines[:b]), "".join(lines[b:e + 1]).rstrip("\n"), "".join(lines[e + 1:])


def replace_block(text: str, block: str, *, card: Path) -> str:
    """``text`` with the block between the markers replaced by ``block``."""
    before, _, after = _split(text, card)
    return before + block + "\n" + after


def recorded_sources(text: str, card: Path) -> tuple[list[tuple[str, Path]], list[str]]:
    """The sources (label, path) and methods a card's block was written from."""
    _, block, _ = _split(text, card)
    for line in block.splitlines():
        found = _SOURCES.match(line.strip())
        if found:
            try:
                recorded = json.loads(found.group(1))
                figures = [(str(label), card.parent / str(path)) for label, path in recorded["figures"]]
                methods = recorded["methods"]
                if not isinstance(methods, list) or not all(isinstance(m, str) for m in methods):
                    raise TypeError("'methods' is not a list of names")
            except (ValueError, KeyError, TypeError) as exc:
                detail = f"no {exc}" if isinstance(exc, KeyError) else str(exc)
                raise EstimatorError(
                    f"{card}: its '<!-- figures:sources ... -->' line is not a JSON object with 'figures' "
                    f"([label, path] pairs) and 'methods' (a list of names) ({detail}); write the block again "
                    "with --figures LABEL=PATH") from None
            return figures, methods
    raise EstimatorError(f"{card}: its figures block records no sources; give them with --figures LABEL=PATH")


def _parse_rows(block: str) -> dict[tuple[str, str], list[str]]:
    rows = {}
    for line in block.splitlines()[1:]:
        if not line.startswith("|") or line.startswith(("|---", "| figures |")):
            continue
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        rows[(cells[0], cells[1])] = cells[2:]
    return rows


def check_block(current: str, expected: str) -> list[str]:
    """What differs between the card's block and the one its sources give, one line per figure."""
    if current == expected:
        return []
    have, want = _parse_rows(current), _parse_rows(expected)
    headings = [heading for heading, _ in COLUMNS]
    problems = []
    for key, cells in want.items():
        if key not in have:
            problems.append(f"{key[0]} / {key[1]}: row missing from the card")
            continue
        for heading, card_cell, json_cell in zip(headings, have[key] + [""] * len(headings), cells, strict=False):
            if card_cell != json_cell:
                problems.append(f"{key[0]} / {key[1]} / {heading}: card says {card_cell or '(nothing)'}, "
                                f"the JSON gives {json_cell}")
    problems += [f"{key[0]} / {key[1]}: row in the card, not in the JSONs" for key in have if key not in want]
    return problems or ["the block's other lines (sources, commands) differ from what the JSONs give"]


def kept_copy(source: Source, methods: Sequence[str] | None) -> dict[str, Any]:
    """The part of an evaluate output a card needs: its figures per shown method, its command and scope."""
    names = _selected(source.result["methods"], methods)
    entries = source.result["methods"]
    return {"label": source.label, "kept_from": str(source.path),
            **{key: source.result.get(key) for key in _KEPT_FIELDS},
            "methods": {name: {k: entries[name][k] for k in _KEPT_METHOD_FIELDS if k in entries[name]}
                        for name in names}}


def _slug(label: str) -> str:
    return re.sub(r"[^a-z0-9]+", "-", label.lower()).strip("-") or "figures"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.description = (
        "Write a model card's figures table from estimator evaluate --json outputs: the block between "
        f"'{BEGIN}' and '{END}' becomes a table with a row per source and method (soft objects' figures "
        "first, then all objects': felt error, share felt within a factor 2, interval coverage with the stated "
        "level, median interval width, dangerous misses, estimates shown unknown, rigid objects shown rigid) and the command that made "
        "each source. The block records its sources, so without --figures the card is written again from them. "
        "--check writes nothing and exits with status 1 when the card differs from its sources, naming each "
        "figure that does."
    )
    parser.add_argument("card", metavar="CARD", nargs="?", default=str(SHIPPED_CARD),
                        help="the model card (markdown) holding the two marker lines (default: the shipped "
                             "model's MODEL_CARD.md)")
    parser.add_argument("--figures", action="append", metavar="LABEL=PATH", default=None,
                        help="an estimator evaluate --json output and the label of its rows (the label ends "
                             "at the first '='), e.g. 'Half-space gel=runs/cross-contact/figures.json'; repeat "
                             "for several, in the table's order. Without it: the sources the card's block records")
    parser.add_argument("--methods", nargs="+", metavar="METHOD", default=None,
                        help="the methods to show, in this order (hybrid also picks hybrid[variant]; "
                             "without --figures: those the block records; otherwise every method of each source)")
    parser.add_argument("--keep", metavar="DIR", default=None,
                        help="also write a small copy of each source (its figures, command and scope, without "
                             "the per-record lists) into DIR as LABEL.json, and point the card at the copies. "
                             "A LABEL.json already there is replaced only when it is a source this card's block "
                             "records (its own copy) or holds the same copy already; any other (another card's "
                             "copy, say) is refused, naming it, and nothing is written, unless --overwrite")
    parser.add_argument("--overwrite", action="store_true",
                        help="with --keep: replace LABEL.json files in DIR that this card does not record")
    parser.add_argument("--check", action="store_true",
                        help="write nothing; exit with status 1 when the card's block differs from what its "
                             "sources give, naming each figure that differs")


def _figure_specs(specs: Sequence[str]) -> list[tuple[str, Path]]:
    out = []
    for spec in specs:
        # at the first '=': a label holds none, a path may (runs/grasp=1/figures.json)
        label, sep, path = spec.partition("=")
        if not sep or not label.strip() or not path.strip():
            raise EstimatorError(f"--figures {spec!r}: expected LABEL=PATH")
        out.append((label, Path(path)))
    return out


def _own_sources(text: str, card: Path) -> set[Path]:
    """The source files the card's block records (none when it records none yet)."""
    try:
        specs, _ = recorded_sources(text, card)
    except EstimatorError:
        return set()
    return {path.resolve() for _, path in specs}


def _check_kept(copies: Mapping[Path, str], own: set[Path], keep: Path) -> None:
    """Refuse (before anything is written) a ``--keep`` copy that would replace a different file the card
    does not record: another card's copy, or anything else of the user's."""
    for path, copy in copies.items():
        if not path.exists() or path.resolve() in own:
            continue
        try:
            same = path.read_text(encoding="utf-8") == copy
        except (OSError, UnicodeDecodeError):
            same = False
        if not same:
            raise EstimatorError(f"--keep {keep}: {path} exists, differs from this source's copy and is not a source "
                                 "this card records (another card's copy?); keep into another folder, or pass "
                                 "--overwrite to replace it; nothing was written")


def _write_all(files: Mapping[Path, str], card: Path) -> None:
    """Write ``files`` (the card last) each beside its destination and rename them into place only once
    all are complete: on a failure none is touched."""
    try:
        with staged(*files) as temporaries:
            for temporary, content in zip(temporaries if len(files) > 1 else [temporaries], files.values(),
                                          strict=True):
                temporary.write_text(content, encoding="utf-8")
    except OSError as exc:
        raise EstimatorError(f"{card}: cannot write the model card ({exc.strerror or exc}); "
                             "the card and any --keep copies were left as they were") from None


def run(args: argparse.Namespace) -> int:
    card = Path(args.card)
    try:
        text = card.read_text(encoding="utf-8")
    except OSError as exc:
        raise EstimatorError(f"{card}: cannot read the model card ({exc.strerror})") from None
    except UnicodeDecodeError as exc:
        raise EstimatorError(f"{card}: not a UTF-8 text model card (byte {exc.start}: {exc.reason})") from None
    if args.figures:
        specs, methods = _figure_specs(args.figures), args.methods
    else:
        specs, recorded_methods = recorded_sources(text, card)
        methods = args.methods if args.methods is not None else recorded_methods
    sources = [load_source(label, path) for label, path in specs]
    # A method may be missing from some sources (a rig evaluated with one model only), not from all:
    # such a name is a typo, which the table would otherwise drop without a word.
    have = dict.fromkeys(name for s in sources for name in s.result["methods"])
    unknown = [m for m in methods or [] if not _selected(have, [m])]
    if unknown:
        where = "--methods" if args.methods is not None else f"{card}: the recorded methods"
        raise EstimatorError(f"{where} {', '.join(unknown)}: in none of the sources (they have {', '.join(have)})")
    if getattr(args, "overwrite", False) and not args.keep:
        raise EstimatorError("--overwrite: replaces files --keep DIR would write; give --keep DIR, or leave it out")
    table_rows(sources, methods)  # every source has a row to show, named by the user's path; before anything is written
    copies: dict[Path, str] = {}
    if args.keep and not args.check:
        keep = Path(args.keep)
        slugs = [_slug(s.label) for s in sources]
        if len(set(slugs)) != len(slugs):
            raise EstimatorError(f"--keep: two labels give one file name ({', '.join(slugs)})")
        if keep.exists() and not keep.is_dir():
            raise EstimatorError(f"--keep {keep}: exists and is not a folder")
        copies = {keep / f"{slug}.json": json.dumps(kept_copy(source, methods), indent=1, allow_nan=False) + "\n"
                  for source, slug in zip(sources, slugs, strict=True)}
        if not getattr(args, "overwrite", False):
            _check_kept(copies, _own_sources(text, card), keep)
        # The card points at the copies: its table is rendered from them as they will be read back.
        sources = [Source(source.label, path, json.loads(copy))
                   for source, (path, copy) in zip(sources, copies.items(), strict=True)]
    block = render_block(sources, card=card, methods=methods)
    if args.check:
        _, current, _ = _split(text, card)
        problems = check_block(current, block)
        if problems:
            print(f"{card}: the figures table differs from its sources:", file=sys.stderr)
            for problem in problems:
                print(f"  {problem}", file=sys.stderr)
            print(f"write it again with: estimator card {card}", file=sys.stderr)
            return 1
        print(f"{card}: the figures table matches its {len(sources)} sources")
        return 0
    new_text = replace_block(text, block, card=card)
    if copies:
        keep = Path(args.keep)
        try:
            keep.mkdir(parents=True, exist_ok=True)
        except FileExistsError:
            raise EstimatorError(f"--keep {keep}: exists and is not a folder") from None
        except OSError as exc:
            raise EstimatorError(f"--keep {keep}: cannot create the folder ({exc.strerror})") from None
    _write_all({**copies, card: new_text}, card)
    print(f"{card}: figures table written from {len(sources)} sources")
    return 0
