"""The dataset builder: object-level split without leakage, samples measured from records."""

from __future__ import annotations

import json
import shutil
from collections import Counter, defaultdict
from pathlib import Path

import numpy as np
import pytest

from estimator.cli import main
from estimator.errors import EstimatorError, SampleError
from estimator.inference.inputs import ANALYTICAL_METHODS, Variant
from estimator.inference.provenance import SPLITS, load_split
from estimator.training.dataset import MODULUS_SPREAD, split_objects
from estimator.training.dataset_cli import parse_size
from estimator.training.samples import load_sample, sample_paths
from teleop.settings import load_settings

MATERIALS = {f"{m}_{i}": m for m in ("foam", "rubber", "plastic", "metal", "wood") for i in range(8)} | {"odd": "glass"}


def test_split_is_deterministic_disjoint_and_complete():
    split = split_objects(MATERIALS, seed=4)
    assert split == split_objects(dict(reversed(MATERIALS.items())), seed=4)  # input order does not matter
    names = [n for s in SPLITS for n in split[s]]
    assert sorted(names) == sorted(MATERIALS) and len(set(names)) == len(names)
    assert split != split_objects(MATERIALS, seed=5)
    assert [len(split[s]) for s in SPLITS] == [29, 6, 6]  # 0.7 / 0.15 / 0.15 of 41


def test_split_is_stratified_by_material():
    split = split_objects(MATERIALS, seed=0, fractions=(0.5, 0.25, 0.25))
    for s, share in zip(SPLITS, (0.5, 0.25, 0.25), strict=True):
        per_material = Counter(MATERIALS[n] for n in split[s])
        for material in ("foam", "rubber", "plastic", "metal", "wood"):
            assert per_material[material] == pytest.approx(8 * share, abs=1), (s, material)


@pytest.mark.parametrize("fractions", [(0.7, 0.15, 0.15), (0.8, 0.1, 0.1), (0.6, 0.2, 0.2)])
def test_every_split_gets_its_share_of_a_material_to_within_one_object(fractions):
    # Each object goes to the split furthest below its share so far: however many objects a material
    # has, no split is a whole object (or more) off its share of them.
    for n in range(1, 31):
        split = split_objects({f"foam_{i}": "foam" for i in range(n)}, seed=0, fractions=fractions)
        for s, share in zip(SPLITS, fractions, strict=True):
            assert abs(len(split[s]) - n * share) < 1, (n, s, {k: len(v) for k, v in split.items()})


@pytest.mark.parametrize("fractions", [(0.5, 0.5), (0.8, 0.3, -0.1), (0.5, 0.2, 0.2)])
def test_bad_fractions_are_refused(fractions):
    with pytest.raises(EstimatorError, match="fractions"):
        split_objects(MATERIALS, seed=0, fractions=fractions)


def test_split_file_naming_an_object_twice_is_refused(tmp_path):
    path = tmp_path / "split.json"
    path.write_text(json.dumps({"train": ["a", "b"], "val": ["b"], "test": []}))
    with pytest.raises(SampleError, match=r"more than one split: \['b'\]"):
        load_split(path)


@pytest.mark.slow
def test_build_dataset_from_records_never_leaks_an_object(sim_grasps, tmp_path, capsys):
    records, calibration = sim_grasps
    out = tmp_path / "ds"
    argv = ["build-dataset", "--records", str(records), "--out", str(out), "--calibration", str(calibration),
            "--size", "32x44", "--shifts", "2", "--split", "0.5,0.25,0.25", "--seed", "3", "--json"]
    assert main(argv) == 0
    summary = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert summary["records"] == 4 and summary["size_px"] == [32, 44]
    assert summary["calibration_smoothing_px"] == [0.0]  # what a model trained on it then reads
    # The window the images show: the pad of the settings' estimator sensor (the simulated Wedge's).
    settings = load_settings()
    assert summary["window_m"] == pytest.approx(list(settings.sensor(settings.sensing.finger).pad_size_m))
    split = load_split(out / "split.json")
    where = defaultdict(set)
    n_samples = 0
    for s in SPLITS:
        for path in (sample_paths(out / s) if (out / s).is_dir() else []):
            sample = load_sample(path)
            n_samples += 1
            where[sample.object_name].add(s)
            assert sample.object_name in split[s], path  # no object outside its split
            assert path.parent.name == sample.object_name
            assert sample.depth_m.shape == (3, 32, 44) and sample.rgb_diff.shape == (3, 32, 44, 3)
            assert [e.method for e in sample.estimates] == list(ANALYTICAL_METHODS)
            assert sample.label_modulus_pa > 0 and np.all(np.diff(sample.force_n) >= -0.5)
            # The rig it was measured on, for the gel scale and the rig features.
            gel = settings.sensor(settings.sensing.finger)
            assert (sample.gel_modulus_pa, sample.gel_thickness_m) == (gel.gel_modulus_pa, gel.gel_thickness_m)
            assert sample.finger_stiffness_n_per_m == settings.gripper.finger_stiffness_n_per_m
    assert all(len(s) == 1 for s in where.values())  # every grasp and augmentation of an object in one split
    assert n_samples == sum(summary["samples"].values()) >= 3
    assert main(argv) == 2  # refuses to write over a dataset
    assert "already holds a dataset" in capsys.readouterr().err


