"""The conformal step: temperature, rigid probability and interval scale fitted on validation grasps."""

from __future__ import annotations

import numpy as np
import pytest

from estimator.inference.distribution import EDGES_LOG10, Described
from estimator.training.conformal import (
    FLOOR_LEAK,
    INTERVAL_LEVEL,
    MIN_BAND_GRASPS,
    OK_LEVEL_FLOOR,
    P_RIGID_CHOICES,
    described,
    fit_conformal,
    holds,
)

CENTRES = (EDGES_LOG10[:-1] + EDGES_LOG10[1:]) / 2
LIMIT_PA = 6.75e6
SOFT_PA = 5e3


def logits_of(centres: np.ndarray, sd: float = 0.2) -> np.ndarray:
    """A model's logits, each grasp's distribution a normal of ``sd`` decades about its centre (log10 Pa)."""
    return np.stack([-((CENTRES - c) ** 2) / (2 * sd**2) for c in centres])


def test_the_conformal_step_picks_the_rigid_threshold_and_a_scale_that_hold_on_the_validation_grasps():
    rng = np.random.default_rng(1)
    soft = rng.uniform(4.0, 5.8, 300)  # log10 E of soft objects, well below the 6.83 limit
    rigid = rng.uniform(8.5, 11.5, 200)  # plastics to metals
    truth = np.concatenate([soft, rigid])
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
    logits = logits_of(truth + error)
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


def test_a_failed_upper_bound_does_not_make_the_rigid_threshold_stricter():
    # p_rigid decides lower bounds only: an answer "softer than soft_pa" that fails is no reason to
    # answer rigid objects less often, and no p_rigid could make it hold.
    rng = np.random.default_rng(5)
    soft = 5.0 + rng.uniform(-0.3, 0.3, 200)
    truth = np.concatenate([soft, [4.6]])
    said = np.concatenate([soft, [3.0]])  # the last grasp said softer than soft_pa; it is not
    force = np.full(truth.size, 25.0)
    cal = fit_conformal(logits_of(said), truth, gel_scales=np.ones(truth.size), peak_forces_n=force, soft_pa=SOFT_PA,
                        limit_pa=LIMIT_PA)
    states = [d.state for d in described(logits_of(said), cal, np.ones(truth.size), force)]
    assert "lower_bound" not in states and states[-1] == "upper_bound" and cal["bound_coverage"] == 0.0
    assert cal["p_rigids"] == [P_RIGID_CHOICES[0]] * 3


def test_a_truth_on_an_interval_edge_is_held():
    closed = Described("ok", 2e4, 1e4, 4e4, 0.0)
    assert holds(closed, 1e4) and holds(closed, 4e4) and holds(closed, 2e4)
    assert not holds(closed, 9.99e3) and not holds(closed, 4.01e4)
    assert holds(Described("lower_bound", 6.75e6, 6.75e6, None, 0.99), 6.75e6)
    assert holds(Described("upper_bound", 5e3, None, 5e3, 0.0), 5e3)


def _fit_one_band(said: np.ndarray, truth: np.ndarray, **kwargs) -> dict:
    """fit_conformal of a model sure of ``said`` (log10 Pa) on grasps all of 25 N, all on the reference gel."""
    return fit_conformal(logits_of(said), truth, gel_scales=np.ones(truth.size), peak_forces_n=np.full(truth.size, 25.0),
                         soft_pa=SOFT_PA, limit_pa=LIMIT_PA, **kwargs)


def test_a_band_with_only_rigid_grasps_gets_a_usable_interval_scale():
    # Every validation grasp is rigid (answered with a lower bound): no ok interval to fit a scale on.
    truth = np.random.default_rng(6).uniform(9.0, 11.0, 50)
    cal = _fit_one_band(np.full(truth.size, 8.05), truth)
    assert cal["n_ok"] == 0
    assert all(np.isfinite(s) and s >= 1.0 for s in cal["interval_scales"])
    assert all(OK_LEVEL_FLOOR <= q <= 1.0 for q in cal["ok_levels"])


def test_bounds_that_hold_on_exactly_the_level_keep_the_loosest_rigid_threshold():
    # 9 of 10 lower bounds right is exactly 90 %: enough.
    rng = np.random.default_rng(9)
    soft = rng.uniform(4.5, 5.8, 100)
    rigid = np.concatenate([rng.uniform(9.0, 11.0, 9), [5.0]])  # the tenth "rigid" answer is a soft object
    cal = _fit_one_band(np.concatenate([soft + rng.normal(0, 0.1, soft.size), np.full(rigid.size, 8.05)]),
                        np.concatenate([soft, rigid]))
    assert cal["n"] - cal["n_ok"] == 10 and cal["bound_coverage"] == 0.9
    assert cal["p_rigids"][-1] == P_RIGID_CHOICES[0]


