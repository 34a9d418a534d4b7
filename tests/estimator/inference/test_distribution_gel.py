"""The estimate on a measuring gel other than the reference one: the softest modulus resolved is at most
a tenth of the resolution limit taken onto the reference gel."""

from __future__ import annotations

import math

import numpy as np
import pytest

from estimator.inference.distribution import EDGES_LOG10, N_BINS, describe_on_gel

SOFT_PA = 1e4  # the softest modulus the model resolves, on the reference gel
LIMIT_PA = 1e5  # the resolution limit on the measuring gel
MEDIAN_PA = 7e3  # on the reference gel: below SOFT_PA, above a tenth of a limit of 5e4 there


def _all_in_the_bin_of(e_pa: float) -> np.ndarray:
    probs = np.zeros(N_BINS)
    probs[np.searchsorted(EDGES_LOG10, math.log10(e_pa), side="right") - 1] = 1.0
    return probs


def _describe(gel_scale: float):
    return describe_on_gel(_all_in_the_bin_of(MEDIAN_PA), scale=1.0, limit_pa=LIMIT_PA, soft_pa=SOFT_PA,
                           p_rigid=0.5, gel_scale=gel_scale)


def test_a_limit_below_ten_soft_moduli_on_the_reference_gel_lowers_the_softest_resolved():
    gel_scale = 0.5  # the limit on the reference gel: 5e4 Pa, so the softest resolved is 5e3 Pa there
    said = _describe(gel_scale)
    assert said.state == "ok"  # the median, about 7e3 Pa there, is above 5e3 Pa
    assert said.low_pa < MEDIAN_PA / gel_scale < said.high_pa  # in the measuring gel's moduli
    assert 5e3 / gel_scale <= said.e_pa <= LIMIT_PA


def test_with_a_limit_of_ten_soft_moduli_or_more_the_same_median_is_an_upper_bound_at_soft_pa():
    gel_scale = 1.0  # the limit on the reference gel: 1e5 Pa, ten times SOFT_PA
    said = _describe(gel_scale)
    assert (said.state, said.low_pa, said.high_pa) == ("upper_bound", None, pytest.approx(SOFT_PA / gel_scale))
