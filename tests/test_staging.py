"""teleop.staging: outputs renamed into place only when complete; an interrupt leaves the old ones."""

from __future__ import annotations

import pytest

from teleop.staging import staged, staged_dir


def test_staged_files_replace_their_destinations_together(tmp_path):
    a, b = tmp_path / "a.txt", tmp_path / "b.txt"
    a.write_text("old a")
    with staged(a, b) as (pa, pb):
        assert pa.parent == tmp_path and pa.name.startswith(".a.txt.") and pa.name.endswith(".partial")
        pa.write_text("new a")
        pb.write_text("new b")
        assert a.read_text() == "old a" and not b.exists()
    assert (a.read_text(), b.read_text()) == ("new a", "new b")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.txt", "b.txt"]


def test_an_interrupt_leaves_the_old_file_and_no_temporary(tmp_path):
    a = tmp_path / "a.txt"
    a.write_text("old")
    with pytest.raises(KeyboardInterrupt), staged(a) as partial:
        partial.write_text("half")
        raise KeyboardInterrupt
    assert a.read_text() == "old"
    assert [p.name for p in tmp_path.iterdir()] == ["a.txt"]


def test_a_staged_folder_is_swapped_in_keeping_the_files_it_did_not_write(tmp_path):
    out = tmp_path / "report"
    out.mkdir()
    (out / "index.html").write_text("old page")
    (out / "mine.txt").write_text("kept")
    with staged_dir(out) as folder:
        (folder / "index.html").write_text("new page")
        assert (out / "index.html").read_text() == "old page"
    assert (out / "index.html").read_text() == "new page" and (out / "mine.txt").read_text() == "kept"
    assert [p.name for p in tmp_path.iterdir()] == ["report"]


def test_an_interrupted_staged_folder_leaves_the_old_one(tmp_path):
    out = tmp_path / "report"
    out.mkdir()
    (out / "index.html").write_text("old page")
    with pytest.raises(KeyboardInterrupt), staged_dir(out) as folder:
        (folder / "fig.png").write_text("new")
        raise KeyboardInterrupt
    assert [p.name for p in out.iterdir()] == ["index.html"] and (out / "index.html").read_text() == "old page"
    assert [p.name for p in tmp_path.iterdir()] == ["report"]


def test_a_new_staged_folder_is_created(tmp_path):
    with staged_dir(tmp_path / "new") as folder:
        (folder / "x").write_text("x")
    assert (tmp_path / "new" / "x").read_text() == "x"


def test_a_staged_folder_drops_the_entries_it_is_told_to(tmp_path):
    """An earlier run's outputs this run did not write again are not carried over; other files are."""
    out = tmp_path / "report"
    out.mkdir()
    for name in ("index.html", "grasp-old-timeline.png", "mine.txt"):
        (out / name).write_text("old")
    with staged_dir(out, drop=lambda name: name.startswith("grasp-")) as folder:
        (folder / "index.html").write_text("new page")
        (folder / "grasp-new-timeline.png").write_text("new")
    assert sorted(p.name for p in out.iterdir()) == ["grasp-new-timeline.png", "index.html", "mine.txt"]
    assert (out / "index.html").read_text() == "new page" and (out / "mine.txt").read_text() == "old"


def test_a_staged_working_folder_drops_the_entries_it_is_told_to(tmp_path, monkeypatch):
    out = tmp_path / "report"
    out.mkdir()
    for name in ("index.html", "grasp-old-timeline.png", "mine.txt"):
        (out / name).write_text("old")
    monkeypatch.chdir(out)
    with staged_dir(out, drop=lambda name: name.startswith("grasp-")) as folder:
        (folder / "index.html").write_text("new page")
    assert sorted(p.name for p in out.iterdir()) == ["index.html", "mine.txt"]
