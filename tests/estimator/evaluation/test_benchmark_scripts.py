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
