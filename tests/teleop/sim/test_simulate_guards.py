"""``teleop simulate``: --overwrite leaves no other run's records, --target-force-n within what the
estimator reads, objects too small or too wide to grasp."""

from __future__ import annotations

import errno
import json
import signal
import subprocess
import sys
import textwrap
import time
import zipfile
from concurrent.futures.process import BrokenProcessPool
from pathlib import Path

import numpy as np
import pytest
from support.catalogue_toml import object_toml

from teleop.catalogue import ObjectSpec
from teleop.cli import main
from teleop.clikit import Terminated
from teleop.errors import SettingsError, SimulationError
from teleop.settings import default_settings_path, load_settings
from teleop.sim import simulate_cli
from teleop.sim.grasp import simulate_grasp
from teleop.sim.simulate import grasp_rng

OAK = object_toml("oak_block", "box", "wood", 1.1e10)
BEACH_BALL = object_toml("beach ball", "sphere", "plastic", 1e7, size_m=[0.3, 0.3, 0.3])
TINY = object_toml("tiny_1mm", "sphere", "metal", 2e11, size_m=[0.001, 0.001, 0.001])


@pytest.fixture
def catalogue(tmp_path, ball_toml):
    path = tmp_path / "objects.toml"
    path.write_text(ball_toml + OAK + BEACH_BALL + TINY)
    return path


def run(capsys, *argv: str) -> tuple[int, str, str]:
    code = main(["simulate", *argv])
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def test_overwrite_removes_this_objects_earlier_grasps_and_keeps_other_objects(tmp_path, catalogue, quick_settings,
                                                                              capsys):
    out = tmp_path / "o"
    out.mkdir()
    for name in ("oak_block_g000.grasp", "oak_block_g001.grasp", "oak_block_g001.png", "oak_block_g1000.grasp"):
        (out / name).write_bytes(b"an earlier seed's grasp")
    others = ("small_rubber_ball_g000.grasp", "small_rubber_ball_g001.png", "oak_block_notes.grasp",
              "oak_block_g001_g000.grasp")  # the last: an object named "oak_block_g001"
    for name in others:
        (out / name).write_bytes(b"not this run's")
    code, _, stderr = run(capsys, "--objects", str(catalogue), "--only", "oak_block", "--out", str(out),
                          "--settings", str(quick_settings), "--overwrite")
    assert code == 0, stderr
    assert sorted(p.name for p in out.iterdir()) == sorted(["oak_block_g000.grasp", *others])
    assert (out / "oak_block_g000.grasp").read_bytes() != b"an earlier seed's grasp"
    assert all((out / name).read_bytes() == b"not this run's" for name in others)


def test_a_failed_grasp_leaves_no_earlier_file_of_its_name_with_overwrite(tmp_path, catalogue, capsys):
    out = tmp_path / "o"
    out.mkdir()
    (out / "beach_ball_g000.grasp").write_bytes(b"an earlier catalogue's grasp")
    (out / "beach_ball_g000.png").write_bytes(b"its sheet")
    code, stdout, stderr = run(capsys, "--objects", str(catalogue), "--only", "beach ball", "--out", str(out),
                               "--overwrite", "--json")
    assert code == 1 and "beach ball grasp 0" in stderr
    assert json.loads(stdout.strip().splitlines()[-1])["grasps"] == 0
    assert list(out.iterdir()) == []


@pytest.mark.parametrize("name", ["oak_block_g001.grasp", "oak_block_g000.png"],
                         ids=["a grasp of another index", "a preview, taken like its record"])
def test_an_earlier_file_of_the_object_is_refused_without_overwrite(tmp_path, catalogue, capsys, name):
    out = tmp_path / "o"
    out.mkdir()
    (out / name).write_bytes(b"an earlier seed's file")
    code, _, stderr = run(capsys, "--objects", str(catalogue), "--only", "oak_block", "--out", str(out))
    assert code == 2 and f"1 of these records exist already ({name}): pass --overwrite" in stderr
    assert [p.name for p in out.iterdir()] == [name]
    assert (out / name).read_bytes() == b"an earlier seed's file"


def test_the_mirrored_estimator_constant_matches_the_estimator():
    from estimator.settings import EstimatorSettings

    assert EstimatorSettings().contact_force_n == simulate_cli.DEFAULT_CONTACT_FORCE_N


