"""``estimator compare`` and ``estimator fine-tune --compare``: which model is better on objects neither trained on."""

from __future__ import annotations

import json
import shutil

import pytest

from estimator.cli import main
from estimator.evaluation.compare import (
    MIN_OBJECTS,
    NothingToCompare,
    _better,
    compare_models,
    felt_difference,
    verdict,
)
from estimator.evaluation.compare_cli import print_comparison
from teleop.settings import load_settings

DISPLAY = (1e3, 1e7)


def rows_of(errors: dict[str, dict[str, list[float]]]) -> list[dict]:
    """Scored ``ok`` rows whose felt error is the given one (decades), per method and object."""
    rows = []
    for method, objects in errors.items():
        for name, values in objects.items():
            for i, error in enumerate(values):
                truth = 1e5
                rows.append({"path": f"{name}_{i}.grasp", "object": name, "material": "rubber", "shape": "sphere",
                             "truth_pa": truth, "method": method, "state": "ok", "e_pa": truth * 10 ** error,
                             "low_pa": truth * 10 ** (error - 0.1), "high_pa": truth * 10 ** (error + 0.1),
                             "reason": "r"})
    return rows


def test_the_difference_and_its_interval_come_from_a_bootstrap_over_objects():
    base = {f"o{i}": [0.5, 0.4] for i in range(6)}
    better = {f"o{i}": [0.1, 0.2] for i in range(6)}
    diff = felt_difference(rows_of({"base": base, "candidate": better}), display_range_pa=DISPLAY)
    assert diff["felt_log10_error"] == pytest.approx(0.15 - 0.45, abs=1e-6)
    low, high = diff["interval"]
    assert low <= diff["felt_log10_error"] <= high < 0 and diff["objects"] == 6 and diff["level"] == 0.9
    again = felt_difference(rows_of({"base": base, "candidate": better}), display_range_pa=DISPLAY)
    assert again == diff  # seeded

    # Better on some objects, worse on others: the interval straddles 0.
    mixed = {f"o{i}": ([0.1, 0.1] if i % 2 else [0.8, 0.8]) for i in range(6)}
    straddle = felt_difference(rows_of({"base": base, "candidate": mixed}), display_range_pa=DISPLAY)
    assert straddle["interval"][0] < 0 < straddle["interval"][1]
    assert [_better(d) for d in (diff, straddle)] == ["candidate", "undecided"]
    assert _better(felt_difference(rows_of({"base": better, "candidate": base}), display_range_pa=DISPLAY)) == "base"
    few = {name: values for name, values in list(base.items())[:MIN_OBJECTS - 1]}
    assert _better(felt_difference(rows_of({"base": few, "candidate": {o: [0.0] for o in few}}),
                                   display_range_pa=DISPLAY)) == "undecided"  # too few objects to tell
    # A model that answered nothing: no difference.
    refused = [dict(r, state="insufficient_data", e_pa=None, low_pa=None, high_pa=None)
               for r in rows_of({"candidate": better})]
    none = felt_difference(rows_of({"base": base}) + refused, display_range_pa=DISPLAY)
    assert none["felt_log10_error"] is None and none["interval"] is None


def test_the_verdict_says_which_and_by_how_much():
    def result(diff, objects, misses=(1, 1), better="candidate"):
        return {"base": {"felt_log10_error": 0.048, "dangerous_misses": misses[0]},
                "candidate": {"felt_log10_error": 0.041, "dangerous_misses": misses[1]},
                "difference": {"felt_log10_error": -0.007, "interval": diff, "level": 0.9, "objects": objects},
                "grasps": 286, "n_objects": objects, "better": better,
                "dangerous_misses_increase": misses[1] > misses[0]}

    text = verdict(result([-0.012, -0.002], 12))
    assert text.startswith("candidate better: felt error 0.048 -> 0.041 decade")
    assert "-0.007, 90 % interval -0.012 to -0.002" in text and "286 grasps of 12 objects" in text
    text = verdict(result([-0.012, 0.004], 12, misses=(3, 5), better="undecided"))
    assert text.startswith("undecided (the interval contains 0)") and "dangerous misses 3 -> 5 (more" in text
    assert f"at least {MIN_OBJECTS} are needed" in verdict(result([-0.01, -0.01], 2, better="undecided"))


