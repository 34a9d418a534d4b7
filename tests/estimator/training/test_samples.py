"""Training samples: validation, the .npz round trip, their analytical estimates, and the directory loader."""

from __future__ import annotations

import dataclasses
import io
import zipfile

import numpy as np
import pytest

from estimator.errors import SampleError
from estimator.estimate import Estimate
from estimator.training.samples import (
    SAMPLE_FORMAT,
    TrainingSample,
    iter_samples,
    load_sample,
    sample_paths,
    save_sample,
)

N, H, W = 3, 10, 14


def make_sample(**changes) -> TrainingSample:
    rng = np.random.default_rng(3)
    fields = dict(
        object_name="apple",
        grasp=2,
        augmentation=1,
        rgb_diff=rng.normal(0, 20, (N, H, W, 3)).astype(np.float32),
        depth_m=rng.uniform(0, 1e-3, (N, H, W)).astype(np.float32),
        force_n=np.array([1.0, 5.0, 12.0]),
        width_m=np.array([0.0750, 0.0745, 0.0741]),
        rgb_diff_markers=rng.normal(0, 20, (N, H, W, 3)).astype(np.float32),
        depth_markers_m=rng.uniform(0, 1e-3, (N, H, W)).astype(np.float32),
        elastic_estimate_pa=2.1e6,
        hertz_estar_pa=2.4e5,
        label_modulus_pa=3.25e6,
        gel_modulus_pa=1.5e5,
        gel_thickness_m=4e-3,
        finger_stiffness_n_per_m=8e4,
        material="food",
        shape="sphere",
    )
    fields.update(changes)
    return TrainingSample(**fields)


def assert_same(a: TrainingSample, b: TrainingSample) -> None:
    for f in dataclasses.fields(TrainingSample):
        x, y = getattr(a, f.name), getattr(b, f.name)
        if isinstance(x, np.ndarray):
            assert y.dtype == x.dtype and np.array_equal(x, y), f.name
        else:
            assert x == y, f.name


@pytest.mark.parametrize(
    "changes",
    [{}, {"rgb_diff_markers": None, "depth_markers_m": None, "elastic_estimate_pa": None,
          "hertz_estar_pa": None, "label_modulus_pa": None, "gel_modulus_pa": None, "gel_thickness_m": None,
          "finger_stiffness_n_per_m": None, "material": "", "shape": ""}],
    ids=["full", "minimal"],
)
def test_round_trip_is_exact(tmp_path, changes):
    sample = make_sample(**changes)
    path = save_sample(sample, tmp_path / "s.npz")
    assert not list(tmp_path.glob("*.partial"))
    back = load_sample(path)
    assert_same(sample, back)
    assert back.n_frames == N and back.has_markers == (sample.rgb_diff_markers is not None)
    with zipfile.ZipFile(path) as zf:  # an absent value is an absent member, never a NaN
        assert ("elastic_estimate_pa.npy" in zf.namelist()) == (sample.elastic_estimate_pa is not None)


def test_integers_and_numpy_scalars_are_normalised():
    sample = make_sample(grasp=np.int64(4), elastic_estimate_pa=np.float32(2e6), label_modulus_pa=5)
    assert type(sample.grasp) is int and type(sample.elastic_estimate_pa) is float
    assert sample.label_modulus_pa == 5.0