@pytest.mark.parametrize("force, message", [
    ("0.75", "--target-force-n 0.75: expected more than the estimator's contact force, "
             "estimator.contact_force_n = 0.75 N"),
    ("0.1", "the fingers would never reach contact"),
])
def test_a_target_force_the_estimator_cannot_read_is_refused(tmp_path, catalogue, capsys, force, message):
    code, _, stderr = run(capsys, "--objects", str(catalogue), "--out", str(tmp_path / "o"), "--target-force-n", force)
    assert code == 2 and message in stderr and len(stderr.strip().splitlines()) == 1, stderr
    assert not (tmp_path / "o").exists()


def test_the_target_force_bounds_follow_the_settings_file(tmp_path, capsys):
    text = default_settings_path().read_text()
    text = text.replace("contact_force_n = 0.75", "contact_force_n = 0.3")
    path = tmp_path / "settings.toml"
    path.write_text(text)
    settings = load_settings(path)
    assert settings.gripper.target_force_n == 30.0 and settings.tables["estimator"]["contact_force_n"] == 0.3
    # The records carry the gripper they were simulated with (its target_force_n this one): no upper bound.
    simulate_cli._check_target_force(140.0, settings, str(path))
    simulate_cli._check_target_force(0.5, settings, str(path))  # above 0.3 N: only warned of
    assert "some may stay below the estimator's contact force (0.3 N" in capsys.readouterr().err
    with pytest.raises(SettingsError, match="estimator.contact_force_n = 0.3 N"):
        simulate_cli._check_target_force(0.3, settings, str(path))


def test_an_object_too_small_to_grasp_is_a_failed_grasp(tmp_path, catalogue, quick_settings, capsys):
    obj = ObjectSpec(name="tiny_1mm", shape="sphere", material="metal", modulus_pa=2e11,
                     size_m=(0.001, 0.001, 0.001))
    with pytest.raises(SimulationError, match="'tiny_1mm' is too small to grasp: .* the fingers closed on each other"):
        simulate_grasp(obj, settings=load_settings(quick_settings), rng=grasp_rng(0, obj, 0), seed=0)
    out = tmp_path / "o"
    code, stdout, stderr = run(capsys, "--objects", str(catalogue), "--only", "tiny_1mm", "--out", str(out),
                               "--settings", str(quick_settings), "--json")
    summary = json.loads(stdout.strip().splitlines()[-1])
    assert code == 1 and summary["grasps"] == 0 and "too small to grasp" in summary["failed"][0]["reason"]
    assert list(out.glob("*.grasp")) == []


def test_a_too_wide_object_is_told_the_real_limit(tmp_path, catalogue, capsys):
    code, stdout, _ = run(capsys, "--objects", str(catalogue), "--only", "beach ball", "--out", str(tmp_path / "o"),
                          "--json")
    reason = json.loads(stdout.strip().splitlines()[-1])["failed"][0]["reason"]
    assert code == 1 and "does not fit" in reason
    assert "0.298 m across at its narrowest" in reason and "under 0.95 x 0.08 = 0.076 m" in reason, reason


def test_grasps_that_reach_their_target_are_kept(tmp_path, ball_toml, quick_settings):
    # The too-small check leaves an ordinary grasp alone: the fingers stop short of each other.
    obj = ObjectSpec(name="ball", shape="sphere", material="rubber", modulus_pa=8e5, size_m=(0.02, 0.02, 0.02))
    record, truth = simulate_grasp(obj, settings=load_settings(quick_settings), rng=grasp_rng(0, obj, 0), seed=0)
    assert float(np.min(truth.motor_width_m)) > 1e-3 and truth.force_n.max() >= 0.99 * truth.target_force_n


def test_an_unexpected_error_in_a_grasp_ends_the_run_naming_it_and_keeps_the_records_written(
        tmp_path, catalogue, quick_settings, capsys, monkeypatch):
    def simulate(obj, **kwargs):
        if obj.name == "oak_block":
            raise RuntimeError("boom")
        return simulate_grasp(obj, **kwargs)

    monkeypatch.setattr(simulate_cli, "simulate_grasp", simulate)
    out = tmp_path / "o"
    code, stdout, stderr = run(capsys, "--objects", str(catalogue), "--only", "small rubber ball,oak_block", "--out",
                               str(out), "--settings", str(quick_settings), "--json")
    assert code == 2 and stdout == "" and "Traceback" not in stderr
    assert (f"teleop simulate: error: oak_block grasp 0: unexpected error: RuntimeError: boom (-v shows where); the "
            f"run stopped: 1 of 2 records were written to {out} (each whole), the rest not: to finish, run the same "
            "command with --only oak_block --overwrite (") in stderr
    assert [p.name for p in out.iterdir()] == ["small_rubber_ball_g000.grasp"]


