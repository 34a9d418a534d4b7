"""Audit of the dataset builder: labels on the right sample, no held-out object in training, nothing
dropped silently, a manifest that describes the files it lists."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from estimator.errors import EstimatorError
from estimator.inference.provenance import SPLITS, load_split
from estimator.training.dataset import DatasetOptions, build_dataset, load_manifest, split_objects
from estimator.training.samples import load_sample, sample_paths
from teleop.settings import load_settings


def _on_disk(out: Path) -> list[str]:
    return sorted(p.relative_to(out).as_posix() for s in SPLITS if (out / s).is_dir() for p in sample_paths(out / s))


def test_a_record_whose_measurement_fails_at_a_later_shift_leaves_no_sample_behind(sim_grasps, tmp_path,
                                                                                   monkeypatch):
    import estimator.training.dataset as dataset

    records, calibration = sim_grasps
    sources = sorted(records.glob("*.grasp"))[:2]
    real = dataset.sample_grasp
    failing_path = sources[1]

    def failing(record, *, shift, **kwargs):  # shift 0 measures, shift 1 of one record fails
        if shift == 1 and record.label.object_name == failing.name:
            raise EstimatorError("depth reconstruction failed")
        return real(record, shift=shift, **kwargs)

    from teleop.record import read_record
    failing.name = read_record(failing_path).label.object_name
    monkeypatch.setattr(dataset, "sample_grasp", failing)
    out = tmp_path / "ds"
    manifest = build_dataset(sources, out, settings=load_settings(), progress=False,
                             options=DatasetOptions(shifts=2, size_px=(32, 44), calibration=str(calibration)))
    assert [(s["path"], s["cause"]) for s in manifest["skipped"]] == [(str(failing_path), "measurement failed")]
    # what the manifest lists is exactly what training reads: no sample of a skipped record on disk
    listed = sorted(p for u in manifest["used"] for p in u["samples"])
    assert _on_disk(out) == listed
    assert sum(manifest["samples"].values()) == len(listed) >= 1


def test_a_record_whose_sample_is_not_finite_is_skipped_and_the_build_goes_on(sim_grasps, tmp_path, monkeypatch):
    import dataclasses

    import estimator.training.dataset as dataset

    records, calibration = sim_grasps
    sources = sorted(records.glob("*.grasp"))[:2]
    real = dataset.sample_grasp

    def corrupt(record, **kwargs):  # the second record's depth comes out NaN
        sampled = real(record, **kwargs)
        if record.label.object_name != corrupt.name:
            return sampled
        return dataclasses.replace(sampled, depth_m=np.full_like(sampled.depth_m, np.nan))

    from teleop.record import read_record
    corrupt.name = read_record(sources[1]).label.object_name
    monkeypatch.setattr(dataset, "sample_grasp", corrupt)
    out = tmp_path / "ds"
    manifest = build_dataset(sources, out, settings=load_settings(), progress=False,
                             options=DatasetOptions(shifts=1, size_px=(32, 44), calibration=str(calibration)))
    [skipped] = manifest["skipped"]
    assert (skipped["path"], skipped["cause"]) == (str(sources[1]), "measurement failed") and "depth_m" in skipped["reason"]
    assert [u["path"] for u in manifest["used"]] == [str(sources[0])] and _on_disk(out) == manifest["used"][0]["samples"]


@pytest.fixture(scope="module")
def built(sim_grasps, tmp_path_factory):
    """A dataset of the simulated records plus a second, differently labelled grasp of one object, built with
    options other than the defaults and given its records in reverse path order."""
    import dataclasses

    from teleop.record import read_record, write_record

    records, calibration = sim_grasps
    folder = tmp_path_factory.mktemp("audit_recs")
    sources = sorted(records.glob("*.grasp"))
    for source in sources:
        shutil.copy(source, folder / source.name)
    # another grasp of the first object (a record of the second, relabelled): its own modulus and material
    first = read_record(sources[0]).label
    other = read_record(sources[1])
    label = dataclasses.replace(first, modulus_pa=first.modulus_pa * 1.5, material="relabelled", shape="odd")
    write_record(dataclasses.replace(other, label=label), folder / "aa_second_grasp.grasp")
    settings = load_settings()
    marker = next(s for s in read_record(sources[0]).sensors if s.markers)
    pad = settings.sensor(settings.sensing.finger).pad_size_m
    options = DatasetOptions(n_frames=2, shifts=2, size_px=(32, 44), window_m=(pad[0] * 0.8, pad[1] * 0.9),
                             markers=True, calibration=str(calibration), marker_calibration=marker.calibration)
    paths = sorted(folder.glob("*.grasp"), reverse=True)
    out = tmp_path_factory.mktemp("audit_ds") / "ds"
    manifest = build_dataset(paths, out, settings=settings, options=options, seed=7, fractions=(0.5, 0.25, 0.25),
                             progress=False)
    return out, manifest, options, paths


def test_every_sample_carries_its_own_records_label_grasp_and_augmentation(built):
    from teleop.record import read_record

    out, manifest, _, paths = built
    split = load_split(out / "split.json")
    records_of: dict[str, list[str]] = {}
    for path in sorted(paths):
        records_of.setdefault(read_record(path).label.object_name, []).append(str(path))
    assert any(len(v) == 2 for v in records_of.values())
    n_shifted = 0
    for used in manifest["used"]:
        label = read_record(used["path"]).label
        assert used["object"] == label.object_name and used["object"] in split[used["split"]]
        grasp = records_of[label.object_name].index(used["path"])  # the object's i-th record in path order
        by_augmentation = {}
        for relative in used["samples"]:
            sample = load_sample(out / relative)
            stem = Path(relative).stem
            assert Path(relative).parts[0] == used["split"]
            assert (sample.object_name, sample.label_modulus_pa) == (label.object_name, label.modulus_pa), relative
            assert (sample.material, sample.shape) == (label.material, label.shape), relative
            assert sample.grasp == grasp and stem.endswith(f"_g{grasp:04d}_a{sample.augmentation}"), relative
            assert sample.n_frames == 2 and sample.has_markers and sample.rgb_diff.shape == (2, 32, 44, 3)
            by_augmentation[sample.augmentation] = sample
        if len(by_augmentation) > 1:
            n_shifted += 1
            assert not np.array_equal(by_augmentation[0].force_n, by_augmentation[1].force_n)
    assert n_shifted >= 1
    # a stored sample is what the live sampling gives for its record with the options built with (its window too)
    from estimator.inference.sampling import sample_grasp

    _, _, options, _ = built
    used = manifest["used"][0]
    first = next(load_sample(out / p) for p in used["samples"] if p.endswith("_a0.npz"))
    live = sample_grasp(read_record(used["path"]), settings=load_settings(), calibration=options.calibration,
                        n_frames=options.n_frames, size_px=options.size_px, shift=0, rgb=True, markers=True,
                        marker_calibration=options.marker_calibration, window_m=options.window_m)
    assert np.array_equal(first.depth_m, live.depth_m) and np.array_equal(first.rgb_diff, live.rgb_diff)


def test_the_manifest_describes_the_files_and_options_it_was_built_with(built):
    out, manifest, options, paths = built
    settings = load_settings()
    assert json.loads((out / "dataset.json").read_text()) == load_manifest(out) == manifest
    assert (manifest["n_frames"], manifest["shifts"], manifest["size_px"], manifest["markers"]) == (2, 2, [32, 44],
                                                                                                   True)
    assert manifest["window_m"] == pytest.approx(list(options.window_m))
    assert (manifest["calibration"], manifest["marker_calibration"]) == (options.calibration,
                                                                          options.marker_calibration)
    assert manifest["finger"] == settings.sensing.finger and manifest["records"] == len(paths)
    split = load_split(out / "split.json")
    raw_split = json.loads((out / "split.json").read_text())
    assert (raw_split["seed"], raw_split["fractions"]) == (7, [0.5, 0.25, 0.25])
    assert manifest["objects"] == {s: len(split[s]) for s in SPLITS}
    on_disk = _on_disk(out)
    assert sorted(p for u in manifest["used"] for p in u["samples"]) == on_disk
    assert manifest["samples"] == {s: sum(p.startswith(f"{s}/") for p in on_disk) for s in SPLITS}
    assert manifest["grasps_used"] == len(manifest["used"]) == len(paths) - len(manifest["skipped"])


def test_a_split_without_test_samples_is_warned_about_too(sim_grasps, tmp_path):
    records, calibration = sim_grasps
    manifest = build_dataset(sorted(records.glob("*.grasp")), tmp_path / "ds", settings=load_settings(),
                             options=DatasetOptions(shifts=1, size_px=(32, 44), calibration=str(calibration)),
                             fractions=(0.75, 0.25, 0.0), progress=False)
    assert manifest["samples"]["val"] and not manifest["samples"]["test"]
    assert [w.split(":")[0].split(" (")[0] for w in manifest["warnings"]] == ["split 'test' has no samples"]


def test_an_interrupted_build_leaves_nothing_behind(sim_grasps, tmp_path, monkeypatch):
    import estimator.training.dataset as dataset

    records, calibration = sim_grasps

    def interrupted(sample, path):
        raise KeyboardInterrupt

    monkeypatch.setattr(dataset, "save_sample", interrupted)
    with pytest.raises(KeyboardInterrupt):
        build_dataset(sorted(records.glob("*.grasp")), tmp_path / "ds", settings=load_settings(), progress=False,
                      options=DatasetOptions(shifts=1, size_px=(32, 44), calibration=str(calibration)))
    assert list(tmp_path.iterdir()) == []


def test_split_names_are_sorted_whatever_order_they_were_drawn_in():
    materials = {f"obj_{i:02d}": ("foam" if i % 2 else "wood") for i in range(30)}
    split = split_objects(materials, seed=11)
    assert all(split[s] == sorted(split[s]) for s in SPLITS)
    assert split != split_objects(materials, seed=12)


def test_a_manifest_of_another_format_is_refused(tmp_path):
    from estimator.errors import SampleError

    (tmp_path / "dataset.json").write_text(json.dumps({"format": "compliance-teleop.other", "version": 1}))
    with pytest.raises(SampleError, match="not a compliance-teleop.dataset manifest"):
        load_manifest(tmp_path)
    (tmp_path / "dataset.json").write_text("[]")
    with pytest.raises(SampleError, match="not a compliance-teleop.dataset manifest"):
        load_manifest(tmp_path)


def test_an_unsafe_object_name_gets_sixteen_hex_digits_of_its_hash():
    import hashlib

    from estimator.training.dataset import object_file_name

    assert object_file_name("Ball") == "Ball+" + hashlib.sha256(b"Ball").hexdigest()[:16]


def test_moduli_more_than_twice_apart_are_warned_about():
    from estimator.training.dataset import _modulus_warnings

    def labels(ratio):
        return {Path("a.grasp"): ("ball", "", 1e6), Path("b.grasp"): ("ball", "", ratio * 1e6)}

    [warning] = _modulus_warnings(labels(2.5))
    assert "'ball'" in warning and "2.5 times apart" in warning and "a.grasp" in warning and "b.grasp" in warning
    assert _modulus_warnings(labels(2.0)) == []


def test_the_skipped_records_are_listed_in_path_order_whichever_stage_skipped_them(sim_grasps, tmp_path):
    from tests.estimator.training.test_dataset import _variants

    folder, _ = _variants(sim_grasps, tmp_path / "recs")
    manifest = build_dataset(sorted(folder.glob("*.grasp")), tmp_path / "ds", settings=load_settings(),
                             options=DatasetOptions(shifts=1, size_px=(32, 44)), progress=False)
    names = [Path(s["path"]).name for s in manifest["skipped"]]
    assert names == sorted(names) and "no_loading.grasp" in names  # measured, then skipped, among the others
    assert manifest["records"] == 6 and manifest["grasps_used"] == 1


def test_a_build_whose_every_record_fails_its_check_counts_them_all(sim_grasps, tmp_path):
    from tests.estimator.training.test_dataset import _variants

    folder, _ = _variants(sim_grasps, tmp_path / "recs")
    paths = [folder / "garbage.grasp", folder / "no_label.grasp", folder / "no_modulus.grasp"]
    with pytest.raises(EstimatorError, match="no training sample made from the 3 records given"):
        build_dataset(paths, tmp_path / "ds", settings=load_settings(),
                      options=DatasetOptions(shifts=1, size_px=(32, 44)), progress=False)


def test_of_byte_copies_given_in_any_order_the_first_in_path_order_is_kept(sim_grasps, tmp_path):
    records, calibration = sim_grasps
    source = sorted(records.glob("*.grasp"))[0]
    for folder in ("a", "b"):
        (tmp_path / folder).mkdir()
        shutil.copy(source, tmp_path / folder / source.name)
    first, second = tmp_path / "a" / source.name, tmp_path / "b" / source.name
    manifest = build_dataset([second, first], tmp_path / "ds", settings=load_settings(), progress=False,
                             options=DatasetOptions(shifts=1, size_px=(32, 44), calibration=str(calibration)))
    assert [u["path"] for u in manifest["used"]] == [str(first)]
    assert [(s["path"], s["cause"]) for s in manifest["skipped"]] == [(str(second), "duplicate")]
    assert f"duplicate of {first}" in manifest["skipped"][0]["reason"]
