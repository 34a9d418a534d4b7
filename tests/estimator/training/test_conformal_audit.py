"""The conformal step, pinned by a mutation audit: the level it is asked for, the analytical floor it
fits under, and the documented figures (80 % floor of the ok intervals, 1 % leak, 100 grasps a band)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from estimator.errors import EstimatorError
from estimator.inference.distribution import EDGES_LOG10, censor, fit_temperature, floor_log_weights
from estimator.inference.inputs import FLOOR_METHODS
from estimator.training.conformal import described, fit_conformal, holds

CENTRES = (EDGES_LOG10[:-1] + EDGES_LOG10[1:]) / 2
LIMIT_PA = 6.75e6
SOFT_PA = 5e3


def logits_of(centres: np.ndarray, sd: float = 0.2) -> np.ndarray:
    """A model's logits, each grasp's distribution a normal of ``sd`` decades about its centre (log10 Pa)."""
    return np.stack([-((CENTRES - c) ** 2) / (2 * sd**2) for c in centres])


def _held(logits, cal, truth, force, floors=None, **changes) -> np.ndarray:
    """Whether each grasp's answer under ``cal`` (with ``changes``) holds its truth (all on the reference gel)."""
    said = described(logits, {**cal, **changes}, np.ones(truth.size), force, floors)
    return np.array([holds(d, 10.0**t) for d, t in zip(said, truth, strict=True)])


def _soft_grasps(n: int, seed: int, sd: float = 0.25) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(logits, truth, peak force) of ``n`` grasps of soft objects, answered ``sd`` decades off, all at 25 N."""
    rng = np.random.default_rng(seed)
    truth = rng.uniform(4.5, 5.8, n)
    return logits_of(truth + rng.normal(0, sd, n)), truth, np.full(n, 25.0)


@pytest.mark.parametrize("level", [0.8, 0.95])
def test_the_fit_holds_the_level_it_is_asked_for_and_records_it(level):
    logits, truth, force = _soft_grasps(150, seed=21)
    cal = fit_conformal(logits, truth, gel_scales=np.ones(truth.size), peak_forces_n=force, soft_pa=SOFT_PA,
                        limit_pa=LIMIT_PA, level=level, force_band_edges_n=())
    assert cal["level"] == level
    assert cal["n_ok"] == truth.size and cal["bound_coverage"] is None and cal["ok_coverage"] == cal["coverage"]
    # Split conformal at that level: ceil((n + 1) level) answers hold, and a hair narrower they would not.
    needed = math.ceil((truth.size + 1) * level)
    (scale,) = cal["interval_scales"]
    assert _held(logits, cal, truth, force).sum() >= needed > _held(
        logits, cal, truth, force, interval_scales=[scale * (1 - 1e-6)]).sum()


def _hybrid_grasps() -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(logits, truth, peak force, floors): soft grasps answered too softly, whose analytical lower bounds
    (all holding, 0.1 decade under the truth) lift most of the distribution."""
    rng = np.random.default_rng(22)
    n = 150
    truth = rng.uniform(4.5, 5.8, n)
    logits = logits_of(truth - 0.3 + rng.normal(0, 0.3, n), sd=0.4)
    return logits, truth, np.full(n, 25.0), truth - 0.1


def _fit_hybrid(**kwargs) -> tuple[dict, tuple[np.ndarray, ...]]:
    logits, truth, force, floors = grasps = _hybrid_grasps()
    cal = fit_conformal(logits, truth, gel_scales=np.ones(truth.size), peak_forces_n=force, soft_pa=SOFT_PA,
                        limit_pa=LIMIT_PA, floors_log10=floors, force_band_edges_n=(), **kwargs)
    return cal, grasps


def test_a_hybrids_calibration_records_its_floor_leaking_one_percent():
    cal, _ = _fit_hybrid()
    assert cal["floor"] == {"methods": list(FLOOR_METHODS), "leak": 0.01}


def test_a_hybrids_temperature_is_fitted_under_its_floor():
    cal, (logits, truth, _, floors) = _fit_hybrid()
    under_floor = fit_temperature(logits, censor(truth), log_weights=floor_log_weights(floors, leak=0.01))
    assert cal["temperature"] == pytest.approx(under_floor, rel=1e-9)
    assert cal["temperature"] != pytest.approx(fit_temperature(logits, censor(truth)), rel=1e-3)


def test_a_hybrids_scale_is_the_narrowest_at_which_its_floored_answers_hold():
    cal, (logits, truth, force, floors) = _fit_hybrid()
    needed = math.ceil((truth.size + 1) * 0.9)
    (scale,) = cal["interval_scales"]
    assert _held(logits, cal, truth, force, floors).sum() >= needed > _held(
        logits, cal, truth, force, floors, interval_scales=[scale * (1 - 1e-6)]).sum()
    assert cal["coverage"] == pytest.approx(_held(logits, cal, truth, force, floors).mean())


