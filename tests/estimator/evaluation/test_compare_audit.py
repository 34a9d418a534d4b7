"""``estimator compare`` at its edges: the bootstrap's figures, the verdict's thresholds, what compare_models wires."""

from __future__ import annotations

import math
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from estimator.errors import EstimatorError
from estimator.evaluation import compare
from estimator.evaluation.compare import (
    LEVEL,
    MIN_OBJECTS,
    RESAMPLES,
    SEED,
    _better,
    compare_models,
    felt_difference,
    unseen_records,
    verdict,
)
from estimator.evaluation.metrics import felt_log10_error, felt_pa
from teleop.settings import load_settings

DISPLAY = (1e3, 1e7)
TRUTH = 1e5


def scored(method: str, name: str, error: float | None, i: int = 0, truth: float = TRUTH) -> dict:
    """A scored row of ``method`` on object ``name`` felt ``error`` decades too stiff; None: refused."""
    row = {"path": f"{name}_{i}.grasp", "object": name, "material": "rubber", "shape": "sphere", "truth_pa": truth,
           "method": method, "state": "ok", "e_pa": None, "low_pa": None, "high_pa": None, "reason": "r"}
    if error is None:
        return dict(row, state="insufficient_data")
    return dict(row, e_pa=truth * 10 ** error, low_pa=truth * 10 ** (error - 0.1), high_pa=truth * 10 ** (error + 0.1))


def rows_of(errors: dict[str, dict[str, list[float | None]]]) -> list[dict]:
    return [scored(method, name, e, i) for method, objects in errors.items()
            for name, values in objects.items() for i, e in enumerate(values)]


def stiffer_than_the_display() -> list[dict]:
    """A 1 GPa object: rendered rigid by the base (felt right: the label clipped to the rigid end), at 1 MPa by the
    candidate (felt 1 decade soft)."""
    rigid = DISPLAY[1]
    return [dict(scored("base", "g", 0.0, truth=1e9), state="lower_bound", e_pa=rigid, low_pa=rigid, high_pa=None),
            dict(scored("candidate", "g", 0.0, truth=1e9), e_pa=1e6, low_pa=5e5, high_pa=2e6)]


def reference(rows, resamples=RESAMPLES, level=LEVEL, seed=SEED):
    """The documented bootstrap, written out: objects drawn with replacement, both models' felt errors pooled over
    the grasps of the drawn objects, resamples where a model has no grasp left out; the percentile interval."""
    per_object: dict[str, list[list[float]]] = {}
    for r in rows:
        errors = per_object.setdefault(r["object"], [[], []])
        felt = felt_pa(r, display_range_pa=DISPLAY)
        if felt is not None:
            errors[("base", "candidate").index(r["method"])].append(
                felt_log10_error(felt, r["truth_pa"], display_range_pa=DISPLAY))
    objects = sorted(per_object)
    pooled = [[e for o in objects for e in per_object[o][m]] for m in (0, 1)]
    point = sum(pooled[1]) / len(pooled[1]) - sum(pooled[0]) / len(pooled[0])
    drawn = np.random.default_rng(seed).integers(0, len(objects), size=(resamples, len(objects)))
    differences = []
    for draw in drawn:
        grasps = [[e for i in draw for e in per_object[objects[i]][m]] for m in (0, 1)]
        if grasps[0] and grasps[1]:
            differences.append(sum(grasps[1]) / len(grasps[1]) - sum(grasps[0]) / len(grasps[0]))
    tail = (1 - level) / 2
    return point, [float(v) for v in np.quantile(differences, [tail, 1 - tail])], len(objects)


UNEVEN = {
    "base": {"a": [0.5, 0.4, 0.6], "b": [0.3], "c": [0.2, 0.1], "d": [0.7, None], "e": [None], "f": [0.4, 0.4]},
    "candidate": {"a": [0.1], "b": [0.2, 0.3, 0.1], "c": [None, 0.3], "d": [0.6, 0.5], "e": [None], "f": [None]},
}


@pytest.mark.parametrize("level, seed", [(LEVEL, SEED), (0.5, 3)])
def test_the_difference_is_pooled_over_grasps_and_the_interval_is_the_documented_bootstrap(level, seed):
    rows = rows_of(UNEVEN) + stiffer_than_the_display()
    point, interval, objects = reference(rows, level=level, seed=seed)
    diff = felt_difference(rows, display_range_pa=DISPLAY, level=level, seed=seed)
    assert diff["felt_log10_error"] == pytest.approx(point, abs=1e-12)
    assert diff["interval"] == pytest.approx(interval, abs=1e-12)
    assert diff["objects"] == objects == 7  # "e", refused by both, is still drawn
    assert (diff["level"], diff["resamples"], diff["seed"]) == (level, RESAMPLES, seed)


