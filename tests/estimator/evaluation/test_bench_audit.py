"""``estimator.evaluation.bench``: which figures each configuration's entry carries, counted over which
grasps, and how its latency is taken (audit: a figure that could change silently)."""

from __future__ import annotations

import dataclasses
import math
from types import SimpleNamespace

import numpy as np
import pytest

from estimator.estimate import Estimate
from estimator.evaluation import bench as bench_module
from estimator.evaluation.bench import BenchConfig, bench, timed
from estimator.evaluation.evaluate import evaluate_record, result_row
from estimator.evaluation.metrics import summarise
from estimator.settings import estimator_settings
from haptics.settings import display_range_pa
from teleop.catalogue import load_catalogue
from teleop.errors import SettingsError
from teleop.record import read_record, write_record
from teleop.settings import load_settings
from teleop.sim.grasp import simulate_grasp


@pytest.fixture(scope="module")
def records(tmp_path_factory):
    """(three labelled grape records, an unlabelled copy, settings)."""
    settings = load_settings()
    grape = next(o for o in load_catalogue() if o.name == "grape")
    record, _ = simulate_grasp(grape, settings=settings, rng=np.random.default_rng(0))
    folder = tmp_path_factory.mktemp("bench_audit")
    good = [write_record(record, folder / f"g{i}.grasp") for i in range(3)]
    unlabelled = write_record(dataclasses.replace(record, label=None), folder / "nolabel.grasp")
    return good, unlabelled, settings


TICK = 2.0 ** -10


class Clock:
    """A stand-in for ``time``: each configuration's run moves it on by the next of its steps, in ticks of
    2**-10 s (exact in binary, so equal steps give equal latencies)."""

    def __init__(self) -> None:
        self.now = 0.0

    def perf_counter(self) -> float:
        return self.now

    def runner(self, estimate: Estimate, steps_ms, seen=None):
        steps = iter(steps_ms)

        def run(record):
            if seen is not None:
                seen.append(record.frames[0].reduce)
            self.now += next(steps) * TICK
            return estimate
        return run


def test_timed_gives_the_warm_up_estimate_and_the_median_of_the_repeats(monkeypatch):
    clock = Clock()
    monkeypatch.setattr(bench_module, "time", SimpleNamespace(perf_counter=clock.perf_counter))
    answers = iter([Estimate.ok("series", 1e5, 5e4, 2e5), *[Estimate.refuse("series", "later")] * 3])
    steps = iter([100.0, 1.0, 2.0, 10.0])

    def run(record):
        clock.now += next(steps) / 1e3
        return next(answers)

    estimate, ms = timed(run, None, 3)
    assert estimate.state == "ok" and ms == pytest.approx(2.0, rel=1e-6)  # the warm-up (100 ms) is not timed


