"""The scripts in ``benchmarks/``: bad options refused by argparse, the project's errors as one line.

They used to print nan with exit status 0 (``--grasps 0``, ``--repeats 0``) or end in a traceback."""

from __future__ import annotations

import importlib.util
import logging
from pathlib import Path

import pytest

BENCHMARKS = Path(__file__).resolve().parents[3] / "benchmarks"


@pytest.fixture
def run(monkeypatch):
    """Run a script of ``benchmarks/`` by name with arguments, as ``python benchmarks/NAME.py ARGS`` would:
    its ``main()``'s return value."""
    monkeypatch.syspath_prepend(str(BENCHMARKS))  # where the scripts find scriptkit
    for var in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):  # some set them on import
        monkeypatch.setenv(var, "1")

    def main(name: str, argv: list[str]) -> int:
        spec = importlib.util.spec_from_file_location(f"benchmark_{name}", BENCHMARKS / f"{name}.py")
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
        monkeypatch.setattr("sys.argv", [str(BENCHMARKS / f"{name}.py"), *argv])
        return module.main()

    # A script sets its loggers' levels for its process (bench_operator quiets the node's): not for the
    # tests after this one, whose log captures would come out empty.
    levels = {name: logger.level for name, logger in logging.root.manager.loggerDict.items()
              if isinstance(logger, logging.Logger)}
    yield main
    for name, logger in logging.root.manager.loggerDict.items():
        if isinstance(logger, logging.Logger):
            logger.setLevel(levels.get(name, logging.NOTSET))


@pytest.mark.parametrize(("name", "argv", "expected"), [
    ("bench_simulate", ["--grasps", "0"], "--grasps: '0': expected a whole number >= 1"),
    ("bench_simulate", ["--grasps", "-1"], "--grasps: '-1': expected a whole number >= 1"),
    ("bench_hybrid", ["rec", "--repeats", "0"], "--repeats: '0': expected a whole number >= 1"),
    ("bench_hybrid", ["rec", "--limit", "0"], "--limit: '0': expected a whole number >= 1"),
    ("bench_optics", ["--repeats", "0"], "--repeats: '0': expected a whole number >= 1"),
    ("bench_optics", ["--threads", "x"], "--threads: 'x': expected a whole number >= 1"),
    ("bench_depth", ["--repeats", "0"], "--repeats: '0': expected a whole number >= 1"),
    ("bench_depth", ["--repeats", "-3"], "--repeats: '-3': expected a whole number >= 1"),
    ("bench_operator", ["--seconds", "-1"], "--seconds: '-1': expected a number > 0"),
])
def test_a_bad_option_is_refused_by_argparse_before_any_work(run, name, argv, expected, capsys):
    with pytest.raises(SystemExit) as done:
        run(name, argv)
    assert done.value.code == 2 and expected in capsys.readouterr().err


@pytest.mark.parametrize(("name", "argv", "expected"), [
    ("bench_hybrid", ["/nonexist"], "bench_hybrid.py: error: /nonexist: not a directory"),
    ("bench_operator", ["--scene", "nosuch"], "bench_operator.py: error: no scene 'nosuch'"),
    ("accuracy_ceiling", ["--objects", "/nonexist.csv"], "accuracy_ceiling.py: error: "),
])
def test_the_projects_errors_are_one_line_with_status_2(run, name, argv, expected, capsys):
    assert run(name, argv) == 2
    err = capsys.readouterr().err
    assert err.startswith(expected) and err.count("\n") == 1 and "Traceback" not in err