def test_a_full_disk_ends_the_run_naming_the_record_it_could_not_write(
        tmp_path, catalogue, quick_settings, capsys, monkeypatch):
    def disk_full(self, *args, **kwargs):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(zipfile.ZipFile, "writestr", disk_full)
    out = tmp_path / "o"
    code, stdout, stderr = run(capsys, "--objects", str(catalogue), "--only", "small rubber ball", "--out", str(out),
                               "--settings", str(quick_settings), "--json")
    assert code == 2 and stdout == "" and "Traceback" not in stderr
    # Not "unexpected error: OSError: [Errno 28] No space left on device", which named no file.
    assert (f"teleop simulate: error: small rubber ball grasp 0: cannot write {out / 'small_rubber_ball_g000.grasp'}: "
            "No space left on device (-v shows where); the run stopped: 0 of 1 records were written") in stderr
    assert list(out.iterdir()) == []


def test_a_dead_worker_ends_the_run_with_what_was_written_and_no_leftovers(
        tmp_path, catalogue, quick_settings, capsys, monkeypatch):
    def dies_after_the_first(work, jobs, **kwargs):
        work(jobs[0])  # written whole
        obj, index, _, _, out, *_ = jobs[1]  # killed mid-write
        Path(out, simulate_cli.grasp_filename(obj, index) + ".partial").write_bytes(b"half a record")
        Path(out, simulate_cli.grasp_filename(obj, index).replace(".grasp", ".png")).write_bytes(b"a sheet")
        raise BrokenProcessPool("A process in the process pool was terminated abruptly")

    monkeypatch.setattr(simulate_cli, "progress_map", dies_after_the_first)
    out = tmp_path / "o"
    code, stdout, stderr = run(capsys, "--objects", str(catalogue), "--only", "small rubber ball,oak_block", "--out",
                               str(out), "--settings", str(quick_settings), "--workers", "2", "--json")
    assert code == 2 and stdout == "" and "Traceback" not in stderr
    assert ("teleop simulate: error: a worker process died (killed? out of memory?); the run stopped: 1 of 2 "
            f"records were written to {out} (each whole), the rest not: to finish, run the same command with --only "
            "oak_block --overwrite and fewer --workers if memory ran short") in stderr
    assert [p.name for p in out.iterdir()] == ["small_rubber_ball_g000.grasp"]


@pytest.mark.parametrize(("signum", "status", "said"), [(signal.SIGINT, 130, "interrupted"),
                                                      (signal.SIGTERM, 143, "terminated")])
def test_an_interrupted_run_leaves_no_temporary_of_its_stopped_workers(
        tmp_path, catalogue, quick_settings, capsys, monkeypatch, signum, status, said):
    def stopped_mid_write(work, jobs, **kwargs):
        work(jobs[0])  # written whole
        obj, index, _, _, out, *_ = jobs[1]  # its worker stopped mid-write: no clean-up of its own ran
        name = simulate_cli.grasp_filename(obj, index)
        Path(out, name + ".partial").write_bytes(b"half a record")
        Path(out, name.replace(".grasp", ".partial.png")).write_bytes(b"half a sheet")
        raise KeyboardInterrupt if signum == signal.SIGINT else Terminated(signum)

    monkeypatch.setattr(simulate_cli, "progress_map", stopped_mid_write)
    out = tmp_path / "o"
    code, stdout, stderr = run(capsys, "--objects", str(catalogue), "--only", "small rubber ball,oak_block", "--out",
                               str(out), "--settings", str(quick_settings), "--workers", "2")
    assert (code, stdout, stderr) == (status, "", f"teleop simulate: {said}\n")
    assert [p.name for p in out.iterdir()] == ["small_rubber_ball_g000.grasp"]