def test_the_ok_intervals_never_promise_less_than_the_floor_however_many_bounds_hold():
    rng = np.random.default_rng(10)
    soft = rng.uniform(4.5, 5.8, 100)
    rigid = rng.uniform(9.0, 11.0, 300)  # every rigid answer right: a large surplus of held bounds
    cal = _fit_one_band(np.concatenate([soft + rng.normal(0, 0.3, soft.size), np.full(rigid.size, 8.05)]),
                        np.concatenate([soft, rigid]))
    assert cal["bound_coverage"] == 1.0
    assert min(cal["ok_levels"]) >= OK_LEVEL_FLOOR
    assert cal["ok_coverage"] >= OK_LEVEL_FLOOR - 0.02


def test_bounds_failing_beyond_what_ok_intervals_can_make_up_give_the_widest_interval_not_an_error():
    rng = np.random.default_rng(11)
    soft_ok = rng.uniform(4.5, 5.8, 10)
    soft_called_rigid = rng.uniform(4.5, 5.8, 60)  # sure of rigid for soft objects: bounds that fail
    cal = _fit_one_band(np.concatenate([soft_ok + rng.normal(0, 0.3, soft_ok.size), np.full(60, 8.05)]),
                        np.concatenate([soft_ok, soft_called_rigid]))
    assert all(level <= 1.0 for level in cal["ok_levels"])
    assert all(np.isfinite(s) and s >= 1.0 for s in cal["interval_scales"])


def test_the_temperature_scores_rigid_truths_censored_as_the_model_learned_them():
    # Rigid objects are learned censored at CENSOR_PA (1e8 Pa): a model that puts them there is right,
    # and the temperature must not flatten its distribution for truths it was never asked to place.
    rng = np.random.default_rng(12)
    soft, rigid = rng.uniform(4.5, 5.8, 200), rng.uniform(9.0, 11.5, 200)
    cal = _fit_one_band(np.concatenate([soft + rng.normal(0, 0.2, soft.size), np.full(rigid.size, 8.05)]),
                        np.concatenate([soft, rigid]))
    assert cal["temperature"] < 1.0


def test_a_hybrids_floor_leaves_the_floor_leak_of_the_weight_below_it():
    # With the floor on the resolution limit, on a bin edge, the floor multiplies the odds of E at or
    # above the limit by exactly 1 / FLOOR_LEAK.
    rng = np.random.default_rng(8)
    limit_log10 = EDGES_LOG10[38]
    truth = rng.uniform(6.8, 8.0, 120)
    logits = logits_of(rng.uniform(6.4, 7.2, truth.size), sd=0.5)
    ones, force, floors = np.ones(truth.size), np.full(truth.size, 25.0), np.full(truth.size, limit_log10)
    cal = fit_conformal(logits, truth, gel_scales=ones, peak_forces_n=force, soft_pa=SOFT_PA,
                        limit_pa=10.0**limit_log10, floors_log10=floors)
    floored = np.array([d.p_above_limit for d in described(logits, cal, ones, force, floors)])
    unfloored = np.array([d.p_above_limit for d in described(logits, {**cal, "floor": None}, ones, force)])
    assert np.allclose(floored / (1 - floored), unfloored / (1 - unfloored) / FLOOR_LEAK, rtol=1e-6)


def test_the_fit_scores_answers_on_any_gel_against_the_truth_on_that_gel():
    # Labels are on the reference gel (log10 of E times the gel scale); answers and truths on the measuring gel.
    rng = np.random.default_rng(13)
    n = 300
    measured = rng.uniform(4.5, 5.8, n)  # log10 E the measuring gel sees
    error = rng.normal(0, 0.2, n)
    figures = []
    for scale in (1.0, 4.0):
        label = measured + np.log10(scale)
        cal = fit_conformal(logits_of(label + error), label, gel_scales=np.full(n, scale),
                            peak_forces_n=np.full(n, 25.0), soft_pa=SOFT_PA, limit_pa=LIMIT_PA)
        figures.append((cal["coverage"], cal["ok_coverage"]))
    assert figures[0][0] >= INTERVAL_LEVEL
    assert figures[1] == pytest.approx(figures[0], abs=0.02)


