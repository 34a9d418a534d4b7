"""A log still being written, read as it grows: its damage is told at its size when told, not at open."""

from __future__ import annotations

from teleop.session import LogReader
from teleop.session.logfile import LogReader as _Reader


def test_a_log_that_grows_while_it_is_read_says_so_and_no_byte_past_its_size(tmp_path, recorded, monkeypatch):
    whole = recorded.path.read_bytes()
    at_open, later = len(whole) // 3, 2 * len(whole) // 3
    growing = tmp_path / "growing.mcap"
    growing.write_bytes(whole[:at_open])
    summary = _Reader._summary

    def grown_after_open(self, file):  # the recorder appends after the reader took the file's size
        if growing.stat().st_size == at_open:
            with growing.open("ab") as out:
                out.write(whole[at_open:later])
        return summary(self, file)

    monkeypatch.setattr(_Reader, "_summary", grown_after_open)
    reader = LogReader(growing)
    list(reader.messages())
    assert reader.stopped and at_open < reader.good_bytes <= later
    assert reader.damage.startswith(f"the file ends inside the record after byte {reader.good_bytes} of {later} ")
    assert reader.damage.endswith(f"; the file grew from {at_open} to {later} bytes while it was read: it is still "
                                  "being written")


def test_a_log_cut_while_it_is_read_is_said_to_have_shrunk(tmp_path):
    from teleop.session.logdamage import describe

    cut = tmp_path / "cut.mcap"
    cut.write_bytes(b"x" * 58)
    with cut.open("rb") as file:
        said = describe(ValueError("bad record"), file, 8, 100, 8, None)
        assert "shrank from 100 to 58 bytes" in said and "grew" not in said
        said = describe(ValueError("bad record"), file, 80, 100, 80, None)  # a record read before the cut
        assert "after byte 80 of 100" in said and "shrank from 100 to 58 bytes" in said
