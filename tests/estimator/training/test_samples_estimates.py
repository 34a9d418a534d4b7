"""Training samples carry every analytical estimate: round trip, None encoding, damaged members."""

from __future__ import annotations

import dataclasses
import zipfile

import numpy as np
import pytest

from estimator.errors import SampleError
from estimator.estimate import Estimate
from estimator.training.samples import load_sample, save_sample


def _rewrite(path, **members):
    with np.load(path) as archive:
        contents = {name: archive[name] for name in archive.files}
    for name, value in members.items():
        if value is None:
            contents.pop(name)
        else:
            contents[name] = value
    with path.open("wb") as fh:
        np.savez(fh, **contents)


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


def test_a_sample_without_estimates_writes_no_estimate_members(synthetic, tmp_path):
    sample = dataclasses.replace(synthetic.sample("foam_a", 0, 0, rng=np.random.default_rng(0)), estimates=())
    path = save_sample(sample, tmp_path / "s.npz")
    with zipfile.ZipFile(path) as zf:
        assert not [n for n in zf.namelist() if n.startswith("estimate_")]
    assert load_sample(path).estimates == ()


def test_bad_estimates_are_refused(synthetic):
    sample = synthetic.sample("foam_a", 0, 0, rng=np.random.default_rng(0))
    with pytest.raises(SampleError, match="name a method twice"):
        dataclasses.replace(sample, estimates=(Estimate.refuse("split", "a"), Estimate.refuse("split", "b")))
    with pytest.raises(SampleError, match="estimates must be a tuple of Estimate"):
        dataclasses.replace(sample, estimates=({"method": "split"},))


@pytest.mark.parametrize(("members", "expected"), [
    ({"estimate_state": None}, "member 'estimate_state' is missing"),
    ({"estimate_pa": np.zeros((4, 2))}, "estimate_pa float64 (m, 3)"),
    ({"estimate_method": np.array(["split"])}, "must be str (m,)"),
    ({"estimate_pa": np.full((4, 3), -1.0)}, "member 'estimate_pa' of method 'split'"),
    ({"estimate_state": np.array(["ok", "ok", "maybe", "ok"])}, "member 'estimate_pa' of method"),
])
def test_damaged_estimate_members_name_the_file(synthetic, tmp_path, members, expected):
    path = save_sample(synthetic.sample("foam_a", 0, 0, rng=np.random.default_rng(0)), tmp_path / "s.npz")
    _rewrite(path, **members)
    with pytest.raises(SampleError) as info:
        load_sample(path)
    assert str(path) in str(info.value) and expected in str(info.value), str(info.value)