def _two_band_grasps(n_light: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(logits, truth, peak force): ``n_light`` light grasps of soft objects answered far off, and 450 firm
    ones, 300 of them rigid."""
    rng = np.random.default_rng(7)
    light_truth = rng.uniform(4.0, 5.8, n_light)
    firm_truth = np.concatenate([rng.uniform(4.0, 5.8, 150), rng.uniform(8.5, 11.0, 300)])
    truth = np.concatenate([light_truth, firm_truth])
    said = np.concatenate([light_truth + rng.normal(0, 0.6, n_light), firm_truth[:150] + rng.normal(0, 0.2, 150),
                           np.full(300, 8.05)])
    force = np.concatenate([np.full(n_light, 5.0), np.full(450, 25.0)])
    return logits_of(said), truth, force


def test_each_band_keeps_the_level_on_its_own_grasps_whatever_the_bounds_of_other_bands():
    logits, truth, force = _two_band_grasps(200)
    cal = fit_conformal(logits, truth, gel_scales=np.ones(truth.size), peak_forces_n=force, soft_pa=SOFT_PA,
                        limit_pa=LIMIT_PA, force_band_edges_n=(10.0,))
    # The firm band's held bounds do not lower what the light band's ok intervals must hold.
    assert cal["band_coverage"][0] >= INTERVAL_LEVEL, cal["band_coverage"]
    assert cal["band_coverage"][1] >= INTERVAL_LEVEL, cal["band_coverage"]


def test_a_band_of_exactly_the_fewest_grasps_gets_its_own_fit():
    logits, truth, force = _two_band_grasps(MIN_BAND_GRASPS)
    kw = dict(gel_scales=np.ones(truth.size), peak_forces_n=force, soft_pa=SOFT_PA, limit_pa=LIMIT_PA)
    banded = fit_conformal(logits, truth, force_band_edges_n=(10.0,), **kw)
    everywhere = fit_conformal(logits, truth, force_band_edges_n=(), **kw)
    assert banded["band_n"][0] == MIN_BAND_GRASPS
    assert banded["interval_scales"][0] != everywhere["interval_scales"][0]


def test_each_force_band_answers_with_its_own_rigid_threshold():
    # P(E >= limit) of about 0.7: rigid where the band's threshold is 0.5, not where it is 0.9.
    cal = {"temperature": 1.0, "floor": None, "force_band_edges_n": [10.0], "p_rigids": [0.9, 0.5],
           "interval_scales": [1.0, 1.0], "soft_pa": SOFT_PA, "limit_pa": LIMIT_PA}
    light, firm = described(logits_of(np.array([6.95, 6.95])), cal, np.ones(2), np.array([5.0, 25.0]))
    assert light.p_above_limit == firm.p_above_limit
    assert 0.5 <= firm.p_above_limit < 0.9, firm.p_above_limit
    assert firm.state == "lower_bound" and light.state != "lower_bound"


def test_band_coverage_is_the_share_held_among_that_bands_own_grasps():
    rng = np.random.default_rng(14)
    n_light, n_firm = 50, 400  # too few light grasps for a fit of their own: they take the one fitted on all
    truth = rng.uniform(4.5, 5.8, n_light + n_firm)
    error = np.concatenate([rng.normal(0, 0.8, n_light), rng.normal(0, 0.2, n_firm)])
    force = np.concatenate([np.full(n_light, 5.0), np.full(n_firm, 25.0)])
    cal = fit_conformal(logits_of(truth + error), truth, gel_scales=np.ones(truth.size), peak_forces_n=force,
                        soft_pa=SOFT_PA, limit_pa=LIMIT_PA, force_band_edges_n=(10.0,))
    said = described(logits_of(truth + error), cal, np.ones(truth.size), force)
    held = np.array([holds(d, 10.0**t) for d, t in zip(said, truth, strict=True)])
    assert cal["band_n"] == [n_light, n_firm]
    assert cal["band_coverage"] == pytest.approx([held[:n_light].mean(), held[n_light:].mean()])
    assert cal["band_coverage"][0] < cal["coverage"] < cal["band_coverage"][1]


def test_the_scale_is_the_narrowest_at_which_the_answers_it_describes_hold():
    # Sure of E just above the limit for 100 objects a little below it: a narrow interval lies wholly
    # above the limit and is a lower bound that fails, a wide one reaches down to the truth, so each
    # scale tried must be scored on the answers it describes.
    rng = np.random.default_rng(5)
    soft, rigid, near = rng.uniform(4.5, 5.8, 300), rng.uniform(8.5, 11.0, 200), rng.uniform(6.0, 6.6, 100)
    truth = np.concatenate([soft, rigid, near])
    logits = np.concatenate([logits_of(soft + rng.normal(0, 0.2, soft.size)), logits_of(np.full(rigid.size, 8.05)),
                             logits_of(rng.normal(7.1, 0.05, near.size), sd=0.1)])
    kw = dict(gel_scales=np.ones(truth.size), peak_forces_n=np.full(truth.size, 25.0))
    cal = fit_conformal(logits, truth, soft_pa=SOFT_PA, limit_pa=LIMIT_PA, force_band_edges_n=(), **kw)
    needed = np.ceil((truth.size + 1) * INTERVAL_LEVEL)

    def held(scale: float, p_rigid: float) -> list[bool]:
        said = described(logits, {**cal, "interval_scales": [scale], "p_rigids": [p_rigid]}, kw["gel_scales"],
                         kw["peak_forces_n"])
        return [holds(d, 10.0**t) for d, t in zip(said, truth, strict=True)]

    (scale,), (p_rigid,) = cal["interval_scales"], cal["p_rigids"]
    assert sum(held(scale, p_rigid)) >= needed > sum(held(scale * (1 - 1e-6), p_rigid))
    assert cal["coverage"] == pytest.approx(np.mean(held(scale, p_rigid)))
    # The loosest threshold whose lower bounds hold at the level, as the operator gets them.
    looser = P_RIGID_CHOICES[P_RIGID_CHOICES.index(p_rigid) - 1]
    said = described(logits, {**cal, "p_rigids": [looser]}, kw["gel_scales"], kw["peak_forces_n"])
    assert np.mean([holds(d, 10.0**t) for d, t in zip(said, truth, strict=True) if d.state == "lower_bound"]) < 0.9
    assert p_rigid < P_RIGID_CHOICES[-1]
