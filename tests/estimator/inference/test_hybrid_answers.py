"""The hybrid's answer on a stand-in model (fast: no trained model, no torch): when auto takes the series
fit, the refusals a user reads (input range, calibration smoothing, depth binning), auto's fallback, the
widening for a rig outside the training range, the force band's peak force and the gel scale."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest
from support.hybrid_stand_in import SETTINGS, StandInPredictor, gaussian

from estimator.errors import ModelError
from estimator.estimate import Estimate
from estimator.inference import hybrid as hybrid_module
from estimator.inference.hybrid import RIG_WIDENING, AutoPolicy, HybridEstimator
from estimator.inference.inputs import REFERENCE_GEL_MODULUS_PA
from estimator.inference.sampling import SampledGrasp
from estimator.inference.window import InputRange

PROBS = gaussian(5.0, 0.2)  # an ok answer near 1e5 Pa
NO_FLOOR = (-math.inf, None)


def sampled_grasp(estimates=(), **fields) -> SampledGrasp:
    """A sampled grasp whose analytical fits are ``estimates`` (by default only a refusing series fit)."""
    fields.setdefault("force_n", np.array([1.0, 5.0, 10.0]))
    return SampledGrasp(estimates=tuple(estimates) or (Estimate.refuse("series", "-"),), **fields)


def answer(predictor=None, sampled=None, mode="model") -> Estimate:
    predictor = predictor or StandInPredictor(PROBS, NO_FLOOR)
    return HybridEstimator(predictor, settings=SETTINGS).estimate_sampled(sampled or sampled_grasp(), mode=mode)


def decades(est: Estimate) -> float:
    low, high = est.interval_pa
    return math.log10(high / low)


# --------------------------------------------------------------------------- when auto takes the series fit


def test_auto_takes_a_series_fit_exactly_at_its_interval_threshold():
    assert AutoPolicy(1.0).accepts(Estimate.ok("series", 3e4, 1e4, 1e5), frames=3)  # exactly 1 decade


def test_auto_does_not_take_a_series_fit_wider_than_its_threshold():
    assert not AutoPolicy(1.0).accepts(Estimate.ok("series", 3e4, 1e4, 10 ** 5.5), frames=3)  # 1.5 decades


def test_auto_takes_only_an_ok_series_fit_over_enough_distinct_frames():
    policy = AutoPolicy(10.0)
    assert not policy.accepts(Estimate.at_least("series", 1e5, "stiff"), frames=5)
    assert not policy.accepts(Estimate.ok("series", 3e4, 1e4, 1e5), frames=2)
    assert policy.accepts(Estimate.ok("series", 3e4, 1e4, 1e5), frames=3)


# --------------------------------------------------------------------------- refusals


def test_a_sensor_outside_the_models_input_range_gets_no_model_number(monkeypatch):
    monkeypatch.setattr(hybrid_module, "sampled_input_range", lambda _s, _v: InputRange(refusal="grid too coarse"))
    est = answer()
    assert est.state == "insufficient_data" and not est and est.e_pa is None
    assert "the model does not apply to this sensor: grid too coarse" in est.reason


def test_a_calibration_smoothing_the_model_never_saw_is_refused():
    sampled = sampled_grasp(measurements=SimpleNamespace(calibration_smoothing_px=2.0, segment=None))
    est = answer(sampled=sampled)  # the stand-in was trained on smoothing 0
    assert est.state == "insufficient_data" and not est and est.e_pa is None
    assert "does not apply to this calibration" in est.reason and "--smoothing-px 0" in est.reason


def test_auto_falls_back_past_refusing_fits_to_the_first_that_answers():
    sampled = sampled_grasp(estimates=(Estimate.refuse("series", "too few frames"), Estimate.ok("hertz", 2e5, 1e5, 4e5)),
                            measurements=SimpleNamespace(calibration_smoothing_px=2.0, segment=None))
    est = answer(sampled=sampled, mode="auto")
    assert est.state == "ok" and est.e_pa == pytest.approx(2e5)
    assert est.reason.startswith("hertz: the model does not apply to this calibration")


def test_a_model_trained_on_other_depth_binning_is_refused_at_construction():
    predictor = StandInPredictor(PROBS, NO_FLOOR)
    predictor.depth_binning += 1
    predictor.model_dir = "stand-in"
    with pytest.raises(ModelError, match="depth binned by"):
        HybridEstimator(predictor, settings=SETTINGS)


# --------------------------------------------------------------------------- the number and interval a user reads


def test_a_rig_outside_the_training_range_widens_the_interval_and_says_so():
    inside = StandInPredictor(PROBS, NO_FLOOR)
    inside.rig_range = {"finger_stiffness_n_per_m": [1e4, 1e6]}
    outside = StandInPredictor(PROBS, NO_FLOOR)
    outside.rig_range = {"finger_stiffness_n_per_m": [1e4, 2e4]}
    a = answer(inside, sampled_grasp(finger_stiffness_n_per_m=1e5))
    b = answer(outside, sampled_grasp(finger_stiffness_n_per_m=1e5))
    assert a.state == b.state == "ok" and b.e_pa == pytest.approx(a.e_pa)
    assert "outside the training range" in b.reason and "outside the training range" not in a.reason
    assert decades(b) == pytest.approx(RIG_WIDENING * decades(a), rel=0.05)


def test_the_force_band_is_chosen_by_the_grasps_peak_force():
    predictor = StandInPredictor(PROBS, NO_FLOOR)
    seen = []
    describe = predictor.describe

    def recording(probs, *, peak_force_n, **kwargs):
        seen.append(peak_force_n)
        return describe(probs, peak_force_n=peak_force_n, **kwargs)

    predictor.describe = recording
    answer(predictor, sampled_grasp(force_n=np.array([2.0, 12.0, 7.0])))
    assert seen == [12.0]


def test_the_answer_is_in_the_measuring_gels_moduli():
    reference = answer(sampled=sampled_grasp(gel_modulus_pa=REFERENCE_GEL_MODULUS_PA))
    stiffer = answer(sampled=sampled_grasp(gel_modulus_pa=2 * REFERENCE_GEL_MODULUS_PA))
    assert reference.state == stiffer.state == "ok"
    assert stiffer.e_pa == pytest.approx(2 * reference.e_pa, rel=1e-6)


def test_auto_says_the_model_answered():
    est = answer(mode="auto")  # the series fit refuses: the model answers
    assert est.method == "auto" and est.state == "ok" and est.reason.startswith("model: ")


def test_an_interval_ending_exactly_at_the_floor_is_said_to_be_floored_there():
    # Private: no stand-in distribution puts the interval's low end exactly on the floor as printed.
    from estimator.inference.hybrid import _floor_said

    said = SimpleNamespace(state="ok", e_pa=1e5, low_pa=6.66e4, high_pa=2e5)
    text = _floor_said(said, "series", 6.66e4, 0.01)
    assert "its distribution floored at the series lower bound 6.66e+04 Pa" in text
