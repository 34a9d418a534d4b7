"""``estimator bench``: the Pareto frontier, coarser depth grids, and the command on a tiny directory."""

from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pytest

from estimator.cli import main
from estimator.evaluation import bench_cli
from estimator.evaluation.bench import configurations, pareto_front
from estimator.evaluation.evaluate import evaluate_record
from estimator.inference.sampling import decoded
from estimator.settings import estimator_settings
from teleop.catalogue import load_catalogue
from teleop.errors import SettingsError
from teleop.record import read_record, write_record
from teleop.settings import load_settings
from teleop.sim.grasp import simulate_grasp


def test_pareto_front_keeps_only_undominated_points():
    points = [(1.0, 2.0), (2.0, 1.0), (3.0, 1.5), (0.5, None), (2.0, 1.0), (10.0, 0.2), (1.0, 2.5)]
    assert pareto_front(points) == [True, True, False, False, True, True, False]
    assert pareto_front([]) == []
    assert pareto_front([(5.0, None)]) == [False]


def test_a_configuration_that_answers_more_grasps_is_not_dominated_by_one_that_refuses_them():
    # (latency ms, error over answered grasps, refusals): the hybrid refuses the grasps with no loading
    # frame, auto answers them with a worse force/width fallback and is as fast.
    hybrid, auto, slower_auto = (6.2, 0.70, 5), (6.3, 0.92, 0), (6.3, 0.95, 0)
    assert pareto_front([hybrid, auto]) == [True, True]
    assert pareto_front([hybrid, auto, slower_auto]) == [True, True, False]
    assert pareto_front([(6.2, 0.70, 0), auto]) == [True, False]


def test_the_analytical_configurations_score_as_evaluate_does_width_lag_and_all(tmp_path):
    # Simulated widths are stamped late, as a host stamps a gripper read when it returns: evaluate
    # corrects that by default, bench did not, so the two commands gave one method two errors.
    settings = load_settings()
    grape = next(o for o in load_catalogue() if o.name == "grape")
    record, _ = simulate_grasp(grape, settings=settings, rng=np.random.default_rng(0))
    path = write_record(record, tmp_path / "grape.grasp")
    scored = {}
    for correct in (True, False):
        [row] = evaluate_record(path, settings=settings, methods=["no_tactile"], calibration=None,
                                correct_width_lag=correct)
        configs = configurations(settings=settings, calibration=None, frames=[], models=[],
                                 correct_width_lag=correct)
        benched = next(c for c in configs if c.name == "no_tactile").run(record)
        assert (benched.state, benched.e_pa) == (row["state"], pytest.approx(row["e_pa"]))
        scored[correct] = row["e_pa"]
    assert scored[True] != pytest.approx(scored[False], rel=0.05)  # the lag moves this grasp's estimate
    assert next(c for c in configurations(settings=settings, calibration=None, frames=[], models=[])
                if c.name == "no_tactile").run(record).e_pa == pytest.approx(scored[True])  # by default


def test_bench_corrects_the_width_lag_unless_told_not_to_as_evaluate(tmp_path, monkeypatch, capsys):
    (tmp_path / "unreadable.grasp").write_bytes(b"")  # found; the run stops at the bench itself
    asked = []

    def recorded(**kwargs):
        asked.append(kwargs["correct_width_lag"])
        return []

    monkeypatch.setattr(bench_cli, "configurations", recorded)
    for extra in ([], ["--no-width-lag"]):
        assert main(["bench", str(tmp_path), "--models", *extra]) == 2
    assert asked == [True, False] and "no labelled, readable .grasp record" in capsys.readouterr().err


