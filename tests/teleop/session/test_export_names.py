"""Record names of an export: within a file system's 255-byte limit however long the log's name."""

from __future__ import annotations

import json
import zipfile
from pathlib import Path

from teleop.session.export_names import record_name, same_grasp_records

SESSION, GRASP = "s-20260101-0001", "g0007"


def _fits(name: str) -> bool:
    return len(name.encode("utf-8")) <= 255


def test_a_short_stem_is_kept_whole():
    assert record_name(Path("lab/run1.mcap"), SESSION, GRASP, set()) == f"run1_{SESSION}_{GRASP}.grasp"


def test_a_long_unicode_stem_is_cut_to_fit_and_kept_apart_by_a_hash(tmp_path):
    stem = "Greifversuch-Gummibälle-" * 10  # 240 characters, 250 UTF-8 bytes: a legal file name
    assert len(stem) == 240 and _fits(stem + ".mcap")
    taken: set[str] = set()
    first = record_name(Path(f"{stem}.mcap"), SESSION, GRASP, taken)
    again = record_name(Path(f"{stem}.mcap"), SESSION, GRASP, taken)
    other = record_name(Path(f"{stem}X.mcap"), SESSION, GRASP, taken)
    for name in (first, again, other):
        assert _fits(name), (len(name.encode()), name)
        assert name.startswith("Greifversuch-Gummib") and name.endswith((f"_{SESSION}_{GRASP}.grasp",
                                                                          f"_{SESSION}_{GRASP}-2.grasp"))
        (tmp_path / name).write_bytes(b"")  # the file system takes it
    assert again == first.removesuffix(".grasp") + "-2.grasp"
    assert len({first, again, other}) == 3


def test_twins_of_a_cut_name_are_found(tmp_path):
    log = Path("Greifversuch-Gummibälle-" * 10 + ".mcap")
    name = record_name(log, SESSION, GRASP, set())
    assert not name.startswith(log.stem.replace("ä", "_"))  # cut
    twin = tmp_path / f"short_{SESSION}_{GRASP}.grasp"
    with zipfile.ZipFile(twin, "w") as zf:
        zf.writestr("record.json", json.dumps({"provenance": {"extra": {
            "session_id": SESSION, "grasp_id": GRASP, "session": "short.mcap"}}}))
    assert same_grasp_records([twin], log, name, SESSION, GRASP) == [(twin, "short.mcap")]