def test_records_of_one_name_in_two_folders_keep_their_own_samples(sim_grasps, tmp_path, capsys):
    # Runs on several rigs name their records alike (<object>_g000.grasp in each run's folder).
    records, calibration = sim_grasps
    import dataclasses

    from teleop.record import read_record, write_record

    first = sorted(records.glob("*.grasp"))[0]
    (tmp_path / "recs" / "run_b").mkdir(parents=True)
    shutil.copy(first, tmp_path / "recs" / first.name)
    # Another grasp (not a byte copy of this one, which would be a duplicate) under the same file name.
    record = read_record(first)
    provenance = dataclasses.replace(record.provenance, seed=(record.provenance.seed or 0) + 1)
    write_record(dataclasses.replace(record, provenance=provenance), tmp_path / "recs" / "run_b" / first.name)
    out = tmp_path / "ds"
    assert main(["build-dataset", "--records", str(tmp_path / "recs"), "--out", str(out), "--calibration",
                 str(calibration), "--size", "32x44", "--shifts", "1", "--json"]) == 0
    summary = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    on_disk = [p for s in SPLITS if (out / s).is_dir() for p in sample_paths(out / s)]
    assert summary["grasps_used"] == 2 and len(on_disk) == sum(summary["samples"].values()) == 2


def test_build_dataset_refuses_an_empty_directory(tmp_path, capsys):
    assert main(["build-dataset", "--records", str(tmp_path), "--out", str(tmp_path / "o")]) == 2
    assert "no .grasp records" in capsys.readouterr().err


@pytest.mark.parametrize("size", ["0x88", "4x4", "7x88", "64x7", "251x88", "64x351", "999x999"])
def test_a_size_training_would_refuse_is_refused_before_building(size, tmp_path, capsys):
    with pytest.raises(SystemExit) as done:
        main(["build-dataset", "--records", str(tmp_path), "--out", str(tmp_path / "o"), "--size", size])
    assert done.value.code == 2 and not (tmp_path / "o").exists()
    assert f"size '{size}': expected rows 8..250 and cols 8..350" in capsys.readouterr().err


@pytest.mark.parametrize("command", ["build-dataset", "train", "fine-tune", "recalibrate"])
def test_a_negative_seed_is_refused_by_argparse_before_any_work(command, capsys):
    with pytest.raises(SystemExit) as done:
        main([command, "--seed", "-1"])
    assert done.value.code == 2 and "--seed: '-1': expected a whole number >= 0" in capsys.readouterr().err


@pytest.mark.parametrize("size", ["8x8", "250x350"])
def test_the_extremes_of_the_size_range_are_accepted(size):
    assert Variant(size_px=parse_size(size)).size_px == tuple(int(v) for v in size.split("x"))


# --------------------------------------------------------------------------- every drop has a name