@pytest.mark.slow
def test_sigterm_while_a_worker_writes_leaves_no_temporary(tmp_path, catalogue, quick_settings):
    # A real spawned pool, its worker inside a record's write when the command is terminated.
    script = tmp_path / "stalled.py"
    script.write_text(textwrap.dedent(f"""
        import sys, time
        from pathlib import Path
        from teleop.cli import main
        from teleop.sim import simulate_cli

        def stalls_mid_write(job):
            obj, index, _, _, out, *_ = job
            Path(out, simulate_cli.grasp_filename(obj, index) + ".partial").write_bytes(b"half a record")
            time.sleep(60)

        if __name__ == "__main__":
            simulate_cli._simulate_one = stalls_mid_write
            sys.exit(main(["simulate", "--objects", {str(catalogue)!r}, "--only", "small rubber ball,oak_block",
                           "--out", {str(tmp_path / "o")!r}, "--settings", {str(quick_settings)!r},
                           "--workers", "2"]))
    """))
    child = subprocess.Popen([sys.executable, str(script)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 60
        while not list((tmp_path / "o").glob("*.partial")):
            assert child.poll() is None and time.monotonic() < deadline, child.communicate()[1]
            time.sleep(0.02)
        child.send_signal(signal.SIGTERM)  # to the command alone, as a service manager does
        _, err = child.communicate(timeout=20)
    finally:
        child.kill()
    assert child.returncode == 143 and err.rstrip().endswith("teleop simulate: terminated"), err
    assert list((tmp_path / "o").iterdir()) == []


@pytest.mark.slow
def test_a_worker_killed_mid_run_is_one_error_line(tmp_path, catalogue, quick_settings):
    # A worker of the spawned pool dies as under the OOM killer: no traceback, exit 2, no temporaries.
    script = tmp_path / "crash.py"
    script.write_text(textwrap.dedent(f"""
        import os, sys
        from teleop.cli import main
        from teleop.sim import simulate_cli

        original = simulate_cli._simulate_one

        def dies_on_oak(job):
            if job[0].name == "oak_block":
                os._exit(9)
            return original(job)

        if __name__ == "__main__":
            simulate_cli._simulate_one = dies_on_oak
            sys.exit(main(["simulate", "--objects", {str(catalogue)!r}, "--only", "small rubber ball,oak_block",
                           "--out", {str(tmp_path / "o")!r}, "--settings", {str(quick_settings)!r},
                           "--workers", "2", "--json"]))
    """))
    done = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=120)
    assert done.returncode == 2 and done.stdout == "" and "Traceback" not in done.stderr, done.stderr
    assert "error: a worker process died (killed? out of memory?); the run stopped: " in done.stderr
    assert "oak_block" in done.stderr.rsplit("--only", 1)[1]
    assert {p.suffix for p in (tmp_path / "o").iterdir()} <= {".grasp"}


def test_a_missing_calibration_file_is_warned_of_once_and_the_records_written(tmp_path, catalogue, quick_settings,
                                                                             capsys):
    settings = tmp_path / "nocal.toml"
    settings.write_text(quick_settings.read_text().replace("sim-wedge-left.npz", "nosuch.npz", 1))
    out = tmp_path / "o"
    code, _, stderr = run(capsys, "--objects", str(catalogue), "--only", "small rubber ball", "--out", str(out),
                          "--settings", str(settings))
    assert code == 0, stderr
    missing = Path(load_settings(settings).sensor("left").calibration)
    assert stderr.count("warning") == 1
    assert (f"teleop simulate: warning: {settings}: [sensors.left] calibration {missing}: no such file (a relative "
            f"path resolves against {tmp_path}); make it with `estimator calibrate`: the records are simulated all "
            "the same (raw frames) and name that file: `estimator estimate` reads them once it exists, or with "
            "--calibration CAL\n") in stderr
    assert [p.name for p in out.iterdir()] == ["small_rubber_ball_g000.grasp"]


def test_a_copied_settings_file_is_warned_of_in_teleop_settings_words_with_the_shipped_calibrations(
        tmp_path, catalogue, quick_settings, capsys):
    # The shipped settings copied elsewhere: their relative calibration paths resolve beside the copy.
    settings = tmp_path / "mysettings.toml"
    settings.write_text(quick_settings.read_text().replace(f"{default_settings_path().parent}/calibration/",
                                                           "calibration/"))
    assert main(["settings", str(settings)]) == 0
    said = [line.removeprefix("teleop settings: warning: ") for line in capsys.readouterr().err.splitlines()]
    assert len(said) == 2 and all("the shipped one is" in line for line in said)
    code, _, stderr = run(capsys, "--objects", str(catalogue), "--only", "small rubber ball",
                          "--out", str(tmp_path / "o"), "--settings", str(settings))
    assert code == 0, stderr
    warnings = [line for line in stderr.splitlines() if "warning" in line]
    assert warnings == [f"teleop simulate: warning: {settings}: {line}: the records are simulated all the same (raw "
                        "frames) and name that file: `estimator estimate` reads them once it exists, or with "
                        "--calibration CAL" for line in said]
    assert str(tmp_path / "calibration" / "sim-wedge-left.npz") in warnings[0]