@pytest.mark.slow
def test_compare_scores_both_models_on_objects_neither_trained_on(sim_grasps, trained_model, tmp_path, capsys):
    records, calibration = sim_grasps
    # A "fine-tuned" copy: same network, and the rubber duck among the objects it was tuned on.
    candidate = tmp_path / "candidate"
    shutil.copytree(trained_model, candidate)
    meta = json.loads((candidate / "metadata.json").read_text())
    meta["fine_tuning"] = {"objects": ["rubber_duck"]}
    (candidate / "metadata.json").write_text(json.dumps(meta))

    result = compare_models(trained_model, candidate, records, settings=load_settings(), calibration=str(calibration),
                            progress=False)
    assert result["objects"] == ["silicone_ball_shore00_30", "steel_ball_bearing", "stress_ball"]
    assert [s["cause"] for s in result["skipped"]] == ["candidate trained on rubber_duck"]
    for role in ("base", "candidate"):
        m = result[role]
        assert {"felt_log10_error", "felt_within_2x", "dangerous_misses", "interval_coverage", "answered",
                "soft_interval_width_decades_median", "states"} <= set(m)
        assert sum(m["states"].values()) == 3 and m["method"] == "auto"
    # The same network on the same grasps: no difference, so no verdict either way.
    assert result["difference"]["felt_log10_error"] == pytest.approx(0.0, abs=1e-12)
    assert result["better"] == "undecided" and not result["dangerous_misses_increase"]

    argv = ["compare", str(records), "--base", str(trained_model), "--candidate", str(candidate),
            "--calibration", str(calibration)]
    assert main([*argv, "--json"]) == 0
    printed = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert printed["better"] == "undecided" and printed["base"]["n"] == result["base"]["n"]
    assert main(argv) == 0
    out = capsys.readouterr().out
    assert "rubber_duck.grasp: candidate trained on rubber_duck" in out
    assert "compared on 3 grasps of 3 objects neither model trained on" in out
    assert out.strip().splitlines()[-1].startswith("undecided (the interval contains 0): felt error")

    # Nothing left to compare on: a clear error, every record listed with its cause.
    meta["fine_tuning"] = {"objects": sorted(p.stem for p in records.glob("*.grasp"))}
    (candidate / "metadata.json").write_text(json.dumps(meta))
    with pytest.raises(NothingToCompare, match="no labelled record of an object neither model trained on"):
        compare_models(trained_model, candidate, records, settings=load_settings(), progress=False)
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err and "stress_ball.grasp: candidate trained on stress_ball" in err
    assert main(["compare", str(records), "--base", str(tmp_path / "typo"), "--candidate", str(candidate)]) == 2
    assert f"--base model folder {tmp_path / 'typo'} does not exist" in capsys.readouterr().err


@pytest.mark.slow
def test_fine_tune_prints_the_verdict_on_records_it_did_not_train_on(trained_model, synthetic, sim_grasps, tmp_path,
                                                                    capsys):
    records, _ = sim_grasps
    data = synthetic.write_dataset(tmp_path / "d", seed=5)
    args = ["fine-tune", "--model", str(trained_model), "--data", str(data), "--out", str(tmp_path / "m"),
            "--epochs", "1", "--compare", str(records)]
    assert main([*args, "--json"]) == 0
    summary = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    compared = summary["compare"]
    assert compared["better"] in {"base", "candidate", "undecided"}
    assert compared["candidate"]["model"] == str(tmp_path / "m") and compared["base"]["model"] == str(trained_model)
    assert compared["n_objects"] == len(list(records.glob("*.grasp")))  # catalogue objects: neither trained on them
    assert compared["difference"]["interval"] is not None


def test_fine_tune_refuses_a_mistyped_model_and_compare_records_it_trained_on(trained_model, synthetic, tmp_path,
                                                                            capsys):
    data = synthetic.write_dataset(tmp_path / "d", seed=5)
    for option, command in (("--model", "fine-tune"), ("--init", "train")):
        assert main([command, option, str(tmp_path / "typo"), "--data", str(data), "--out",
                     str(tmp_path / "m")]) == 2
        err = capsys.readouterr().err
        assert "Traceback" not in err and f"{option} {tmp_path / 'typo'}: no such directory" in err
    assert main(["fine-tune", "--model", str(trained_model), "--data", str(data), "--out", str(tmp_path / "m"),
                 "--replay", str(tmp_path / "typo")]) == 2
    assert f"--replay {tmp_path / 'typo'}: no such directory" in capsys.readouterr().err

    # Records only of objects the base model or the fine-tuning data trained on: refused before any training.
    from teleop.catalogue import load_catalogue
    from teleop.settings import CONFIG_DIR

    records = tmp_path / "records"
    records.mkdir()
    settings = load_settings()
    stress_ball = next(o for o in load_catalogue(CONFIG_DIR / "objects.toml") if o.name == "stress_ball")
    _write_grasp_of(stress_ball, "foam_a", records / "g.grasp", settings)
    assert main(["fine-tune", "--model", str(trained_model), "--data", str(data), "--out", str(tmp_path / "m"),
                 "--compare", str(records)]) == 2
    err = capsys.readouterr().err
    assert f"--compare {records}: no labelled record of an object neither" in err and "1 trained on" in err
    assert not (tmp_path / "m").exists()


def _write_grasp_of(obj, name, path, settings):
    """A simulated grasp of ``obj`` labelled as the object ``name``."""
    from dataclasses import replace

    import numpy as np

    from teleop.record import write_record
    from teleop.sim.grasp import simulate_grasp

    record, _ = simulate_grasp(obj, settings=settings, rng=np.random.default_rng(0), seed=0)
    write_record(replace(record, label=replace(record.label, object_name=name)), path)


@pytest.mark.parametrize("soft_n, noted", [(0, True), (2, False)])
def test_a_comparison_without_soft_objects_says_it_cannot_test_the_scale(capsys, soft_n, noted):
    row = {"n": 3, "felt_log10_error": 0.0, "felt_within_2x": 1.0, "dangerous_misses": 0, "rigid_shown_rigid": 1.0,
           "answered": 1.0, "interval_coverage": 1.0, "interval_width_decades_median": 0.1,
           "soft_interval_width_decades_median": None, "model": "m", "soft_n": soft_n}
    print_comparison({"grasps": 3, "n_objects": 3, "records": 3, "mode": "auto", "base": row, "candidate": row,
                      "verdict": "undecided"})
    assert ("no soft object (label at or below 3 MPa)" in capsys.readouterr().out) is noted