def _variants(sim_grasps, folder):
    """One good simulated record and one of each kind build-dataset must skip, in ``folder``."""
    import dataclasses

    from teleop.record import Samples, read_record, write_record

    records, _ = sim_grasps
    good_path = sorted(records.glob("*.grasp"))[0]
    good = read_record(good_path)
    folder.mkdir(parents=True)
    shutil.copy(good_path, folder / "good.grasp")
    (folder / "garbage.grasp").write_bytes(b"not a zip")
    write_record(dataclasses.replace(good, label=None), folder / "no_label.grasp")
    write_record(dataclasses.replace(good, label=dataclasses.replace(good.label, modulus_pa=None)),
                 folder / "no_modulus.grasp")
    gone = folder / "gone" / "cal.npz"
    sensors = tuple(dataclasses.replace(s, calibration=str(gone)) for s in good.sensors)
    write_record(dataclasses.replace(good, sensors=sensors), folder / "moved_calibration.grasp")
    flat = Samples(good.force_n.t_s, np.zeros_like(good.force_n.value))
    write_record(dataclasses.replace(good, force_n=flat), folder / "no_loading.grasp")
    return folder, gone


def test_every_skipped_record_is_named_with_its_cause(sim_grasps, tmp_path, capsys):
    folder, gone = _variants(sim_grasps, tmp_path / "recs")
    out = tmp_path / "ds"
    argv = ["build-dataset", "--records", str(folder), "--out", str(out), "--size", "32x44", "--shifts", "1",
            "--json"]
    assert main(argv) == 0
    captured = capsys.readouterr()
    manifest = json.loads(captured.out.strip().splitlines()[-1])
    skipped = {Path(s["path"]).name: s for s in manifest["skipped"]}
    assert {name: s["cause"] for name, s in skipped.items()} == {
        "garbage.grasp": "unreadable", "no_label.grasp": "unlabelled", "no_modulus.grasp": "unlabelled",
        "moved_calibration.grasp": "calibration missing", "no_loading.grasp": "no usable loading phase",
    }
    reason = skipped["moved_calibration.grasp"]["reason"]
    assert str(gone) in reason and "does not exist" in reason and "teleop simulate" in reason
    assert "--calibration" in reason
    assert "not a readable ZIP" in skipped["garbage.grasp"]["reason"]
    assert "teleop label" in skipped["no_label.grasp"]["reason"]
    for name in skipped:  # and on stderr, by name
        assert f"skipped {folder / name}: " in captured.err
    assert [Path(u["path"]).name for u in manifest["used"]] == ["good.grasp"]
    assert manifest["skipped_reasons"] == {"unreadable": 1, "unlabelled": 2, "calibration missing": 1,
                                           "no usable loading phase": 1}
    assert json.loads((out / "dataset.json").read_text())["skipped"] == manifest["skipped"]
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == []


def test_the_manifest_counts_only_objects_that_gave_samples(sim_grasps, tmp_path, capsys):
    import dataclasses

    from teleop.record import Samples, read_record, write_record

    folder, _ = _variants(sim_grasps, tmp_path / "recs")
    good = read_record(folder / "good.grasp")
    flat = Samples(good.force_n.t_s, np.zeros_like(good.force_n.value))  # measured, and no loading phase
    other = dataclasses.replace(good.label, object_name="never_loaded")
    write_record(dataclasses.replace(good, label=other, force_n=flat), folder / "never_loaded.grasp")
    argv = ["build-dataset", "--records", str(folder), "--out", str(tmp_path / "ds"), "--size", "32x44",
            "--shifts", "1", "--split", "1,0,0", "--json"]
    assert main(argv) == 0
    manifest = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert "never_loaded.grasp" in {Path(s["path"]).name for s in manifest["skipped"]}
    assert manifest["objects"] == {"train": 1, "val": 0, "test": 0}


def test_a_build_that_makes_nothing_fails_naming_every_record_and_leaves_no_folder(sim_grasps, tmp_path, capsys):
    folder, _ = _variants(sim_grasps, tmp_path / "recs")
    (folder / "good.grasp").unlink()
    out = tmp_path / "ds"
    assert main(["build-dataset", "--records", str(folder), "--out", str(out), "--size", "32x44",
                 "--shifts", "1"]) == 2
    err = capsys.readouterr().err
    assert "no training sample made from the 5 records" in err and "Traceback" not in err
    for name in ("garbage", "no_label", "no_modulus", "moved_calibration", "no_loading"):
        assert f"{folder / name}.grasp: " in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["recs"]  # no dataset, whole or half


