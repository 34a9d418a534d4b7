"""``teleop record`` refuses a bad option by the name the user typed, before it records anything."""

from __future__ import annotations

import pytest

import teleop.cli


@pytest.mark.parametrize(("option", "value", "expected"), [
    ("--chunk-kib", "0", "expected a whole number >= 1"),
    ("--chunk-kib", "-4", "expected a whole number >= 1"),
    ("--flush-interval-s", "0", "expected a number > 0"),
    ("--flush-interval-s", "nan", "expected a number > 0"),
])
def test_a_bad_chunk_or_flush_option_is_refused_by_its_name(tmp_path, capsys, option, value, expected):
    out = tmp_path / "session.mcap"
    with pytest.raises(SystemExit) as exited:
        teleop.cli.main(["record", "--out", str(out), "--duration-s", "0.1", option, value])
    err = capsys.readouterr().err
    assert exited.value.code == 2 and f"argument {option}: '{value}': {expected}" in err
    assert "chunk_bytes" not in err and "flush_interval_s" not in err  # not the recorder's own names
    assert not out.exists()  # refused before anything started
