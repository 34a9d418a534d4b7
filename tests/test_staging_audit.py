"""teleop.staging: what a staged output leaves in place, carries over and removes, and in which order."""

from __future__ import annotations

import errno
import os

import pytest

from teleop.staging import staged, staged_dir


def _replaced_in_order(monkeypatch) -> list[str]:
    """The names ``os.replace`` moves into place, in order."""
    moved: list[str] = []
    replace = os.replace

    def recording(src, dst):
        moved.append(os.path.basename(dst))
        replace(src, dst)

    monkeypatch.setattr(os, "replace", recording)
    return moved


def test_a_destination_whose_temporary_was_not_written_is_left_as_it_is(tmp_path):
    a, b = tmp_path / "a.txt", tmp_path / "b.txt"
    a.write_text("old a")
    with staged(a, b) as (_, pb):
        pb.write_text("new b")
    assert (a.read_text(), b.read_text()) == ("old a", "new b")


def test_staged_files_are_renamed_in_the_order_given_the_last_one_last(tmp_path, monkeypatch):
    moved = _replaced_in_order(monkeypatch)
    with staged(tmp_path / "data.bin", tmp_path / "index.json") as (data, index):
        index.write_text("{}")
        data.write_text("x")
    assert moved == ["data.bin", "index.json"]


def test_a_folders_entries_the_block_did_not_write_are_carried_as_hard_links(tmp_path):
    out = tmp_path / "report"
    out.mkdir()
    (out / "mine.txt").write_text("kept")
    inode = (out / "mine.txt").stat().st_ino
    with staged_dir(out) as folder:
        (folder / "index.html").write_text("new")
    assert (out / "mine.txt").stat().st_ino == inode


def test_symlinks_in_a_staged_folder_are_carried_as_links_dangling_ones_too(tmp_path):
    out, elsewhere = tmp_path / "report", tmp_path / "elsewhere"
    (out / "sub").mkdir(parents=True)
    elsewhere.mkdir()
    (elsewhere / "big.bin").write_text("data")
    (out / "to-dir").symlink_to(elsewhere)
    (out / "gone").symlink_to(tmp_path / "missing")
    (out / "sub" / "inner").symlink_to(elsewhere / "big.bin")
    (out / "sub" / "inner-dir").symlink_to(elsewhere)
    with staged_dir(out) as folder:
        (folder / "index.html").write_text("new")
    assert all((out / name).is_symlink() for name in ("to-dir", "gone", "sub/inner", "sub/inner-dir"))
    assert os.readlink(out / "gone") == str(tmp_path / "missing")
    assert (out / "sub").is_dir() and not (out / "sub").is_symlink()


def test_a_staged_folder_whose_swap_fails_puts_the_old_folder_back(tmp_path, monkeypatch):
    out = tmp_path / "report"
    out.mkdir()
    (out / "index.html").write_text("old page")
    rename, renames = os.rename, []

    def failing_into_place(src, dst):
        renames.append(src)
        if len(renames) == 2:  # the new folder into place, the old one aside already
            raise OSError("the swap failed")
        rename(src, dst)

    monkeypatch.setattr(os, "rename", failing_into_place)
    with pytest.raises(OSError, match="the swap failed"), staged_dir(out) as folder:
        (folder / "index.html").write_text("new page")
    monkeypatch.undo()
    assert (out / "index.html").read_text() == "old page"
    assert [p.name for p in tmp_path.iterdir()] == ["report"]


def test_a_staged_folder_holding_the_working_folder_deeper_down_keeps_it(tmp_path, monkeypatch):
    out = tmp_path / "report"
    (out / "sub").mkdir(parents=True)
    monkeypatch.chdir(out / "sub")
    with staged_dir(out) as folder:
        (folder / "index.html").write_text("new page")
    assert os.path.samefile(os.getcwd(), out / "sub")
    assert (out / "index.html").read_text() == "new page"


def test_a_staged_working_folder_gets_its_new_entries_oldest_first(tmp_path, monkeypatch):
    out = tmp_path / "report"
    out.mkdir()
    monkeypatch.chdir(out)
    with staged_dir(out) as folder:
        for name, mtime_ns in (("index.html", 3_000_000_000), ("a.png", 1_000_000_000), ("b.png", 2_000_000_000)):
            (folder / name).write_text(name)
            os.utime(folder / name, ns=(mtime_ns, mtime_ns))
        moved = _replaced_in_order(monkeypatch)
    assert moved == ["a.png", "b.png", "index.html"]


def test_a_staged_working_folder_keeps_what_the_block_wrote_though_drop_matches_it(tmp_path, monkeypatch):
    out = tmp_path / "report"
    out.mkdir()
    (out / "grasp-old.png").write_text("old")
    monkeypatch.chdir(out)
    with staged_dir(out, drop=lambda name: name.startswith("grasp-")) as folder:
        (folder / "grasp-new.png").write_text("new")
    assert sorted(p.name for p in out.iterdir()) == ["grasp-new.png"]


def test_a_staged_working_folder_drops_folders_and_links_but_not_what_a_link_points_to(tmp_path, monkeypatch):
    out, elsewhere = tmp_path / "report", tmp_path / "elsewhere"
    (out / "grasp-old").mkdir(parents=True)
    (out / "grasp-old" / "fig.png").write_text("old")
    elsewhere.mkdir()
    (elsewhere / "keep.txt").write_text("not ours")
    (out / "grasp-link").symlink_to(elsewhere)
    monkeypatch.chdir(out)
    with staged_dir(out, drop=lambda name: name.startswith("grasp-")) as folder:
        (folder / "index.html").write_text("new page")
    assert sorted(p.name for p in out.iterdir()) == ["index.html"]
    assert (elsewhere / "keep.txt").read_text() == "not ours"


@pytest.mark.parametrize("given_as_dot", [False, True])
def test_a_staged_working_folder_without_drop_is_filled_in_place_keeping_every_entry(tmp_path, monkeypatch,
                                                                                   given_as_dot):
    out = tmp_path / "report"
    out.mkdir()
    (out / "mine.txt").write_text("kept")
    monkeypatch.chdir(out)
    with staged_dir("." if given_as_dot else out) as folder:
        (folder / "index.html").write_text("new page")
    assert sorted(p.name for p in out.iterdir()) == ["index.html", "mine.txt"]


def test_symlinks_are_carried_as_links_where_the_file_system_has_no_hard_links(tmp_path, monkeypatch):
    out = tmp_path / "report"
    out.mkdir()
    (out / "mine.txt").write_text("kept")
    (out / "gone").symlink_to(tmp_path / "missing")

    def no_hard_links(*args, **kwargs):
        raise OSError(errno.EPERM, "hard links not supported")

    monkeypatch.setattr(os, "link", no_hard_links)
    with staged_dir(out) as folder:
        (folder / "index.html").write_text("new")
    assert (out / "gone").is_symlink() and (out / "mine.txt").read_text() == "kept"


def test_a_link_the_block_wrote_is_not_replaced_by_the_old_entry_of_that_name(tmp_path):
    out = tmp_path / "report"
    out.mkdir()
    (out / "latest").write_text("old")
    with staged_dir(out) as folder:
        (folder / "latest").symlink_to(tmp_path / "not-yet")  # dangling: it does not "exist"
    assert os.readlink(out / "latest") == str(tmp_path / "not-yet")
    assert not (tmp_path / "not-yet").exists()