def test_each_configuration_is_scored_under_its_own_name_with_felt_figures_refusals_and_latency(records,
                                                                                                monkeypatch):
    good, unlabelled, settings = records
    truth = read_record(good[0]).label.modulus_pa
    soft, rigid = display_range_pa(settings)
    assert soft < truth < rigid / 10  # the far estimate is clipped by the display: felt and paper errors differ
    clock = Clock()
    monkeypatch.setattr(bench_module, "time", SimpleNamespace(perf_counter=clock.perf_counter))
    own = estimator_settings(settings).depth_binning
    seen_far, seen_fine, seen_reference = [], [], []
    reference = bench_module.no_contact_reference

    def watched_reference(record, *args, **kwargs):
        seen_reference.append(record.frames[0].reduce)
        return reference(record, *args, **kwargs)

    monkeypatch.setattr(bench_module, "no_contact_reference", watched_reference)
    far = Estimate.ok("series", rigid * 100, rigid * 50, rigid * 200)
    near = Estimate.ok("series", truth * 5, truth * 4, truth * 6)
    configs = [
        # per grasp: warm-up, then one timed repeat
        BenchConfig("far", "analytical", "series", None, None,
                    clock.runner(far, [0, 1.0, 0, 2.0, 0, 9.0], seen_far), own),
        BenchConfig("near", "sampled", "series", 3, None, clock.runner(near, [0, 5.0] * 3), own),
        BenchConfig("fine", "analytical", "series", None, None,
                    clock.runner(far, [0, 5.0] * 3, seen_fine), 4),
        BenchConfig("refuser", "analytical", "hertz", None, None,
                    clock.runner(Estimate.refuse("hertz", "no"), [0, 0.5] * 3), own),
        BenchConfig("hybrid[x]", "model", "hybrid", 3, (16, 22),
                    clock.runner(Estimate.ok("hybrid", truth, truth / 2, truth * 2, "model: m"), [0, 5.0] * 3), own),
        BenchConfig("auto[x]", "auto", "auto", 3, (16, 22),
                    clock.runner(Estimate.ok("auto", truth, truth / 2, truth * 2, "model: m"), [0, 5.0] * 3), own),
    ]
    result = bench([good[0], unlabelled, *good[1:]], settings=settings, configs=configs, repeats=1, progress=False)

    assert (result["records"], result["labelled"]) == (4, 3)
    assert result["skipped"] == {"unlabelled": 1}
    assert result["skipped_records"] == [{"path": str(unlabelled), "cause": "unlabelled: no label"}]
    assert result["reference_ms_p50"] is not None
    assert seen_far == [own] * 6 and seen_fine == [4] * 6  # warm-up and repeat: each read the frames at its own binning
    assert seen_reference == [own] * 6  # the no-contact reference at the settings' binning
    out = {c["name"]: c for c in result["configs"]}
    assert list(out) == [c.name for c in configs]

    answers = [far, near, far, Estimate.refuse("hertz", "no"),
               Estimate.ok("hybrid", truth, truth / 2, truth * 2, "model: m"),
               Estimate.ok("auto", truth, truth / 2, truth * 2, "model: m")]
    rows = [result_row(p, read_record(p).label, c.name, e) for p in good for c, e in zip(configs, answers, strict=True)]
    expected = summarise(rows, [c.name for c in configs], display_range_pa=(soft, rigid))
    for name, entry in out.items():
        for key in ("felt_log10_error", "felt_within_2x", "log10_error", "within_10x", "n"):
            assert entry[key] == expected[name][key], (name, key)

    assert out["far"]["felt_log10_error"] == pytest.approx(math.log10(rigid / truth))
    assert out["far"]["log10_error"] == pytest.approx(math.log10(rigid * 100 / truth))
    assert (out["near"]["within_10x"], out["near"]["felt_within_2x"]) == (1.0, 0.0)
    assert (out["far"]["n"], out["far"]["refusals"]) == (3, 0)
    assert (out["refuser"]["n"], out["refuser"]["refusals"]) == (0, 3)
    assert out["auto[x]"]["answered_by"] == {"model": 3} and "answered_by" not in out["hybrid[x]"]

    # latency: the median over grasps of each grasp's time, and the 90th percentile
    assert out["far"]["latency_ms_p50"] == pytest.approx(2.0 * TICK * 1e3)
    assert out["far"]["latency_ms_p90"] == pytest.approx(float(np.quantile([1.0, 2.0, 9.0], 0.9)) * TICK * 1e3)

    # the frontier weighs latency, felt error and refusals: the fast refuser answers nothing (no error),
    # "far" is fastest of those that answer; "hybrid"/"auto" tie, each undominated; "near"/"fine" lose
    assert {n: c["pareto"] for n, c in out.items()} == {
        "far": True, "near": False, "fine": False, "refuser": False, "hybrid[x]": True, "auto[x]": True}


def test_a_slower_configuration_answering_every_grasp_stays_beside_a_faster_one_that_refuses(records, monkeypatch):
    good, _, settings = records
    truth = read_record(good[0]).label.modulus_pa
    clock = Clock()
    monkeypatch.setattr(bench_module, "time", SimpleNamespace(perf_counter=clock.perf_counter))
    own = estimator_settings(settings).depth_binning
    refusals = iter([Estimate.ok("hybrid", truth, truth / 2, truth * 2)] * 2 + [Estimate.refuse("hybrid", "x")] * 2)

    def sometimes(record):
        clock.now += TICK
        return next(refusals)

    configs = [
        BenchConfig("answers_one", "model", "hybrid", 3, (16, 22), sometimes, own),  # fast, exact, refuses one
        BenchConfig("answers_all", "analytical", "series", None, None,
                    clock.runner(Estimate.ok("series", truth * 3, truth, truth * 9), [0, 5.0] * 2), own),
    ]
    result = bench(good[:2], settings=settings, configs=configs, repeats=1, progress=False)
    out = {c["name"]: c for c in result["configs"]}
    assert out["answers_one"]["refusals"] == 1 and out["answers_all"]["refusals"] == 0
    assert out["answers_one"]["pareto"] and out["answers_all"]["pareto"]


def test_a_record_without_the_fingers_sensor_frames_or_decodable_frames_is_skipped_and_named_as_evaluate(
        records, tmp_path, monkeypatch):
    # It stopped the whole run with the record's FitError, naming no record; evaluate skips it as unreadable.
    good, _, settings = records
    record = read_record(good[0])
    right_only = write_record(dataclasses.replace(record, sensors=(record.sensor("right"),),
                                                  frames=(record.stream("right"),)), tmp_path / "rightonly.grasp")
    no_frames = write_record(dataclasses.replace(record, frames=(record.stream("right"),)), tmp_path / "noframes.grasp")
    garbled = write_record(dataclasses.replace(record, frames=tuple(dataclasses.replace(s, encoded=(b"x",) * len(s))
                                                                    for s in record.frames)), tmp_path / "garbled.grasp")
    clock = Clock()
    monkeypatch.setattr(bench_module, "time", SimpleNamespace(perf_counter=clock.perf_counter))
    truth = record.label.modulus_pa
    configs = [BenchConfig("series", "analytical", "series", None, None,
                           clock.runner(Estimate.ok("series", truth, truth / 2, truth * 2), [1.0] * 2),
                           estimator_settings(settings).depth_binning)]
    result = bench([right_only, good[0], no_frames, garbled], settings=settings, configs=configs, repeats=1,
                   progress=False)
    assert (result["records"], result["labelled"]) == (4, 1)
    assert result["skipped"] == {"unreadable": 3}
    causes = {entry["path"]: entry["cause"] for entry in result["skipped_records"]}
    assert list(causes) == [str(right_only), str(no_frames), str(garbled)]
    for path in (right_only, no_frames):
        [said] = evaluate_record(path, settings=settings, methods=["no_tactile"], calibration=None)
        assert causes[str(path)] == said["skipped"], path
    assert "no sensor on finger 'left'" in causes[str(right_only)]
    assert "no frames from finger 'left'" in causes[str(no_frames)]
    assert causes[str(garbled)].startswith("unreadable: ") and "does not decode" in causes[str(garbled)]
    assert result["configs"][0]["n"] == 1