def _mixed_records(folder, *, good: bool):
    """In ``folder``: a labelled grape (when ``good``), an unlabelled copy, a text file and a truncated
    record, all named .grasp; returns the unlabelled, text and truncated paths."""
    settings = load_settings()
    grape = next(o for o in load_catalogue() if o.name == "grape")
    record, _ = simulate_grasp(grape, settings=settings, rng=np.random.default_rng(0))
    folder.mkdir(parents=True, exist_ok=True)
    whole = write_record(record, folder / "good.grasp").read_bytes()
    if not good:
        (folder / "good.grasp").unlink()
    unlabelled = write_record(dataclasses.replace(record, label=None), folder / "nolabel.grasp")
    (folder / "text.grasp").write_text("garbage\n")
    (folder / "trunc.grasp").write_bytes(whole[:1000])
    return [unlabelled, folder / "text.grasp", folder / "trunc.grasp"]


def test_bench_names_every_record_it_skips_and_why_as_evaluate(tmp_path, monkeypatch, capsys):
    # It skipped unreadable and unlabelled records counting them only; evaluate names each with its cause.
    bad = _mixed_records(tmp_path / "recs", good=True)
    every = bench_cli.configurations
    monkeypatch.setattr(bench_cli, "configurations",  # one cheap configuration: the skipping is under test
                        lambda **kw: [c for c in every(**kw) if c.name == "no_tactile"])
    assert main(["bench", str(tmp_path / "recs"), "--models", "--repeats", "1", "--json"]) == 0
    out, err = capsys.readouterr()
    [line] = out.strip().splitlines()  # stdout stays one JSON object
    result = json.loads(line)
    settings = load_settings()
    said = {str(p): evaluate_record(p, settings=settings, methods=[], calibration=None)[0]["skipped"] for p in bad}
    assert result["skipped_records"] == [{"path": path, "cause": cause} for path, cause in said.items()]
    assert said[str(bad[0])] == "unlabelled: no label" and said[str(bad[1])].startswith("unreadable: ")
    assert (result["records"], result["labelled"]) == (4, 1)
    assert result["skipped"] == {"unreadable": 2, "unlabelled": 1}
    assert "skipped 3 of 4 records:" in err
    for path, cause in said.items():
        assert f"  {path}: {cause}" in err


def test_bench_with_no_record_left_names_the_folder_and_each_cause(tmp_path, capsys):
    # It failed with "no labelled, readable .grasp record to bench", naming neither the folder nor a cause.
    folder = tmp_path / "recs"
    bad = _mixed_records(folder, good=False)
    assert main(["bench", str(folder), "--models", "--repeats", "1", "--json"]) == 2
    out, err = capsys.readouterr()
    assert out == ""
    assert (f"{folder}: no labelled, readable .grasp record to bench: 3 of 3 records skipped "
            "(2 unreadable, 1 unlabelled)") in err
    assert "skipped 3 of 3 records:" in err
    assert f"  {bad[0]}: unlabelled: no label" in err
    assert all(f"  {p}: unreadable: " in err for p in bad[1:])


@pytest.mark.slow
def test_the_binned_estimate_is_close_to_the_full_grid_one(sim_grasps):
    records, calibration = sim_grasps
    settings = load_settings()
    assert estimator_settings(settings).depth_binning == 2
    configs = {c.name: c for c in configurations(settings=settings, calibration=str(calibration), frames=[3],
                                                 models=[], binning=[1])}
    assert {"series/bin1", "hertz/bin1", "elastic/bin1"} <= set(configs) and "no_tactile/bin1" not in configs
    assert configs["series"].binning == 2 and configs["series/bin1"].binning == 1
    compared = 0
    for path in sorted(records.glob("*.grasp")):
        record = read_record(path)
        for method in ("series", "hertz"):
            coarse = configs[method].run(decoded(record, reduce=2))
            full = configs[f"{method}/bin1"].run(decoded(record))
            assert coarse.state == full.state, (path.name, method)
            if full.e_pa is not None:  # the same contact seen through 2 x 2 px blocks: within a tenth of a decade
                assert abs(math.log10(coarse.e_pa / full.e_pa)) < 0.1, (path.name, method)
                compared += 1
    assert compared >= 4
    with pytest.raises(SettingsError, match=r"binning 3 \(--binning\), refused as the depth binning: .*depth_binning = 3"):
        configurations(settings=settings, calibration=str(calibration), frames=[3], models=[], binning=[3])