@pytest.mark.parametrize(
    ("changes", "expected"),
    [
        ({"rgb_diff": np.zeros((N, H, W, 3))}, "rgb_diff must be float32 with 4 dimensions, got float64"),
        ({"rgb_diff": np.zeros((N, H, W), np.float32)}, "rgb_diff must be float32 with 4 dimensions"),
        ({"rgb_diff": np.zeros((N, H, W, 4), np.float32)}, "rgb_diff must have shape (n >= 1, H, W, 3)"),
        ({"rgb_diff": np.zeros((0, H, W, 3), np.float32)}, "rgb_diff must have shape (n >= 1, H, W, 3)"),
        ({"rgb_diff": [[0.0]]}, "rgb_diff must be a numpy array, got list"),
        ({"depth_m": np.zeros((N, H, W + 1), np.float32)}, f"depth_m must be float32 with shape ({N}, {H}, {W})"),
        ({"depth_m": np.zeros((N, H, W))}, "depth_m must be float32"),
        ({"force_n": np.ones(N + 1)}, f"force_n must be float64 with shape ({N},)"),
        ({"force_n": np.ones(N, np.float32)}, "force_n must be float64"),
        ({"width_m": np.array([0.07, -0.001, 0.07])}, "width_m must be >= 0 m"),
        ({"depth_m": np.full((N, H, W), np.nan, np.float32)}, f"depth_m holds {N * H * W} non-finite values"),
        ({"rgb_diff": np.full((N, H, W, 3), np.inf, np.float32)}, "rgb_diff holds"),
        ({"force_n": np.array([1.0, np.nan, 2.0])}, "force_n holds 1 non-finite values"),
        ({"rgb_diff_markers": None}, "must be given together"),
        ({"rgb_diff_markers": np.zeros((N - 1, H, W, 3), np.float32)}, f"rgb_diff_markers must have shape ({N}, H, W, 3)"),
        ({"depth_markers_m": np.zeros((N, H, W), np.float64)}, "depth_markers_m must be float32"),
        ({"elastic_estimate_pa": float("nan")}, "elastic_estimate_pa must be finite and > 0"),
        ({"hertz_estar_pa": -2.0e5}, "hertz_estar_pa must be finite and > 0"),
        ({"hertz_estar_pa": float("inf")}, "hertz_estar_pa must be finite and > 0"),
        ({"label_modulus_pa": 0.0}, "label_modulus_pa must be finite and > 0"),
        ({"label_modulus_pa": True}, "label_modulus_pa must be a number or None"),
        ({"label_modulus_pa": "3e6"}, "label_modulus_pa must be a number or None"),
        ({"gel_thickness_m": 0.0}, "gel_thickness_m must be finite and > 0"),
        ({"finger_stiffness_n_per_m": float("nan")}, "finger_stiffness_n_per_m must be finite and > 0"),
        ({"grasp": -1}, "grasp must be an integer >= 0"),
        ({"augmentation": True}, "augmentation must be an integer >= 0"),
        ({"augmentation": 1.0}, "augmentation must be an integer >= 0"),
        ({"object_name": ""}, "object_name is empty"),
        ({"material": None}, "material must be a string"),
    ],
)
def test_invalid_samples_are_refused_with_the_field_named(changes, expected):
    with pytest.raises(SampleError) as info:
        make_sample(**changes)
    assert expected in str(info.value), str(info.value)


def rewrite(path, **members):
    """Rewrite the .npz at ``path`` with members replaced (value) or removed (None)."""
    with np.load(path) as archive:
        contents = {name: archive[name] for name in archive.files}
    for name, value in members.items():
        if value is None:
            contents.pop(name)
        else:
            contents[name] = value
    with path.open("wb") as fh:
        np.savez(fh, **contents)
    return path


def test_load_errors_name_the_file_and_member(tmp_path):
    good = save_sample(make_sample(), tmp_path / "good.npz")

    def fails(path, expected):
        with pytest.raises(SampleError) as info:
            load_sample(path)
        assert str(path) in str(info.value) and expected in str(info.value), str(info.value)

    fails(tmp_path / "absent.npz", "no such training sample")
    text = tmp_path / "text.npz"
    text.write_text("not an archive")
    fails(text, "not an .npz archive")
    single = tmp_path / "single.npy"
    np.save(single, np.zeros(3))
    fails(single, "not an .npz archive")
    truncated = tmp_path / "truncated.npz"
    truncated.write_bytes(good.read_bytes()[:200])
    fails(truncated, "not an .npz archive")

    cases = [
        ({"force_n": None}, "member 'force_n' is missing"),
        ({"object_name": None}, "member 'object_name' is missing"),
        ({"colour": np.str_("red")}, "unknown member 'colour'"),
        ({"format": np.str_("other.format")}, "format is 'other.format'"),
        ({"version": np.int64(2)}, "version 2 is not supported"),
        ({"grasp": np.float64(2.0)}, "member 'grasp' must be a scalar of kind 'i'"),
        ({"label_modulus_pa": np.array([3.25e6])}, "member 'label_modulus_pa' must be a scalar"),
        ({"depth_m": np.full((N, H, W), np.nan, np.float32)}, "depth_m holds"),
        ({"hertz_estar_pa": np.float64(-1.0)}, "hertz_estar_pa must be finite and > 0"),
        ({"force_n": np.array([1.0, "x"], dtype=object)}, "member 'force_n' is damaged or not a plain array"),
    ]
    for i, (members, expected) in enumerate(cases):
        path = tmp_path / f"case{i}.npz"
        path.write_bytes(good.read_bytes())
        if any(isinstance(v, np.ndarray) and v.dtype == object for v in members.values()):
            with np.load(path) as archive:
                contents = {name: archive[name] for name in archive.files}
            contents.update(members)
            buf = io.BytesIO()
            np.savez(buf, allow_pickle=True, **contents)
            path.write_bytes(buf.getvalue())
        else:
            rewrite(path, **members)
        fails(path, expected)


