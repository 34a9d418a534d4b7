"""A record without a sensor, or without frames, on the settings' finger: named with its cause and
skipped by ``estimator estimate`` (every method) and ``estimator evaluate``; the others are estimated."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest

from estimator.cli import main
from teleop.record import write_record
from teleop.settings import load_settings


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    """A good simulated grasp (``good``), the same with only the right sensor (``rightonly``) and
    with the left sensor but only the right frames (``noframes``)."""
    from teleop.catalogue import load_catalogue
    from teleop.settings import CONFIG_DIR
    from teleop.sim.grasp import simulate_grasp

    out = tmp_path_factory.mktemp("one_finger")
    settings = load_settings()
    puck = next(o for o in load_catalogue(CONFIG_DIR / "objects.toml") if o.name == "rubber_duck")
    record, _ = simulate_grasp(puck, settings=settings, rng=np.random.default_rng(5), seed=5)
    write_record(record, out / "good.grasp")
    write_record(replace(record, sensors=(record.sensor("right"),), frames=(record.stream("right"),)),
                 out / "rightonly.grasp")
    write_record(replace(record, frames=(record.stream("right"),)), out / "noframes.grasp")
    return out


@pytest.mark.slow
@pytest.mark.parametrize("method", ["auto", "series"])
def test_estimate_names_a_record_without_the_finger_and_estimates_the_rest(folder, method, capsys):
    bad, good = folder / "rightonly.grasp", folder / "good.grasp"
    assert main(["estimate", str(bad), str(good), "--method", method, "--json"]) == 2
    captured = capsys.readouterr()
    assert "Traceback" not in captured.err
    assert f"{bad}: SensingSettings.finger = 'left': no sensor on finger 'left'" in captured.err
    lines = [json.loads(line) for line in captured.out.splitlines()]
    assert [line["grasp"] for line in lines] == [str(bad), str(good)]
    assert "error" in lines[0] and lines[1]["state"] in ("ok", "lower_bound", "upper_bound")


@pytest.mark.slow
@pytest.mark.parametrize("methods", [["series"], ["no_tactile", "auto"]])
def test_evaluate_lists_a_record_without_the_fingers_frames_and_scores_the_rest(folder, methods, capsys):
    assert main(["evaluate", str(folder), "--methods", *methods, "--json"]) == 0
    result = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert result["skipped"] == {"unreadable": 2}
    causes = {s["path"]: s["cause"] for s in result["skipped_records"]}
    assert "no frames from finger 'left'" in causes[str(folder / "noframes.grasp")]
    assert "no sensor on finger 'left'" in causes[str(folder / "rightonly.grasp")]
    assert all(c.startswith("unreadable: SensingSettings.finger = 'left'") for c in causes.values())
    for method in methods:
        assert sum(result["methods"][method]["states"].values()) == 1