@pytest.mark.slow
def test_bench_runs_on_a_tiny_directory_and_marks_a_frontier(sim_grasps, trained_model, tmp_path, capsys):
    records, calibration = sim_grasps
    png = tmp_path / "bench.png"
    argv = ["bench", str(records), "--models", str(trained_model), "--calibration", str(calibration),
            "--repeats", "1", "--limit", "3", "--binning", "1", "--json", "--plot", str(png)]
    assert main(argv) == 0
    result = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    configs = {c["name"]: c for c in result["configs"]}
    assert {"no_tactile", "series", "series@3f", "series/bin1"} <= set(configs)
    assert any(name.startswith("hybrid[depth+fw+analytical 3f 16x22]") for name in configs)
    assert any(name.startswith("auto[") for name in configs)
    assert result["labelled"] == 3 and result["reference_ms_p50"] > 0
    for c in result["configs"]:
        assert set(c) >= {"name", "latency_ms_p50", "felt_log10_error", "felt_within_2x", "log10_error",
                          "within_10x", "pareto"}
        assert c["latency_ms_p50"] > 0
        assert c["log10_error"] is None or c["log10_error"] >= 0
    front = [c for c in result["configs"] if c["pareto"]]
    assert front and all(c["felt_log10_error"] is not None for c in front)
    fastest = min((c for c in result["configs"] if c["felt_log10_error"] is not None),
                  key=lambda c: c["latency_ms_p50"])
    assert fastest["pareto"]  # nothing is faster, so nothing dominates it
    assert png.read_bytes()[:4] == b"\x89PNG"


@pytest.mark.parametrize("option", ["--limit", "--repeats"])
def test_bench_refuses_a_count_below_one_by_name(option, tmp_path, capsys):
    assert main(["bench", str(tmp_path), option, "0"]) == 2  # not "no record to bench"
    assert f"{option} 0: expected at least 1" in capsys.readouterr().err


@pytest.mark.parametrize("frames", ["0", "-2", "65", "2.5"])
def test_bench_refuses_a_frame_count_outside_1_to_64_before_benching(frames, tmp_path, capsys):
    with pytest.raises(SystemExit) as done:
        main(["bench", str(tmp_path), "--frames", "3", frames])
    err = capsys.readouterr().err
    assert done.value.code == 2 and f"--frames: {frames!r}: expected a whole number of frames in 1..64" in err


@pytest.mark.parametrize("command", ["build-dataset", "train", "bench"])
def test_commands_are_registered(command, capsys):
    with pytest.raises(SystemExit) as done:
        main([command, "--help"])
    assert done.value.code == 0 and "--json" in capsys.readouterr().out


def test_plot_labels_of_nearby_points_do_not_overlap():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from estimator.evaluation.bench import _separate_labels

    fig, ax = plt.subplots()
    ax.set(xscale="log", xlim=(1, 100), ylim=(0, 3))
    labels = [ax.annotate(f"configuration {i} (0 refused)", (20 + i * 0.1, 1.0 + i * 0.01), fontsize=7,
                          xytext=(5, 2), textcoords="offset points") for i in range(4)]
    renderer = fig.canvas.get_renderer()
    assert labels[0].get_window_extent(renderer).overlaps(labels[1].get_window_extent(renderer))
    _separate_labels(fig, labels)
    boxes = [label.get_window_extent(renderer) for label in labels]
    assert not any(a.overlaps(b) for i, a in enumerate(boxes) for b in boxes[i + 1:])
    plt.close(fig)


