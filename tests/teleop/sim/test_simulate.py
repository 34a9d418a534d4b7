"""``teleop simulate`` end to end."""

from __future__ import annotations

import dataclasses
import json

import pytest
from support.catalogue_toml import object_toml

from teleop.catalogue import load_catalogue
from teleop.cli import main
from teleop.record import read_record
from teleop.settings import default_settings_path, load_settings

OAK = object_toml("oak_block", "box", "wood", 1.1e10, texture_m=3e-5)


@pytest.fixture
def catalogue(tmp_path, ball_toml):
    path = tmp_path / "objects.toml"
    path.write_text(ball_toml + OAK)
    return path


def run(capsys, *argv: str) -> tuple[int, str, str]:
    code = main(["simulate", *argv])
    captured = capsys.readouterr()
    return code, captured.out, captured.err


@pytest.mark.slow
def test_simulates_a_tiny_catalogue_end_to_end(tmp_path, object_table, quick_settings, capsys):
    out = tmp_path / "grasps"
    code, stdout, stderr = run(capsys, "--objects", str(object_table), "--limit-objects", "2",
                               "--grasps-per-object", "1", "--seed", "3", "--out", str(out), "--json", "--preview",
                               "--settings", str(quick_settings))
    assert code == 0, stderr
    summary = json.loads(stdout.strip().splitlines()[-1])
    assert summary["grasps"] == 2 and summary["seconds"] > 0 and summary["grasps_per_s_per_core"] > 0
    assert summary["out"] == str(out) and summary["failed"] == []
    assert "simulate" in stderr  # the progress bar
    expected = load_catalogue(object_table)[:2]
    records = sorted(out.glob("*.grasp"))
    assert len(records) == 2 and len(list(out.glob("*.png"))) == 2
    by_name = {read_record(p).label.object_name: read_record(p) for p in records}
    for obj in expected:
        record = by_name[obj.name]
        assert record.label.modulus_pa == obj.modulus_pa and record.label.material == obj.material
        assert record.provenance.source == "simulated" and record.provenance.seed == 3
        assert len(record.force_n) > 10 and all(len(s) > 4 for s in record.frames)


@pytest.mark.slow
def test_same_seed_gives_identical_files_whatever_the_workers(tmp_path, catalogue, quick_settings, capsys):
    for workers, seed, name in (("1", "11", "one"), ("2", "11", "two"), ("1", "12", "other")):
        code, _, stderr = run(capsys, "--objects", str(catalogue), "--seed", seed, "--workers", workers,
                              "--out", str(tmp_path / name), "--settings", str(quick_settings))
        assert code == 0, stderr
    files = sorted(p.name for p in (tmp_path / "one").glob("*.grasp"))
    assert files == ["oak_block_g000.grasp", "small_rubber_ball_g000.grasp"]
    for name in files:
        assert (tmp_path / "one" / name).read_bytes() == (tmp_path / "two" / name).read_bytes()
        assert (tmp_path / "one" / name).read_bytes() != (tmp_path / "other" / name).read_bytes()


def test_records_already_in_out_are_refused_unless_overwrite(tmp_path, catalogue, quick_settings, capsys):
    out = tmp_path / "o"
    out.mkdir()
    (out / "oak_block_g000.grasp").write_bytes(b"another seed's grasp")
    args = ("--objects", str(catalogue), "--only", "oak_block", "--out", str(out), "--settings", str(quick_settings))
    code, _, stderr = run(capsys, *args)
    assert code == 2 and "1 of these records exist already (oak_block_g000.grasp): pass --overwrite" in stderr
    assert (out / "oak_block_g000.grasp").read_bytes() == b"another seed's grasp"
    code, _, stderr = run(capsys, *args, "--overwrite")
    assert code == 0, stderr
    assert read_record(out / "oak_block_g000.grasp").label.object_name == "oak_block"


