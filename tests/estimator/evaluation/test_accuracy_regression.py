"""The shipped default model on a small fixed set of grasps it never trained on: a retrain that
regresses what the operator feels fails here.

Fourteen objects of the demo catalogue (``configs/objects.toml``; none is in the published
table the models trained on), foam to steel, one grasp each on the nominal simulated Wedge,
simulated with a fixed seed, scored by ``estimator evaluate`` as the display renders them.
The bounds are the shipped model's figures on this set when it was trained (see
``MEASURED``) with a margin: a model may differ, but not be clearly worse.
"""

from __future__ import annotations

import json

import pytest

from estimator.cli import main as estimator_main
from estimator.inference.infer import default_model_dir
from teleop.cli import main as teleop_main
from teleop.settings import config_dir

OBJECTS = ("memory_foam_cube", "kitchen_sponge", "stress_ball", "silicone_ball_shore00_30", "grape", "gummy_bear",
           "eva_foam_block", "rubber_duck", "bouncy_ball", "hockey_puck", "hdpe_bottle_cap", "oak_block",
           "aluminium_block", "steel_ball_bearing")
SEED = 21
#: The shipped default's figures on this set, measured when it was shipped (felt error in decades,
#: share within a factor 2, dangerous misses), and the worst a model may do here.
MEASURED = {"felt_log10_error": 0.135, "felt_within_2x": 12 / 14, "dangerous_misses": 1}
WORST = {"felt_log10_error": 0.18, "felt_within_2x": 11 / 14, "dangerous_misses": 1}


@pytest.mark.slow
def test_the_shipped_model_feels_this_set_as_well_as_when_it_was_trained(tmp_path, capsys, missing_data):
    if not (default_model_dir() / "model.onnx").is_file():
        missing_data("no shipped default model")
    records = tmp_path / "records"
    assert teleop_main(["simulate", "--objects", str(config_dir() / "objects.toml"), "--only", ",".join(OBJECTS),
                        "--seed", str(SEED), "--out", str(records), "--workers", "2"]) == 0
    capsys.readouterr()
    assert estimator_main(["evaluate", str(records), "--model", str(default_model_dir()), "--methods", "hybrid",
                           "--json"]) == 0
    hybrid = json.loads(capsys.readouterr().out.strip().splitlines()[-1])["methods"]["hybrid"]
    assert hybrid["n"] == len(OBJECTS)
    assert hybrid["felt_log10_error"] <= WORST["felt_log10_error"], hybrid
    assert hybrid["felt_within_2x"] >= WORST["felt_within_2x"] - 1e-9, hybrid
    assert hybrid["dangerous_misses"] <= WORST["dangerous_misses"], hybrid