@pytest.mark.slow
def test_the_hybrid_benchmark_script_runs_its_stages_on_the_depth_grid(sim_grasps, trained_model):
    import subprocess
    import sys
    from pathlib import Path

    records, calibration = sim_grasps
    script = Path(__file__).resolve().parents[3] / "benchmarks" / "bench_hybrid.py"
    out = subprocess.run([sys.executable, str(script), str(records), "--model", str(trained_model),
                          "--calibration", str(calibration), "--limit", "2", "--repeats", "1"],
                         capture_output=True, text=True, timeout=300, check=True).stdout
    stages = out.strip().splitlines()[-1]
    assert stages.startswith("hybrid stages over ") and "depth " in stages and "network " in stages
    assert not stages.startswith("hybrid stages over 0 ")


def _drawn_bench_figure(monkeypatch, tmp_path, result):
    """The figure :func:`estimator.evaluation.bench.plot` draws, kept open to be read."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from estimator.evaluation.bench import plot

    monkeypatch.setattr(plt, "close", lambda *args, **kwargs: None)
    plot(result, tmp_path / "bench.png")
    return plt.gcf()


BENCH_RESULT = {
    "dir": "/data/bench_records", "labelled": 3,
    "configs": [
        {"name": name, "latency_ms_p50": ms, "felt_log10_error": err, "refusals": refused, "pareto": pareto}
        for name, ms, err, refused, pareto in [
            ("no_tactile", 2.9, 0.72, 0, True), ("series@3f", 3.4, 0.44, 0, False),
            ("series", 17.0, 0.42, 0, False), ("hertz", 20.0, 1.33, 1, False),
            ("hybrid[depth+fw+analytical 3f 64x88]", 3.2, 0.10, 0, True),
            ("auto[depth+fw+analytical 3f 64x88]", 3.1, 0.10, 0, True),
            ("auto[depth+fw+analytical 3f 16x22]", 3.3, 0.11, 0, False),
        ]
    ],
}


def test_bench_plot_keeps_points_and_labels_clear_of_the_legend(monkeypatch, tmp_path):
    import matplotlib.pyplot as plt

    fig = _drawn_bench_figure(monkeypatch, tmp_path, BENCH_RESULT)
    ax = fig.axes[0]
    renderer = fig.canvas.get_renderer()
    legend = ax.get_legend().get_window_extent(renderer)
    points = ax.transData.transform([(c["latency_ms_p50"], c["felt_log10_error"]) for c in BENCH_RESULT["configs"]])
    assert not any(legend.contains(x, y) for x, y in points)
    for label in ax.texts:
        assert not label.get_window_extent(renderer).overlaps(legend), label.get_text()
    plt.close(fig)


def test_bench_plot_keeps_every_point_label_inside_the_axes(monkeypatch, tmp_path):
    import matplotlib.pyplot as plt

    fig = _drawn_bench_figure(monkeypatch, tmp_path, BENCH_RESULT)
    ax = fig.axes[0]
    renderer = fig.canvas.get_renderer()
    frame = ax.get_window_extent(renderer)
    labels = [t for t in ax.texts if "refused" in t.get_text()]
    assert len(labels) == len(BENCH_RESULT["configs"])
    for label in labels:
        box = label.get_window_extent(renderer)
        assert frame.x0 <= box.x0 and box.x1 <= frame.x1 and frame.y0 <= box.y0 and box.y1 <= frame.y1, (
            label.get_text(), box, frame)
    plt.close(fig)


def test_bench_plot_labels_plain_milliseconds_with_a_modest_margin_and_names_the_records(monkeypatch, tmp_path):
    import matplotlib.pyplot as plt

    fig = _drawn_bench_figure(monkeypatch, tmp_path, BENCH_RESULT)
    ax = fig.axes[0]
    fig.canvas.draw()
    lo, hi = ax.get_xlim()
    shown = {t.get_text() for t in ax.get_xticklabels() if lo <= t.get_position()[0] <= hi and t.get_text()}
    assert {"5", "10", "20"} <= shown, shown  # 2.9-20 ms: more than the powers of ten
    assert hi <= 20.0 * 2.0  # no wasted right part
    assert "/data/bench_records" in ax.get_title() and "latency" in ax.get_title()
    plt.close(fig)