def test_an_object_that_cannot_be_grasped_is_reported(tmp_path, capsys):
    path = tmp_path / "big.toml"
    path.write_text('[[objects]]\nname = "beach ball"\nshape = "sphere"\nmaterial = "plastic"\n'
                    'modulus_pa = 1e7\nsize_m = [0.3, 0.3, 0.3]\n')
    code, stdout, stderr = run(capsys, "--objects", str(path), "--out", str(tmp_path / "o"), "--json")
    assert code == 1
    summary = json.loads(stdout.strip().splitlines()[-1])
    assert summary["grasps"] == 0 and summary["failed"][0]["object"] == "beach ball"
    assert "does not fit" in summary["failed"][0]["reason"] and "beach ball" in stderr


@pytest.mark.slow
def test_only_simulates_the_named_objects(tmp_path, catalogue, quick_settings, capsys):
    code, _, stderr = run(capsys, "--objects", str(catalogue), "--only", "oak_block", "--out", str(tmp_path / "o"),
                          "--settings", str(quick_settings))
    assert code == 0, stderr
    assert [p.name for p in (tmp_path / "o").glob("*.grasp")] == ["oak_block_g000.grasp"]


@pytest.mark.slow
def test_target_force_sets_how_hard_the_scripted_grasps_squeeze(tmp_path, catalogue, quick_settings, capsys):
    peaks = {}
    for ceiling in ("30", "6"):
        code, _, stderr = run(capsys, "--objects", str(catalogue), "--only", "small rubber ball", "--seed", "4",
                              "--grasps-per-object", "2", "--target-force-n", ceiling, "--out", str(tmp_path / ceiling),
                              "--settings", str(quick_settings))
        assert code == 0, stderr
        peaks[ceiling] = [float(read_record(p).force_n.value.max()) for p in sorted((tmp_path / ceiling).glob("*.grasp"))]
    # Targets are drawn at 40-100 % of the ceiling (the same draw for both ceilings); the load cell adds noise.
    assert all(2.0 < p < 6.5 for p in peaks["6"]), peaks
    assert all(p > 10.0 for p in peaks["30"]), peaks


@pytest.mark.parametrize("argv, message", [
    (["--grasps-per-object", "0"], "--grasps-per-object"),
    (["--workers", "0"], "--workers"),
    (["--only", "oak_block,teapot,anvil"], "--only: anvil, teapot not in the catalogue"),
    (["--vary-contact", "--gel-model", "half-space"], "--vary-contact draws the gel's contact model and never"),
    (["--target-force-n", "0"], "--target-force-n 0: GripperSettings.target_force_n = 0"),
    (["--target-force-n", "12", "--randomize-rig"], "--target-force-n sets the one rig's force ceiling"),
])
def test_bad_arguments_are_one_line_errors(tmp_path, catalogue, capsys, argv, message):
    code, _, stderr = run(capsys, "--objects", str(catalogue), "--out", str(tmp_path / "o"), *argv)
    assert code == 2 and message in stderr and "Traceback" not in stderr
    assert len(stderr.strip().splitlines()) == 1


def test_vary_gel_without_randomize_rig_is_refused_before_out_is_made(tmp_path, catalogue, capsys):
    code, _, stderr = run(capsys, "--objects", str(catalogue), "--out", str(tmp_path / "o"), "--vary-gel")
    assert code == 2 and "--vary-gel draws a rig's gel: it needs --randomize-rig" in stderr
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("seed", ["-1", "1.5", "x"])
def test_a_seed_that_is_no_whole_number_from_0_is_refused_by_argparse(tmp_path, catalogue, capsys, seed):
    with pytest.raises(SystemExit) as raised:
        main(["simulate", "--objects", str(catalogue), "--out", str(tmp_path / "o"), "--seed", seed])
    assert raised.value.code == 2 and f"--seed: {seed!r}: expected a whole number >= 0" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