def test_the_defaults_are_2000_resamples_seeded_0_at_90_percent():
    assert (RESAMPLES, SEED, LEVEL, MIN_OBJECTS) == (2000, 0, 0.9, 3)
    rows = rows_of(UNEVEN)
    assert felt_difference(rows, display_range_pa=DISPLAY) == felt_difference(
        rows, display_range_pa=DISPLAY, resamples=2000, level=0.9, seed=0)


def test_resamples_where_a_model_answered_nothing_are_left_out():
    # Most resamples of three objects hold no grasp the candidate answered on "a" alone.
    rows = rows_of({"base": {"a": [0.5], "b": [0.3], "c": [None]}, "candidate": {"a": [0.1], "b": [None], "c": [None]}})
    diff = felt_difference(rows, display_range_pa=DISPLAY)
    assert diff["objects"] == 3 and all(math.isfinite(v) for v in diff["interval"])
    assert diff["interval"] == pytest.approx(reference(rows)[1], abs=1e-12)


@pytest.mark.parametrize("resamples, level", [(0, 0.9), (-1, 0.9), (10, 0.0), (10, 1.0), (10, 1.5)])
def test_a_bootstrap_without_resamples_or_a_level_outside_0_1_is_refused(resamples, level):
    with pytest.raises(EstimatorError, match=f"resamples {resamples}, level {level}"):
        felt_difference(rows_of(UNEVEN), display_range_pa=DISPLAY, resamples=resamples, level=level)


def test_one_resample_is_enough():
    assert felt_difference(rows_of(UNEVEN), display_range_pa=DISPLAY, resamples=1)["interval"] is not None


@pytest.mark.parametrize("objects, interval, better", [
    (MIN_OBJECTS, [-0.2, -0.1], "candidate"),
    (MIN_OBJECTS, [0.1, 0.2], "base"),
    (MIN_OBJECTS - 1, [-0.2, -0.1], "undecided"),
    (12, [-0.2, 0.0], "undecided"),  # an interval that reaches 0 contains it
    (12, [0.0, 0.2], "undecided"),
    (12, [-0.2, 0.2], "undecided"),
    (12, None, "undecided"),
])
def test_better_needs_the_whole_interval_on_one_side_of_0(objects, interval, better):
    assert _better({"objects": objects, "interval": interval}) == better


def _result(base_error=0.048, candidate_error=0.041, objects=12, better="candidate", misses=(1, 1)):
    return {"base": {"felt_log10_error": base_error, "dangerous_misses": misses[0]},
            "candidate": {"felt_log10_error": candidate_error, "dangerous_misses": misses[1]},
            "difference": {"felt_log10_error": -0.007, "interval": [-0.012, -0.002], "level": 0.9, "objects": objects},
            "grasps": 40, "n_objects": objects, "better": better, "dangerous_misses_increase": misses[1] > misses[0]}


@pytest.mark.parametrize("errors, who", [((0.05, None), "candidate"), ((None, 0.05), "base"),
                                         ((None, None), "base and candidate")])
def test_the_verdict_names_the_model_that_answered_nothing(errors, who):
    text = verdict(_result(*errors, better="undecided"))
    assert text == f"undecided: {who} answered none of the 40 grasps of 12 objects neither model trained on"


def test_the_verdict_at_the_object_minimum_blames_the_interval_and_says_no_more_misses_when_there_are_none():
    text = verdict(_result(objects=MIN_OBJECTS, better="undecided"))
    assert text.startswith("undecided (the interval contains 0): ")
    assert text.endswith("; dangerous misses 1 -> 1")
    assert verdict(_result(misses=(2, 1))).endswith("; dangerous misses 2 -> 1")


class _Models:
    """Stand-ins for two model directories: what compare_models reads of them, and the rows it would score."""

    def __init__(self, monkeypatch, rows):
        self.calls = []
        trained = {"base_dir": frozenset({"duck"}), "cand_dir": frozenset({"duck", "frog"})}
        monkeypatch.setattr(compare, "trained_objects", lambda d: trained[str(d)])
        monkeypatch.setattr(compare, "_predictor", lambda d: SimpleNamespace(
            variant=SimpleNamespace(method="hybrid", name="rgb+analytical"), measurement_code_matches=True,
            interval_level={"base_dir": 0.8, "cand_dir": 0.9}[d]))

        def evaluate_records(paths, **kwargs):
            self.calls.append(kwargs)
            return rows

        monkeypatch.setattr(compare, "evaluate_records", evaluate_records)


def _compared_rows():
    rows = rows_of({"base": {f"o{i}": [0.5, 0.4] for i in range(5)},
                    "candidate": {f"o{i}": [0.1, 0.05] for i in range(5)}})
    # A soft object rendered rigid by the base, and one the candidate shows as unknown (an interval over the range).
    rows += [dict(scored("base", "o5", 0.0, truth=5e5), e_pa=1e7, low_pa=1e7, high_pa=None, state="lower_bound"),
             dict(scored("candidate", "o5", 0.0, truth=5e5), e_pa=5e5, low_pa=1e2, high_pa=1e9)]
    rows += [{"path": "duck.grasp", "object": "duck", "skipped": "trained on: duck"},
             {"path": "frog.grasp", "object": "frog", "skipped": "trained on: frog"},
             {"path": "newt.grasp", "object": "newt", "skipped": "trained on: newt"},
             {"path": "toad.grasp", "object": "toad", "skipped": "unlabelled: no label"}]
    return rows


