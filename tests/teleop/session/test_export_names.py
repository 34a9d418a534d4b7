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
        assert _fits(f".{name}.exporting"), (len(name.encode()), name)  # the hidden name it is written under
        assert name.startswith("Greifversuch-Gummib") and name.endswith((f"_{SESSION}_{GRASP}.grasp",
                                                                          f"_{SESSION}_{GRASP}-2.grasp"))
        (tmp_path / f".{name}.exporting").write_bytes(b"")  # the file system takes it
        (tmp_path / name).write_bytes(b"")
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


def test_a_long_grasp_id_is_cut_to_fit_and_kept_apart_by_a_hash(tmp_path):
    """A grasp id of a long scene file's name (ids up to 256 characters pass the wire): the record's
    name, and the hidden name the export writes first, fit; it starts readable and stays apart."""
    long_id = "s" * 240 + "-001"
    taken: set[str] = set()
    names = [record_name(Path("session.mcap"), SESSION, grasp, taken)
             for grasp in (long_id, long_id, "s" * 240 + "-002", "g" * 256)]
    assert len(set(names)) == 4
    for name in names:
        assert _fits(f".{name}.exporting"), (len(name.encode()), name)
        assert name.startswith(f"session_{SESSION}_") and name.endswith(".grasp")
        (tmp_path / f".{name}.exporting").write_bytes(b"")  # the file system takes it
    assert names[0].startswith(f"session_{SESSION}_sssss")
    assert names[1] == names[0].removesuffix(".grasp") + "-2.grasp"
    short = record_name(Path("session.mcap"), SESSION, GRASP, set())
    assert short == f"session_{SESSION}_{GRASP}.grasp"  # a short id stays whole


def test_twins_of_a_long_grasp_id_are_found(tmp_path):
    long_id = "s" * 244
    name = record_name(Path("cut.mcap"), SESSION, long_id, set())
    twin = tmp_path / record_name(Path("recovered.mcap"), SESSION, long_id, set())
    with zipfile.ZipFile(twin, "w") as zf:
        zf.writestr("record.json", json.dumps({"provenance": {"extra": {
            "session_id": SESSION, "grasp_id": long_id, "session": "recovered.mcap"}}}))
    assert same_grasp_records([twin], Path("cut.mcap"), name, SESSION, long_id) == [(twin, "recovered.mcap")]
