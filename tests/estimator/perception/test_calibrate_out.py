"""``estimator calibrate --out``: its folder is made, or refused, before any capture or fit."""

from __future__ import annotations

import argparse

import pytest

import estimator.perception.calibrate_cli as calibrate_cli
from estimator.cli import main


def _args(tmp_path, out):
    return argparse.Namespace(out=str(out), presses=str(tmp_path / "presses"), overwrite=False)


def test_a_missing_out_folder_is_made_before_the_fit(tmp_path):
    # The fit (and with --capture, every press) ran first, then the save failed: "No such file or directory".
    out = tmp_path / "calibration" / "left.npz"
    assert calibrate_cli._checked_out(_args(tmp_path, out)) == out
    assert out.parent.is_dir() and not out.exists()


def test_an_out_folder_that_cannot_be_made_is_refused_before_any_capture(tmp_path, capsys, monkeypatch):
    (tmp_path / "afile").write_text("not a folder")
    out = tmp_path / "afile" / "left.npz"

    def no_capture(*args):
        pytest.fail("captured before --out was checked")

    monkeypatch.setattr(calibrate_cli, "capture_to_folder", no_capture)
    code = main(["calibrate", "--capture", "--presses", str(tmp_path / "presses"), "--ball-radius-mm", "2",
                 "--out", str(out)])
    err = capsys.readouterr().err
    assert code == 2, err
    assert f"--out {out}: {tmp_path / 'afile'} is not a directory" in err, err
    assert "Traceback" not in err