def test_a_record_whose_measurement_fails_is_skipped_as_such(sim_grasps, tmp_path, monkeypatch):
    import dataclasses

    import estimator.training.dataset as dataset
    from estimator.training.dataset import DatasetOptions, build_dataset
    from teleop.record import read_record, write_record

    records, calibration = sim_grasps
    sources = sorted(records.glob("*.grasp"))[:2]
    (tmp_path / "recs").mkdir()
    good = shutil.copy(sources[0], tmp_path / "recs" / "good.grasp")
    record = read_record(sources[1])
    bad = write_record(dataclasses.replace(record, label=dataclasses.replace(record.label, object_name="unmeasurable")),
                       tmp_path / "recs" / "bad.grasp")
    real = dataset.sample_grasp

    def failing(record, **kwargs):  # the measurement of one record fails (e.g. its depth cannot be recovered)
        if record.label.object_name == "unmeasurable":
            raise EstimatorError("depth reconstruction failed")
        return real(record, **kwargs)

    monkeypatch.setattr(dataset, "sample_grasp", failing)
    manifest = build_dataset([good, bad], tmp_path / "ds", settings=load_settings(), progress=False,
                             options=DatasetOptions(shifts=1, size_px=(32, 44), calibration=str(calibration)))
    assert [(s["path"], s["cause"]) for s in manifest["skipped"]] == [(str(bad), "measurement failed")]
    assert "depth reconstruction failed" in manifest["skipped"][0]["reason"]
    assert manifest["skipped_reasons"] == {"measurement failed": 1}
    assert manifest["grasps_used"] == 1 and [u["path"] for u in manifest["used"]] == [str(good)]


def test_a_record_without_a_sensor_on_the_settings_finger_is_skipped_naming_the_finger(sim_grasps, tmp_path):
    import dataclasses

    from estimator.training.dataset import DatasetOptions, build_dataset
    from teleop.record import read_record

    records, calibration = sim_grasps
    (tmp_path / "recs").mkdir()
    path = shutil.copy(sorted(records.glob("*.grasp"))[0], tmp_path / "recs" / "r.grasp")
    absent = "middle"
    assert absent not in [s.finger for s in read_record(path).sensors]
    # A rig whose sensing finger is one the record has no sensor on.
    settings = load_settings()
    middle = dataclasses.replace(settings.sensor(settings.sensing.finger), finger=absent)
    settings = dataclasses.replace(settings, sensors=(*settings.sensors, middle),
                                   sensing=dataclasses.replace(settings.sensing, finger=absent))
    with pytest.raises(EstimatorError) as refused:  # its only record skipped: nothing made
        build_dataset([path], tmp_path / "ds", settings=settings, progress=False,
                      options=DatasetOptions(shifts=1, size_px=(32, 44), calibration=str(calibration)))
    assert f"{path}: no sensor on finger {absent!r}" in str(refused.value) and "--settings" in str(refused.value)
    assert not (tmp_path / "ds").exists()


def test_a_build_that_fails_midway_leaves_nothing_behind(sim_grasps, tmp_path, monkeypatch):
    import estimator.training.dataset as dataset
    from estimator.training.dataset import DatasetOptions, build_dataset

    records, calibration = sim_grasps
    real, calls = dataset.save_sample, []

    def failing_save(sample, path):  # the disk fills up at the second sample
        calls.append(path)
        if len(calls) > 1:
            raise OSError(28, "No space left on device")
        return real(sample, path)

    monkeypatch.setattr(dataset, "save_sample", failing_save)
    out = tmp_path / "ds"
    with pytest.raises(EstimatorError, match="cannot write the dataset beside --out .*No space left"):
        build_dataset(sorted(records.glob("*.grasp")), out, settings=load_settings(),
                      options=DatasetOptions(shifts=1, size_px=(32, 44), calibration=str(calibration)),
                      progress=False)
    assert len(calls) == 2 and list(tmp_path.iterdir()) == []


def test_an_out_folder_with_files_in_it_or_a_missing_calibration_is_refused(sim_grasps, tmp_path, capsys):
    records, _ = sim_grasps
    (tmp_path / "ds").mkdir()
    (tmp_path / "ds" / "notes.txt").write_text("mine")
    assert main(["build-dataset", "--records", str(records), "--out", str(tmp_path / "ds")]) == 2
    assert "not an empty folder" in capsys.readouterr().err
    assert main(["build-dataset", "--records", str(records), "--out", str(tmp_path / "ds2"),
                 "--calibration", str(tmp_path / "typo.npz")]) == 2
    assert f"--calibration {tmp_path / 'typo.npz'}: no such calibration file" in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ds"]