@pytest.mark.slow
def test_the_operator_benchmark_drives_the_gripper_it_times(monkeypatch):
    """Its scripted input lets the enable go as the loop needs before driving (it drove nothing once the
    loop started with the enable suspended, and the benchmark printed no figure)."""
    monkeypatch.syspath_prepend(str(BENCHMARKS))
    spec = importlib.util.spec_from_file_location("benchmark_bench_operator_part1", BENCHMARKS / "bench_operator.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    figures = module.input_to_command("quick", 3.0)
    assert figures["commands"] > 10 and figures["matched"] > 10 and figures["p50_ms"] > 0


def _script(name: str, monkeypatch):
    """The module of ``benchmarks/NAME.py``, loaded as a script would be (scriptkit on the path)."""
    monkeypatch.syspath_prepend(str(BENCHMARKS))
    spec = importlib.util.spec_from_file_location(f"benchmark_{name}_module", BENCHMARKS / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.mark.slow
def test_the_operator_sweep_starts_at_its_first_reading_with_the_enable_let_go(monkeypatch):
    """The loop reads it once the robot node is heard, and drives only an enable let go and held then: a
    sweep clocked from construction held the enable at that first reading, and the loop drove nothing
    until the sweep's next start (``--seconds 2`` timed no command)."""
    import time

    module = _script("bench_operator", monkeypatch)
    device = module.SweepInput(0.08)
    time.sleep(0.3)  # the node heard a while after the device was made
    assert device.waits_for_robot
    assert not device.read().enable
    time.sleep(0.2)
    assert device.read().enable


@pytest.mark.slow
def test_the_operator_benchmark_times_commands_from_its_first_second(run, monkeypatch, capsys):
    """Its whole ``--seconds`` drives the gripper: 1 s used to measure 0 commands and print "p50 -"."""
    module = _script("bench_operator", monkeypatch)
    logging.getLogger("teleop.node").setLevel(logging.ERROR)  # as the script does; `run` restores it
    assert module.input_to_command("quick", 1.0)["matched"] > 10


def test_an_operator_run_that_matched_no_command_is_an_error(monkeypatch):
    """Not figures of nothing ("0 of 0 commands matched: p50 -", status 0)."""
    module = _script("bench_operator", monkeypatch)
    from scriptkit import BenchmarkError

    class Idle:  # a loop that never drives
        def __init__(self, *args):
            pass

        def run(self, **kwargs):
            pass

    monkeypatch.setattr(module, "OperatorLoop", Idle)
    with pytest.raises(BenchmarkError, match=r"--seconds 0.1: no gripper command matched .*\(0 commands"):
        module.input_to_command("quick", 0.1)


@pytest.fixture(scope="module")
def hybrid_records(tmp_path_factory):
    """(grasp the hybrid refuses, one it samples): a memory foam cube squeezed to 0.8 N, a silicone ball."""
    import numpy as np

    from teleop.catalogue import load_catalogue
    from teleop.record import write_record
    from teleop.settings import load_settings
    from teleop.sim.grasp import simulate_grasp

    settings, out = load_settings(), tmp_path_factory.mktemp("hybrid_records")
    objects = {o.name: o for o in load_catalogue()}
    paths = []
    for name, force_n in (("memory_foam_cube", 0.8), ("silicone_ball_shore00_30", None)):
        record, _ = simulate_grasp(objects[name], settings=settings, rng=np.random.default_rng(0), force_n=force_n)
        paths.append(write_record(record, out / f"{name}.grasp"))
    return tuple(paths)


@pytest.mark.slow
def test_the_hybrid_benchmark_says_so_when_every_grasp_is_refused(run, hybrid_records, tmp_path, capsys):
    """One line naming the folder and the count, status 2: not "segment nan" with numpy's warnings, status 0."""
    refused = tmp_path / "refused"
    refused.mkdir()
    (refused / hybrid_records[0].name).write_bytes(hybrid_records[0].read_bytes())
    assert run("bench_hybrid", [str(refused), "--repeats", "1"]) == 2
    out, err = capsys.readouterr()
    assert err.splitlines()[-1] == (f"bench_hybrid.py: error: {refused}: the hybrid refused every grasp benched "
                                    "(1 of 1: too little data to sample): no stage to time")
    assert "nan" not in out and "RuntimeWarning" not in err


@pytest.mark.slow
def test_the_hybrid_stages_skip_the_records_the_bench_skipped(run, hybrid_records, tmp_path, capsys):
    """An unreadable record, left out of the bench's table, aborted the stage timings with its error."""
    records = tmp_path / "mixed"
    records.mkdir()
    (records / hybrid_records[1].name).write_bytes(hybrid_records[1].read_bytes())
    (records / "zz_broken.grasp").write_bytes(b"not a record")
    assert run("bench_hybrid", [str(records), "--repeats", "1"]) == 0
    stages = capsys.readouterr().out.strip().splitlines()[-1]
    assert stages.startswith("hybrid stages over 1 grasps") and "network " in stages


@pytest.mark.slow
@pytest.mark.parametrize(("name", "argv", "figure"), [
    ("bench_depth", ["--repeats", "2"], "reconstruct_depth (whole)              median"),
    ("bench_optics", ["--repeats", "2"], "left          no contact"),
])
def test_a_speed_figure_comes_with_its_ratio_to_the_frame_baseline(run, name, argv, figure, capsys):
    """The project rule: medians, and ratios against a baseline run in the same process (absolute times only
    before)."""
    import json

    assert run(name, [*argv, "--json"] if name != "bench_depth" else argv) == 0
    lines = capsys.readouterr().out.splitlines()
    assert any(line.startswith("frame baseline (one tactile frame's perception in this process") for line in lines)
    row = lines.index(next(line for line in lines if line.startswith(figure)))
    assert " bl" in lines[row] + lines[row + 1]
    figures = json.loads(lines[-1])
    assert figures["frame_baseline_ms"] > 0 and "in_baselines" in lines[-1]


STOPPED = """
import argparse, pathlib, sys, tempfile
sys.path.insert(0, {benchmarks!r})
from scriptkit import run_child, run_script

def work(args):
    with tempfile.TemporaryDirectory(dir={tmp!r}) as folder:
        run_child([sys.executable, "-c", "import os, pathlib, sys, time; "
                   "pathlib.Path(sys.argv[1]).write_text(str(os.getpid())); time.sleep(60)", folder + "/child.pid"])

sys.exit(run_script(argparse.ArgumentParser(prog="probe.py"), work))
"""


@pytest.mark.slow
@pytest.mark.parametrize(("signum", "status", "said"), [(15, 143, "terminated"), (2, 130, "interrupted")])
def test_a_stop_signal_stops_a_script_its_child_and_its_temporaries(tmp_path, signum, status, said):
    """SIGTERM left the child running (reparented to PID 1) and the temporary folder behind; Ctrl-C ended in
    a KeyboardInterrupt traceback."""
    import os
    import subprocess
    import sys
    import time

    script = tmp_path / "probe.py"
    script.write_text(STOPPED.format(benchmarks=str(BENCHMARKS), tmp=str(tmp_path)))
    probe = subprocess.Popen([sys.executable, str(script)], stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 20
    while not (pids := list(tmp_path.glob("*/child.pid"))) or not pids[0].read_text():
        assert probe.poll() is None and time.monotonic() < deadline, "the probe's child never started"
        time.sleep(0.05)
    child = int(pids[0].read_text())
    probe.send_signal(signum)
    _, err = probe.communicate(timeout=20)
    assert (probe.returncode, err) == (status, f"probe.py: {said}\n")
    assert not os.path.exists(f"/proc/{child}") and list(tmp_path.iterdir()) == [script]