def test_compare_models_scores_both_models_and_says_which_is_better(monkeypatch):
    rows = _compared_rows()
    models = _Models(monkeypatch, rows)
    settings = load_settings()
    paths = [Path(f"g{i}.grasp") for i in range(15)]
    result = compare_models("base_dir", "cand_dir", paths, settings=settings, exclude=frozenset({"newt"}),
                            seed=7, resamples=300, progress=False)
    assert models.calls[0]["exclude"] == frozenset({"duck", "frog", "newt"})
    assert [m.method for m in models.calls[0]["models"]] == ["auto", "auto"]
    assert [s["cause"] for s in result["skipped"]] == [
        "base and candidate trained on duck", "candidate trained on frog", "given as excluded trained on newt",
        "unlabelled: no label"]
    assert result["objects"] == [f"o{i}" for i in range(6)] and result["n_objects"] == 6
    assert (result["records"], result["scored"], result["grasps"]) == (15, 11, 11)
    assert result["base"]["interval_level"] == 0.8 and result["candidate"]["interval_level"] == 0.9
    assert result["candidate"]["shown_unknown"] == 1 and result["candidate"]["answered"] == pytest.approx(10 / 11)
    assert result["base"]["answered"] == 1.0
    assert result["base"]["dangerous_misses"] == 1 and result["candidate"]["dangerous_misses"] == 0
    assert not result["dangerous_misses_increase"]
    from haptics.settings import display_range_pa

    assert result["difference"] == felt_difference(rows, display_range_pa=display_range_pa(settings), seed=7,
                                                   resamples=300)
    assert result["better"] == "candidate" and result["verdict"].startswith("candidate better: ")
    assert "paper" not in result["base"]


def test_compare_models_with_equal_misses_reports_no_increase_and_model_mode_uses_the_network(monkeypatch):
    rows = [r for r in _compared_rows() if r.get("object") != "o5"]
    models = _Models(monkeypatch, rows)
    result = compare_models("base_dir", "cand_dir", [Path("g.grasp")], settings=load_settings(), mode="model",
                            resamples=50, progress=False)
    assert [m.method for m in models.calls[0]["models"]] == ["hybrid", "hybrid"]
    assert result["base"]["method"] == "hybrid" and result["mode"] == "model"
    assert result["base"]["dangerous_misses"] == result["candidate"]["dangerous_misses"] == 0
    assert not result["dangerous_misses_increase"]


def test_compare_models_refuses_an_unknown_mode_before_reading_a_model(monkeypatch):
    monkeypatch.setattr(compare, "trained_objects", lambda d: pytest.fail("read a model"))
    with pytest.raises(EstimatorError, match="mode 'network': expected one of auto, model"):
        compare_models("base_dir", "cand_dir", [], settings=load_settings(), mode="network")


def test_unseen_records_keeps_the_labelled_records_of_other_objects(monkeypatch, tmp_path):
    labels = {"a.grasp": SimpleNamespace(object_name="duck", modulus_pa=1e6),
              "b.grasp": SimpleNamespace(object_name="frog", modulus_pa=1e6),
              "c.grasp": SimpleNamespace(object_name="newt", modulus_pa=None),
              "d.grasp": None}
    paths = [tmp_path / name for name in labels]
    monkeypatch.setattr(compare, "find_records", lambda records: paths)
    monkeypatch.setattr(compare, "read_record", lambda path: SimpleNamespace(label=labels[path.name]))
    kept, skipped = unseen_records(tmp_path, frozenset({"duck"}))
    assert kept == [tmp_path / "b.grasp"]
    assert skipped == [{"path": str(tmp_path / "a.grasp"), "cause": "trained on: duck"},
                       {"path": str(tmp_path / "c.grasp"), "cause": "unlabelled"},
                       {"path": str(tmp_path / "d.grasp"), "cause": "unlabelled"}]


def test_a_bootstrap_whose_resamples_all_lack_one_models_grasps_has_no_interval_rather_than_crashing():
    # The candidate answered on "a" alone; the one resample of seed 0 does not draw "a".
    rows = rows_of({"base": {"a": [0.5], "b": [0.3], "c": [None]}, "candidate": {"a": [0.1], "b": [None], "c": [None]}})
    diff = felt_difference(rows, display_range_pa=DISPLAY, resamples=1, seed=0)
    assert diff["felt_log10_error"] == pytest.approx(0.1 - 0.4) and diff["interval"] is None
    assert _better(diff) == "undecided"
    result = dict(_result(better="undecided", objects=3), difference=dict(diff, objects=3))
    assert verdict(result).startswith("undecided (no interval: no resample held grasps both models answered): ")
