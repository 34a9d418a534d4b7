"""``estimator recalibrate``'s command line: its options reach the work, and what it prints."""

from __future__ import annotations

import json

import pytest
from support.rig_settings import rig_settings

from estimator.cli import main
from estimator.training import recalibrate_cli
from estimator.training.recalibrate_cli import _print_cross_validation

CALIBRATION = {"temperature": 1.5, "coverage": 0.88, "n": 12, "force_band_edges_n": [], "p_rigids": [0.9],
               "interval_scales": [1.2]}


def test_cross_validation_gets_the_seed_and_the_settings_given(tmp_path, monkeypatch, capsys):
    got = {}
    monkeypatch.setattr(recalibrate_cli, "cross_validate", lambda *args, **kwargs: got.update(args=args, **kwargs)
                        or {"folds": 3})
    settings = rig_settings(tmp_path, {"sensors.left.depth_resolution_m": 6e-5})
    assert main(["recalibrate", "--model", "m", "--data", "d", "--cross-validate", "3", "--seed", "11",
                 "--settings", str(settings), "--json"]) == 0
    assert got["args"] == ("m", "d") and (got["folds"], got["seed"]) == (3, 11)
    assert got["settings"].source == settings
    assert json.loads(capsys.readouterr().out.strip().splitlines()[-1]) == {"folds": 3}


def test_recalibrating_gets_the_settings_given_and_prints_old_and_new(tmp_path, monkeypatch, capsys):
    got = {}

    def fake(model, data, **kwargs):
        got.update(kwargs)
        new = {**CALIBRATION, "temperature": 2.25, "coverage": 0.91}
        return {"calibration": new, "recalibrated": {"previous": {**CALIBRATION, "temperature": None}, "left_out": []},
                "metrics": {"val": {"n": 12}, "test": {"n": 9}}}

    monkeypatch.setattr(recalibrate_cli, "recalibrate", fake)
    settings = rig_settings(tmp_path, {"sensors.left.depth_resolution_m": 6e-5})
    assert main(["recalibrate", "--model", "m", "--data", "d", "--settings", str(settings)]) == 0
    assert got["settings"].source == settings and got["out_dir"] is None and got["overwrite"] is False
    captured = capsys.readouterr()
    shown = captured.out
    assert "note" not in captured.err
    assert "temperature            - -> 2.25" in shown and "coverage            0.88 -> 0.91" in shown
    assert "on 12 val grasps; wrote m/metadata.json" in shown
    assert main(["recalibrate", "--model", "m", "--data", "d", "--out", "o", "--json"]) == 0
    printed = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert printed["out"] == "o" and printed["calibration"]["temperature"] == 2.25 and got["out_dir"] == "o"


@pytest.mark.parametrize("left_out", [[], ["tofu", "foam_block"]])
def test_a_recalibration_with_no_test_grasps_left_says_so(tmp_path, monkeypatch, capsys, left_out):
    meta = {"calibration": CALIBRATION, "recalibrated": {"previous": CALIBRATION, "left_out": left_out},
            "metrics": {"val": {"n": 12}, "test": {}}}
    monkeypatch.setattr(recalibrate_cli, "recalibrate", lambda model, data, **kwargs: meta)
    assert main(["recalibrate", "--model", "m", "--data", "d"]) == 0
    err = capsys.readouterr().err
    assert "note: no test grasps to score" in err and "metrics.test is empty" in err
    assert ("(tofu, foam_block) are left out" in err) == bool(left_out)


def test_overwrite_without_out_is_refused(capsys):
    assert main(["recalibrate", "--model", "m", "--data", "d", "--overwrite"]) == 2
    assert "--overwrite: replaces a model in --out" in capsys.readouterr().err


def test_the_cross_validation_shows_a_dash_for_figures_over_no_grasp(capsys):
    metrics = {"rigid_shown_rigid": None, "soft_interval_width_decades_median": None, "felt_log10_error": 0.21,
               "felt_within_2x": 0.75, "dangerous_misses": 1, "interval_coverage": 0.9}
    _print_cross_validation({"folds": 2, "seed": 0, "objects": 3, "grasps": 6, "method": "hybrid", "level": 0.9,
                             "metrics": metrics, "force_band_edges_n": [10.0], "band_n": [6, 0],
                             "band_coverage": [0.9, None]})
    shown = capsys.readouterr().out
    assert "rigid shown rigid -" in shown and "median width - at or below" in shown
    assert "felt error      0.2100 decade, 75.0 % within a factor 2" in shown
    assert shown.rstrip().splitlines()[-1].endswith("0 grasps, coverage -")


@pytest.mark.parametrize("rigid", [0.5])
def test_the_cross_validation_shows_the_rigid_share_in_percent(rigid, capsys):
    metrics = {"rigid_shown_rigid": rigid, "soft_interval_width_decades_median": 0.4, "felt_log10_error": 0.2,
               "felt_within_2x": 0.5, "dangerous_misses": 0, "interval_coverage": 0.85}
    _print_cross_validation({"folds": 2, "seed": 0, "objects": 3, "grasps": 6, "method": "hybrid", "level": 0.9,
                             "metrics": metrics, "force_band_edges_n": [], "band_n": [6], "band_coverage": [0.85]})
    shown = capsys.readouterr().out
    assert "rigid shown rigid 50.0 %" in shown and "median width 0.40 decade" in shown