def test_each_configuration_runs_its_own_method_binning_frames_mode_and_width_lag(monkeypatch):
    settings = load_settings()
    own = estimator_settings(settings).depth_binning
    asked = []

    def estimate(record, method, *, settings, calibration, correct_width_lag):
        asked.append((method, estimator_settings(settings).depth_binning, correct_width_lag))
        return Estimate.refuse(method, "stand-in")

    sampled = []

    def sample(record, *, settings, calibration, n_frames, size_px):
        sampled.append(n_frames)
        if n_frames == 5:
            return _Falsy()
        return _Sample([Estimate.refuse(m, f"{m} sampled") for m in ("no_tactile", "elastic", "hertz", "series")])

    class Hybrid:
        def __init__(self, predictor, *, settings, calibration):
            pass

        def estimate(self, record, *, mode):
            return Estimate.refuse("hybrid", mode)

    monkeypatch.setattr(bench_module, "estimate_grasp", estimate)
    monkeypatch.setattr(bench_module, "sample_grasp", sample)
    monkeypatch.setattr(bench_module, "calibration_for", lambda sensor, calibration: None)
    monkeypatch.setattr(bench_module, "HybridEstimator", Hybrid)
    variant = SimpleNamespace(name="rgb+markers+fw+analytical", n_frames=3, size_px=(16, 22), method="hybrid",
                              markers=True)
    record = SimpleNamespace(sensor=lambda finger: None)
    configs = bench_module.configurations(settings=settings, calibration=None, frames=[3, 5],
                                          models=[SimpleNamespace(variant=variant)], binning=[1],
                                          correct_width_lag=False)
    by_name = {c.name: c for c in configs}
    for c in configs:
        estimate_ = c.run(record)
        if c.kind == "analytical":
            assert asked[-1] == (c.method, c.binning, False), c.name
            assert c.binning == (1 if "/bin" in c.name else own), c.name
        elif c.kind == "sampled":
            assert sampled[-1] == c.n_frames and estimate_.method == c.method, c.name
            assert estimate_.reason == ("no loading phase" if c.n_frames == 5 else f"{c.method} sampled"), c.name
        else:
            assert estimate_.reason == ("model" if c.kind == "model" else "auto") and c.markers, c.name
    assert {"series/bin1", "hertz/bin1", "elastic/bin1"} <= set(by_name) and "no_tactile/bin1" not in by_name
    assert {"hybrid[rgb+markers+fw+analytical 3f 16x22]", "auto[rgb+markers+fw+analytical 3f 16x22]"} <= set(by_name)


class _Sample:
    """A sampled grasp that was measured: truthy, with one estimate per analytical method."""

    def __init__(self, estimates):
        self.estimates, self.reason = tuple(estimates), ""

    def __bool__(self) -> bool:
        return True


class _Falsy:
    """A sampled grasp without a sample: falsy, with its reason."""

    reason, estimates = "no loading phase", ()

    def __bool__(self) -> bool:
        return False


def test_a_grasp_without_a_segment_gives_no_reference_time(records, monkeypatch):
    good, _, settings = records
    monkeypatch.setattr(bench_module, "measure_grasp", lambda record, **kw: SimpleNamespace(segment=None))
    monkeypatch.setattr(bench_module, "no_contact_reference", lambda *a, **kw: pytest.fail("no segment to build on"))
    configs = [BenchConfig("refuser", "analytical", "hertz", None, None, lambda r: Estimate.refuse("hertz", "no"),
                           estimator_settings(settings).depth_binning)]
    result = bench(good[:1], settings=settings, configs=configs, repeats=1, progress=False)
    assert result["reference_ms_p50"] is None and result["configs"][0]["refusals"] == 1


def test_a_binning_the_grid_does_not_take_is_refused_naming_the_option():
    with pytest.raises(SettingsError, match=r"binning 3 \(--binning\), refused as the depth binning: "):
        bench_module.configurations(settings=load_settings(), calibration=None, frames=[], models=[], binning=[3])
