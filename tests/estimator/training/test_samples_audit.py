"""Audit of training samples: every per-frame array is checked against the frame count, and the
estimate of a method is that method's."""

from __future__ import annotations

import numpy as np
import pytest

from estimator.errors import SampleError
from estimator.estimate import Estimate
from estimator.training.samples import load_sample, save_sample
from tests.estimator.training.test_samples import H, N, W, make_sample, rewrite


@pytest.mark.parametrize(
    ("changes", "expected"),
    [
        ({"width_m": np.array([0.07, 0.07])}, f"width_m must be float64 with shape ({N},)"),
        ({"width_m": np.full((N, 1), 0.07)}, f"width_m must be float64 with shape ({N},)"),
        ({"depth_markers_m": np.zeros((N, H, W + 1), np.float32)}, f"depth_markers_m must be float32 with shape ({N}, {H}, {W})"),
        ({"rgb_diff_markers": np.zeros((N, H, W, 4), np.float32)}, f"rgb_diff_markers must have shape ({N}, H, W, 3)"),
    ],
)
def test_per_frame_arrays_of_another_shape_are_refused(changes, expected):
    with pytest.raises(SampleError) as info:
        make_sample(**changes)
    assert expected in str(info.value), str(info.value)


def test_the_estimate_of_a_method_is_that_methods():
    estimates = (Estimate.refuse("series", "too few frames"), Estimate.at_least("hertz", 1e6, "bound"))
    sample = make_sample(estimates=estimates)
    assert sample.estimate("hertz") is estimates[1] and sample.estimate("series") is estimates[0]
    assert sample.estimate("elastic") is None


def test_estimate_members_of_different_lengths_name_the_file(synthetic, tmp_path):
    path = save_sample(synthetic.sample("foam_a", 0, 0, rng=np.random.default_rng(0)), tmp_path / "s.npz")
    with np.load(path) as archive:
        states = archive["estimate_state"]
    rewrite(path, estimate_state=states[:-1])  # one state fewer than methods
    with pytest.raises(SampleError) as info:
        load_sample(path)
    assert str(path) in str(info.value) and "must be str (m,)" in str(info.value), str(info.value)