def test_an_out_folder_under_a_plain_file_names_that_file(sim_grasps, tmp_path, capsys):
    records, _ = sim_grasps
    (tmp_path / "afile").write_text("not a folder")
    assert main(["build-dataset", "--records", str(records), "--out", str(tmp_path / "afile" / "ds")]) == 2
    err = capsys.readouterr().err
    assert f"{tmp_path / 'afile'} is not a directory" in err and "File exists" not in err


def _relabelled(sim_grasps, folder, names_and_moduli):
    """Simulated records (the fixture's, in turn) relabelled ``(object, modulus or None: its own)``, in
    ``folder`` as ``r<i>.grasp``; returns their paths."""
    import dataclasses

    from teleop.record import read_record, write_record

    records, _ = sim_grasps
    sources = sorted(records.glob("*.grasp"))
    folder.mkdir(parents=True)
    paths = []
    for i, (name, modulus) in enumerate(names_and_moduli):
        record = read_record(sources[i % len(sources)])
        label = dataclasses.replace(record.label, object_name=name,
                                    modulus_pa=record.label.modulus_pa if modulus is None else modulus)
        paths.append(write_record(dataclasses.replace(record, label=label), folder / f"r{i}.grasp"))
    return paths


def test_object_file_names_keep_safe_names_and_set_every_other_apart():
    from estimator.training.dataset import object_file_name

    for name in ("silicone_ball_shore00_30", "stress_ball", "rubber_duck", "a.b-c", ".hidden"):
        assert object_file_name(name) == name  # datasets of these keep their layout
    others = ["海绵", "软球", "钢球", "café", "cafè", "vinyl eraser", "vinyl/eraser", "..", ".", "...", "_"]
    files = [object_file_name(name) for name in others]
    assert len(set(files)) == len(others), files
    assert files[3].startswith("caf_+") and files[5].startswith("vinyl_eraser+")
    for file in files:
        assert "/" not in file and file.strip(".") and not file.startswith("."), file
    cased = [object_file_name(name) for name in ("ball", "Ball", "BALL")]  # apart where case is ignored
    assert cased[0] == "ball" and len({file.casefold() for file in cased}) == 3, cased


def test_objects_named_in_any_script_get_folders_of_their_own(sim_grasps, tmp_path, capsys):
    names = ["海绵", "软球", "钢球", "café", "cafè", "vinyl eraser", "vinyl_eraser"]
    folder = tmp_path / "recs"
    _relabelled(sim_grasps, folder, [(name, None) for name in names])
    out = tmp_path / "ds"
    assert main(["build-dataset", "--records", str(folder), "--out", str(out), "--calibration",
                 str(sim_grasps[1]), "--size", "32x44", "--shifts", "1", "--json"]) == 0
    summary = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    on_disk = {load_sample(p).object_name: p.parent for s in SPLITS if (out / s).is_dir()
               for p in sample_paths(out / s)}
    assert sorted(on_disk) == sorted(names) and len(set(on_disk.values())) == len(names)
    assert summary["grasps_used"] == sum(summary["samples"].values()) == len(names)
    assert on_disk["vinyl_eraser"].name == "vinyl_eraser"


def test_objects_named_with_dots_only_stay_inside_their_split(sim_grasps, tmp_path):
    from estimator.training.dataset import DatasetOptions, build_dataset
    from estimator.training.splits import load_split_data

    paths = _relabelled(sim_grasps, tmp_path / "recs", [("..", None), (".", None)])
    out = tmp_path / "ds"
    manifest = build_dataset(paths, out, settings=load_settings(), progress=False, fractions=(1.0, 0.0, 0.0),
                             options=DatasetOptions(shifts=1, size_px=(32, 44), calibration=str(sim_grasps[1])))
    assert sorted(p.name for p in out.iterdir()) == ["dataset.json", "split.json", "train"]
    for used in manifest["used"]:
        for sample in used["samples"]:
            assert (out / sample).resolve().parent.parent == (out / "train").resolve(), sample
    data = load_split_data(out, Variant.parse("depth", n_frames=3, size_px=(32, 44)), ("train",))
    assert sorted(r["object"] for r in data["train"].rows) == [".", ".."]