def test_unknown_catalogue_format_is_refused(tmp_path, capsys):
    path = tmp_path / "objects.yaml"
    path.write_text("x")
    code, _, stderr = run(capsys, "--objects", str(path), "--out", str(tmp_path / "o"))
    assert code == 2 and "unknown catalogue format" in stderr


def test_the_shipped_catalogue_is_the_default_and_one_grasp_is_one(tmp_path, quick_settings, capsys):
    code, stdout, stderr = run(capsys, "--only", "stress_ball", "--out", str(tmp_path / "o"),
                               "--settings", str(quick_settings))
    assert code == 0, stderr
    assert stdout.startswith("1 grasp in ") and len(list((tmp_path / "o").glob("stress_ball_g*.grasp"))) == 1


def test_help_explains_every_option(capsys):
    with pytest.raises(SystemExit) as exit_info:
        main(["simulate", "--help"])
    assert exit_info.value.code == 0
    text = capsys.readouterr().out
    for option in ("--objects", "--grasps-per-object", "--seed", "--out", "--workers", "--preview", "--json",
                   "--settings", "--limit-objects", "--only", "--vary-contact"):
        assert option in text
    assert "grasps_per_s_per_core" in text
    # --vary-contact says what it draws, that the half-space is held out, and where the draws go.
    vary = " ".join(text[text.index("\n  --vary-contact"):].split())
    for words in ("teleop.sim.mechanics.ContactSpread", "Poisson's ratio 0.3-0.5", "x0.6-1.5", "friction",
                  "held-out half-space gel", "provenance only"):
        assert words in vary, words


def test_objects_whose_records_would_share_a_file_name_are_refused_before_out_is_made(tmp_path, capsys):
    path = tmp_path / "coll.toml"
    path.write_text("".join(f'[[objects]]\nname = "{name}"\nshape = "box"\nmaterial = "foam"\nmodulus_pa = 1e5\n'
                            for name in ("foam cube", "foam_cube")))
    code, _, stderr = run(capsys, "--objects", str(path), "--out", str(tmp_path / "o"))
    assert code == 2 and "objects 'foam cube' and 'foam_cube' would both be written to foam_cube_g<index>.grasp" in stderr
    assert not (tmp_path / "o").exists()


def test_settings_without_two_sensors_are_refused_before_out_is_made(tmp_path, catalogue, capsys):
    text = default_settings_path().read_text()
    start = text.index("[sensors.right]")
    end = text.index("\n[", start + 1)
    settings = tmp_path / "one_sensor.toml"
    settings.write_text(text[:start] + text[end:])
    code, _, stderr = run(capsys, "--objects", str(catalogue), "--out", str(tmp_path / "o"),
                          "--settings", str(settings))
    assert code == 2 and f"{settings}: the grasp simulator needs exactly two sensors" in stderr
    assert len(stderr.strip().splitlines()) == 1 and not (tmp_path / "o").exists()


def test_overwrite_removes_the_stale_preview_and_the_gripper_is_recorded(tmp_path, catalogue, quick_settings, capsys):
    out = tmp_path / "o"
    out.mkdir()
    (out / "oak_block_g000.png").write_bytes(b"another seed's sheet")
    args = ("--objects", str(catalogue), "--only", "oak_block", "--out", str(out), "--settings", str(quick_settings),
            "--overwrite")
    gripper = load_settings(quick_settings).gripper
    for extra, expected in (((), gripper), (("--operator", "sim"), gripper),
                            (("--target-force-n", "12"), dataclasses.replace(gripper, target_force_n=12.0))):
        code, _, stderr = run(capsys, *args, *extra)
        assert code == 0, stderr
        assert not (out / "oak_block_g000.png").exists()  # the stale preview, removed by --overwrite
        record = read_record(out / "oak_block_g000.grasp")
        assert record.gripper == expected, extra  # what the estimator reads the grasp with
        assert "target_force_n" not in record.provenance.extra
