"""teleop.staging on a read-only file system: removing the temporaries must not hide the real error."""

from __future__ import annotations

import errno
import os
import pathlib

import pytest

from teleop.staging import staged


def test_a_cleanup_the_file_system_refuses_leaves_the_blocks_own_error(tmp_path, monkeypatch):
    a, b = tmp_path / "a.txt", tmp_path / "b.txt"
    a.write_text("old")

    def read_only(self, missing_ok=False):  # EROFS, even for a file that is not there
        raise OSError(errno.EROFS, os.strerror(errno.EROFS), str(self))

    with pytest.raises(OSError) as raised, staged(a, b):
        monkeypatch.setattr(pathlib.Path, "unlink", read_only)
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), "the write")
    assert (raised.value.errno, raised.value.filename) == (errno.ENOSPC, "the write")
    monkeypatch.undo()
    assert a.read_text() == "old" and not b.exists()