def test_the_answers_floor_leaks_what_the_calibration_says():
    # A floor on the resolution limit (a bin edge) multiplies the odds of E at or above it by 1 / leak.
    limit_log10 = EDGES_LOG10[38]
    logits = logits_of(np.array([6.6, 6.9, 7.1]), sd=0.5)
    ones, force, floors = np.ones(3), np.full(3, 25.0), np.full(3, limit_log10)
    cal = {"temperature": 1.0, "force_band_edges_n": [], "p_rigids": [0.999999], "interval_scales": [1.0],
           "soft_pa": SOFT_PA, "limit_pa": 10.0**limit_log10}
    bare = np.array([d.p_above_limit for d in described(logits, {**cal, "floor": None}, ones, force)])
    for leak in (0.01, 0.05):
        floor = {"methods": list(FLOOR_METHODS), "leak": leak}
        floored = np.array([d.p_above_limit for d in described(logits, {**cal, "floor": floor}, ones, force, floors)])
        assert np.allclose(floored / (1 - floored), bare / (1 - bare) / leak, rtol=1e-6)


def test_a_calibration_with_a_floor_refuses_answers_without_their_floors():
    cal, (logits, truth, force, _) = _fit_hybrid()
    with pytest.raises(EstimatorError, match="needs each grasp's floor"):
        described(logits, cal, np.ones(truth.size), force)


def test_ok_intervals_hold_on_at_least_80_percent_whatever_the_bounds_surplus():
    # Every bound right and three times as many bounds as ok answers: the level alone would let the
    # ok intervals hold on far fewer than 80 % of theirs; the floor keeps them at 80 %, just.
    rng = np.random.default_rng(23)
    soft, rigid = rng.uniform(4.5, 5.8, 100), rng.uniform(9.0, 11.0, 300)
    truth = np.concatenate([soft, rigid])
    said = np.concatenate([soft + rng.normal(0, 0.3, soft.size), np.full(rigid.size, 8.05)])
    force = np.full(truth.size, 25.0)
    cal = fit_conformal(logits_of(said), truth, gel_scales=np.ones(truth.size), peak_forces_n=force, soft_pa=SOFT_PA,
                        limit_pa=LIMIT_PA, force_band_edges_n=())
    assert cal["bound_coverage"] == 1.0 and cal["n_ok"] == soft.size
    assert cal["ok_levels"] == [pytest.approx(0.8, abs=0.01)]
    needed_ok = math.ceil((soft.size + 1) * 0.8)
    (scale,) = cal["interval_scales"]
    ok_held = round(cal["ok_coverage"] * soft.size)
    assert ok_held >= needed_ok
    assert cal["ok_levels"] == [ok_held / (soft.size + 1)]  # the split-conformal level they meet
    narrower = _held(logits_of(said), cal, truth, force, interval_scales=[scale * (1 - 1e-6)])
    assert narrower[:soft.size].sum() < needed_ok


@pytest.mark.parametrize(("n_light", "own_fit"), [(100, True), (99, False)])
def test_a_band_of_100_grasps_gets_its_own_fit_and_one_of_99_the_fit_on_all(n_light, own_fit):
    rng = np.random.default_rng(24)
    n_firm = 150
    truth = rng.uniform(4.5, 5.8, n_light + n_firm)
    error = np.concatenate([rng.normal(0, 0.6, n_light), rng.normal(0, 0.15, n_firm)])
    force = np.concatenate([np.full(n_light, 5.0), np.full(n_firm, 25.0)])
    kw = dict(gel_scales=np.ones(truth.size), peak_forces_n=force, soft_pa=SOFT_PA, limit_pa=LIMIT_PA)
    banded = fit_conformal(logits_of(truth + error), truth, force_band_edges_n=(10.0,), **kw)
    everywhere = fit_conformal(logits_of(truth + error), truth, force_band_edges_n=(), **kw)
    assert banded["band_n"] == [n_light, n_firm]
    assert (banded["interval_scales"][0] != everywhere["interval_scales"][0]) is own_fit
    assert banded["interval_scales"][1] != everywhere["interval_scales"][0]  # the firm band has its own


def test_bounds_failing_beyond_repair_take_the_widest_interval_promising_everything_and_say_so(caplog):
    rng = np.random.default_rng(11)
    soft_ok = rng.uniform(4.5, 5.8, 10)
    soft_called_rigid = rng.uniform(4.5, 5.8, 60)  # sure of rigid for soft objects: bounds that fail
    truth = np.concatenate([soft_ok, soft_called_rigid])
    said = np.concatenate([soft_ok + rng.normal(0, 0.3, soft_ok.size), np.full(60, 8.05)])
    with caplog.at_level("WARNING", logger="estimator.training.conformal"):
        cal = fit_conformal(logits_of(said), truth, gel_scales=np.ones(truth.size),
                            peak_forces_n=np.full(truth.size, 25.0), soft_pa=SOFT_PA, limit_pa=LIMIT_PA,
                            force_band_edges_n=())
    assert cal["ok_levels"] == [1.0] and cal["interval_scales"][0] >= 1.0
    assert "70 validation grasps are too few" in caplog.text and "90% interval" in caplog.text