def test_directory_loader(tmp_path):
    (tmp_path / "b" / "grasp=0").mkdir(parents=True)
    (tmp_path / "a").mkdir()
    save_sample(make_sample(object_name="b"), tmp_path / "b" / "grasp=0" / "augmentation=0.npz")
    save_sample(make_sample(object_name="a", grasp=0), tmp_path / "a" / "g0.npz")
    save_sample(make_sample(object_name="a", grasp=1), tmp_path / "a" / "g1.npz")
    (tmp_path / "notes.txt").write_text("ignored")
    paths = sample_paths(tmp_path)
    assert [p.relative_to(tmp_path).as_posix() for p in paths] == [
        "a/g0.npz", "a/g1.npz", "b/grasp=0/augmentation=0.npz"]
    assert [(s.object_name, s.grasp) for s in iter_samples(tmp_path)] == [("a", 0), ("a", 1), ("b", 2)]
    assert load_sample(paths[0]).object_name == "a"
    with np.load(paths[0]) as archive:
        assert archive["format"].item() == SAMPLE_FORMAT

    (tmp_path / "bad.npz").write_text("broken")
    with pytest.raises(SampleError, match="bad.npz"):
        list(iter_samples(tmp_path))
    (tmp_path / "empty").mkdir()
    with pytest.raises(SampleError, match="holds no training samples"):
        list(iter_samples(tmp_path / "empty"))
    with pytest.raises(SampleError, match="not a directory"):
        sample_paths(tmp_path / "absent")


# --------------------------------------------------------------------------- analytical estimates


def test_estimates_round_trip_with_open_sides_and_refusals(synthetic, tmp_path):
    sample = synthetic.sample("metal_a", 1, 0, rng=np.random.default_rng(0))
    assert {e.state for e in sample.estimates} == {"ok", "lower_bound", "insufficient_data", "upper_bound"}
    back = load_sample(save_sample(sample, tmp_path / "s.npz"))
    assert back.estimates == sample.estimates
    assert back.estimate("hertz") == Estimate.at_least("hertz", 1e6, "synthetic bound")
    assert back.estimate("absent") is None
    with np.load(tmp_path / "s.npz") as archive:
        values = archive["estimate_pa"]
    assert values.shape == (4, 3) and np.isnan(values[2]).all()  # the refusal's None values


def test_a_sample_from_before_the_series_rename_reads_split_as_series(synthetic, tmp_path):
    # Datasets built before the rename name the series fit "split"; they still train and calibrate.
    sample = synthetic.sample("foam_a", 0, 0, rng=np.random.default_rng(0))
    path = save_sample(sample, tmp_path / "s.npz")
    with np.load(path) as archive:
        methods = archive["estimate_method"]
    rewrite(path, estimate_method=np.where(methods == "series", "split", methods))
    assert "series" in methods and load_sample(path).estimates == sample.estimates


def test_a_sample_without_estimates_writes_no_estimate_members(synthetic, tmp_path):
    sample = dataclasses.replace(synthetic.sample("foam_a", 0, 0, rng=np.random.default_rng(0)), estimates=())
    path = save_sample(sample, tmp_path / "s.npz")
    with zipfile.ZipFile(path) as zf:
        assert not [n for n in zf.namelist() if n.startswith("estimate_")]
    assert load_sample(path).estimates == ()


def test_bad_estimates_are_refused(synthetic):
    sample = synthetic.sample("foam_a", 0, 0, rng=np.random.default_rng(0))
    with pytest.raises(SampleError, match="name a method twice"):
        dataclasses.replace(sample, estimates=(Estimate.refuse("series", "a"), Estimate.refuse("series", "b")))
    with pytest.raises(SampleError, match="estimates must be a tuple of Estimate"):
        dataclasses.replace(sample, estimates=({"method": "series"},))


@pytest.mark.parametrize(("members", "expected"), [
    ({"estimate_state": None}, "member 'estimate_state' is missing"),
    ({"estimate_pa": np.zeros((4, 2))}, "estimate_pa float64 (m, 3)"),
    ({"estimate_method": np.array(["series"])}, "must be str (m,)"),
    ({"estimate_pa": np.full((4, 3), -1.0)}, "member 'estimate_pa' of method 'series'"),
    ({"estimate_state": np.array(["ok", "ok", "maybe", "ok"])}, "member 'estimate_pa' of method"),
])
def test_damaged_estimate_members_name_the_file(synthetic, tmp_path, members, expected):
    path = save_sample(synthetic.sample("foam_a", 0, 0, rng=np.random.default_rng(0)), tmp_path / "s.npz")
    rewrite(path, **members)
    with pytest.raises(SampleError) as info:
        load_sample(path)
    assert str(path) in str(info.value) and expected in str(info.value), str(info.value)
