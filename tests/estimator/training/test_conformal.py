"""The conformal step: temperature, rigid probability and interval scale fitted on validation grasps."""

from __future__ import annotations

import numpy as np
import pytest

from estimator.inference.distribution import EDGES_LOG10
from estimator.training.conformal import (
    MIN_BAND_GRASPS,
    OK_LEVEL_FLOOR,
    P_RIGID_CHOICES,
    fit_conformal,
)

CENTRES = (EDGES_LOG10[:-1] + EDGES_LOG10[1:]) / 2
LIMIT_PA = 6.75e6
SOFT_PA = 5e3


def test_the_conformal_step_picks_the_rigid_threshold_and_a_scale_that_hold_on_the_validation_grasps():
    rng = np.random.default_rng(1)
    soft = rng.uniform(4.0, 5.8, 300)  # log10 E of soft objects, well below the 6.83 limit
    rigid = rng.uniform(8.5, 11.5, 200)  # plastics to metals
    truth = np.concatenate([soft, rigid])

    def logits_of(centres: np.ndarray) -> np.ndarray:
        return np.stack([-((CENTRES - c) ** 2) / (2 * 0.2**2) for c in centres])

    # Right about the class, scattered 0.2 decade within it: the bounds hold at the first choice.
    right = np.concatenate([soft + rng.normal(0, 0.2, soft.size), np.full(rigid.size, 8.05)])
    firm = np.full(truth.size, 25.0)  # one force band: the per-band fit is tested below
    cal = fit_conformal(logits_of(right), truth, gel_scales=np.ones(truth.size), peak_forces_n=firm, soft_pa=SOFT_PA,
                        limit_pa=LIMIT_PA)
    assert cal["p_rigids"][-1] == P_RIGID_CHOICES[0] and cal["bound_coverage"] >= 0.9 and cal["chosen_on"] == "val"
    assert cal["n"] == truth.size and cal["n_ok"] >= 0.95 * soft.size
    assert min(cal["interval_scales"]) > 0 and cal["temperature"] > 0
    # Every bound holds, so the ok intervals need hold less than 90 % for 90 % of all answers.
    assert cal["coverage"] >= 0.9 and OK_LEVEL_FLOOR <= cal["ok_levels"][-1] < 0.9
    assert cal["ok_levels"][-1] - 0.01 <= cal["ok_coverage"] < 0.9
    # Sure of rigid for 40 soft grasps too: no threshold saves those bounds, so the strictest is
    # taken and the shortfall is reported, not hidden.
    wrong = right.copy()
    wrong[:40] = 8.05
    cal = fit_conformal(logits_of(wrong), truth, gel_scales=np.ones(truth.size), peak_forces_n=firm, soft_pa=SOFT_PA,
                        limit_pa=LIMIT_PA)
    assert cal["p_rigids"][-1] == P_RIGID_CHOICES[-1] and cal["bound_coverage"] < 0.9
    # The ok intervals make up for the failed bounds.
    assert cal["ok_levels"][-1] > 0.9 and cal["ok_coverage"] >= cal["ok_levels"][-1] - 0.01
    assert cal["coverage"] >= 0.9


@pytest.mark.slow
def test_each_force_band_gets_the_interval_scale_that_holds_there():
    rng = np.random.default_rng(2)
    n = 600
    truth = rng.uniform(4.0, 5.8, n)  # soft objects: every answer is ok
    force_n = rng.choice([5.0, 15.0, 25.0], n)
    # Equally sure at every force, but a light grasp is three times as far off.
    error = rng.normal(0.0, np.where(force_n < 10.0, 0.6, 0.2))
    logits = np.stack([-((CENTRES - c) ** 2) / (2 * 0.2**2) for c in truth + error])
    cal = fit_conformal(logits, truth, gel_scales=np.ones(n), peak_forces_n=force_n, soft_pa=SOFT_PA, limit_pa=LIMIT_PA,
                        force_band_edges_n=(10.0, 20.0))
    light, middle, firm = cal["interval_scales"]
    assert light > 2.0 * max(middle, firm)
    assert all(0.87 <= c <= 0.95 for c in cal["band_coverage"]) and cal["band_n"] == [
        int((force_n == f).sum()) for f in (5.0, 15.0, 25.0)]
    # A band with too few grasps to fit takes the scale fitted on all of them.
    few = force_n.copy()
    few[np.flatnonzero(force_n == 5.0)[MIN_BAND_GRASPS - 1:]] = 15.0
    sparse = fit_conformal(logits, truth, gel_scales=np.ones(n), peak_forces_n=few, soft_pa=SOFT_PA, limit_pa=LIMIT_PA,
                           force_band_edges_n=(10.0, 20.0))
    everywhere = fit_conformal(logits, truth, gel_scales=np.ones(n), peak_forces_n=few, soft_pa=SOFT_PA,
                               limit_pa=LIMIT_PA, force_band_edges_n=())
    assert sparse["interval_scales"][0] == everywhere["interval_scales"][0] != sparse["interval_scales"][1]