def test_one_object_labelled_with_far_apart_moduli_is_warned_about(sim_grasps, tmp_path, caplog):
    from estimator.training.dataset import DatasetOptions, build_dataset

    paths = _relabelled(sim_grasps, tmp_path / "recs", [("stress_ball", 1e6), ("stress_ball", 4e4),
                                                         ("sponge", 3e4), ("sponge", 5e4)])
    with caplog.at_level("WARNING", logger="estimator.training.dataset"):
        manifest = build_dataset(paths, tmp_path / "ds", settings=load_settings(), progress=False,
                                 options=DatasetOptions(shifts=1, size_px=(32, 44), calibration=str(sim_grasps[1])))
    assert manifest["grasps_used"] == 4  # a warning, not a refusal
    warned = [r.getMessage() for r in caplog.records if r.levelname == "WARNING"]
    spread = [w for w in manifest["warnings"] if "moduli" in w]
    assert len(spread) == 1 and spread[0] in warned  # sponge's 3e4 and 5e4 are within a factor of 2
    assert spread[0].startswith("object 'stress_ball'")
    assert f"40000 Pa in {paths[1]}" in spread[0] and f"1e+06 Pa in {paths[0]}" in spread[0]


def test_moduli_exactly_the_spread_apart_are_not_warned_about(sim_grasps, tmp_path):
    from estimator.training.dataset import DatasetOptions, build_dataset

    paths = _relabelled(sim_grasps, tmp_path / "recs", [("stress_ball", 1e5), ("stress_ball", MODULUS_SPREAD * 1e5)])
    manifest = build_dataset(paths, tmp_path / "ds", settings=load_settings(), progress=False,
                             options=DatasetOptions(shifts=1, size_px=(32, 44), calibration=str(sim_grasps[1])))
    assert manifest["grasps_used"] == 2
    assert [w for w in manifest["warnings"] if "moduli" in w] == []  # warned "by more than" the spread


def test_a_record_copied_into_two_folders_is_counted_once(sim_grasps, tmp_path, capsys):
    records, calibration = sim_grasps
    paths = sorted(records.glob("*.grasp"))
    for folder in ("a", "b"):
        (tmp_path / "recs" / folder).mkdir(parents=True)
        shutil.copy(paths[0], tmp_path / "recs" / folder / paths[0].name)
    shutil.copy(paths[1], tmp_path / "recs" / "a" / paths[1].name)
    out = tmp_path / "ds"
    assert main(["build-dataset", "--records", str(tmp_path / "recs"), "--out", str(out), "--calibration",
                 str(calibration), "--size", "32x44", "--shifts", "1", "--json"]) == 0
    summary = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert summary["grasps_used"] == 2 and sum(summary["samples"].values()) == 2
    kept, copy = (str(tmp_path / "recs" / f / paths[0].name) for f in ("a", "b"))
    assert summary["skipped"] == [{"path": copy, "cause": "duplicate", "reason": summary["skipped"][0]["reason"]}]
    assert summary["skipped"][0]["reason"].startswith(f"duplicate of {kept}")
    assert summary["skipped_reasons"] == {"duplicate": 1}


def test_a_split_left_without_val_or_test_samples_is_warned_about_at_build_time(sim_grasps, tmp_path, caplog):
    from estimator.training.dataset import DatasetOptions, build_dataset

    records, calibration = sim_grasps
    with caplog.at_level("WARNING", logger="estimator.training.dataset"):
        manifest = build_dataset([sorted(records.glob("*.grasp"))[0]], tmp_path / "ds", settings=load_settings(),
                                 options=DatasetOptions(shifts=1, size_px=(32, 44), calibration=str(calibration)),
                                 progress=False)
    assert manifest["samples"]["val"] == manifest["samples"]["test"] == 0
    warned = [r.getMessage() for r in caplog.records if r.levelname == "WARNING"]
    for split in ("val", "test"):
        assert any(m.startswith(f"split {split!r} has no samples") and "--split" in m for m in warned), warned
    assert len(manifest["warnings"]) == 2
