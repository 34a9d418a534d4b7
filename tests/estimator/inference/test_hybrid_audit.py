"""Audit of the hybrid's answer on a stand-in model (fast: no trained model, no torch): ``auto``'s answer to
a grasp it cannot sample, its fallbacks and their reasons, the policy's range and default, the rig-range
check's tolerance, and what the reason says of the floor and of ``p_rigid`` at their boundaries."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest
from support.hybrid_stand_in import SETTINGS, SOFT_PA, StandInPredictor, gaussian, stand_in_answer

from estimator.errors import ModelError
from estimator.estimate import Estimate
from estimator.inference import hybrid as hybrid_module
from estimator.inference.distribution import describe_on_gel
from estimator.inference.hybrid import (
    DEFAULT_SERIES_INTERVAL_DECADES,
    RIG_RANGE_TOLERANCE,
    RIG_WIDENING,
    AutoPolicy,
    HybridEstimator,
    interval_decades,
    rig_notes,
)
from estimator.inference.inputs import REFERENCE_GEL_MODULUS_PA
from estimator.inference.sampling import SampledGrasp
from estimator.inference.window import COVERAGE_WIDENING

PROBS = gaussian(5.0, 0.2)  # an ok answer near 1e5 Pa
NO_FLOOR = (-math.inf, None)
UNSAMPLED = "no tactile frame within the loading phase"


def hybrid(predictor=None) -> HybridEstimator:
    predictor = predictor or StandInPredictor(PROBS, NO_FLOOR)
    predictor.variant.__dict__.update(size_px=(16, 22), image="depth", markers=False)  # what sampling asks of it
    return HybridEstimator(predictor, settings=SETTINGS)


def sampled_grasp(estimates=(), **fields) -> SampledGrasp:
    fields.setdefault("force_n", np.array([1.0, 5.0, 10.0]))
    return SampledGrasp(estimates=tuple(estimates) or (Estimate.refuse("series", "-"),), **fields)


# --------------------------------------------------------------------------- a grasp that cannot be sampled


@pytest.fixture
def unsampled(monkeypatch):
    """``stream(no_tactile, loading)``: a stream whose grasp cannot be sampled, its force and width giving
    the no_tactile estimate ``no_tactile`` and a loading phase or not; the no_tactile fits asked for are
    listed in ``asked``."""
    asked = []
    monkeypatch.setattr(hybrid_module, "sample_stream", lambda _stream, **_kw: SampledGrasp(reason=UNSAMPLED))

    def stream(no_tactile: Estimate, loading: bool):
        def fit(_measurements, method):
            asked.append(method)
            return no_tactile

        monkeypatch.setattr(hybrid_module, "estimate_measurements", fit)
        return SimpleNamespace(measurements=lambda tactile: None, segment=lambda: loading)

    stream.asked = asked
    return stream


def test_model_mode_refuses_an_unsampled_grasp_with_its_reason_alone(unsampled):
    said = hybrid().estimate_stream(unsampled(Estimate.ok("no_tactile", 4e5, 3e5, 5e5), True), mode="model")
    assert (said.method, said.state, said.reason) == ("hybrid", "insufficient_data", UNSAMPLED)
    assert unsampled.asked == [] and said.latency_s > 0


def test_auto_says_what_force_and_width_read_without_rendering_it(unsampled):
    said = hybrid().estimate_stream(unsampled(Estimate.ok("no_tactile", 4e5, 3e5, 5e5, "fit"), True), mode="auto")
    assert (said.method, said.state, said.e_pa) == ("auto", "insufficient_data", None)
    assert said.reason.startswith(f"no_tactile: no tactile sample ({UNSAMPLED}): force and width only; fit")
    assert said.reason.endswith("(it reads 4e+05 Pa)") and said.latency_s > 0


def test_auto_gives_the_force_and_widths_reason_when_they_give_no_loading_phase(unsampled):
    said = hybrid().estimate_stream(unsampled(Estimate.refuse("no_tactile", "no contact"), False), mode="auto")
    assert (said.method, said.state, said.reason) == ("auto", "insufficient_data", "no contact")


def test_auto_names_a_refusing_force_and_width_fit_when_only_the_frames_are_missing(unsampled):
    said = hybrid().estimate_stream(unsampled(Estimate.refuse("no_tactile", "too few points"), True), mode="auto")
    assert (said.method, said.state) == ("auto", "insufficient_data")
    assert said.reason == f"no_tactile: no tactile sample ({UNSAMPLED}): force and width only; too few points"


def test_auto_with_no_loading_phase_still_says_a_force_and_width_reading(unsampled):
    # A reading (ok) without a loading phase: not a contact failure, so not the force and width's refusal.
    said = hybrid().estimate_stream(unsampled(Estimate.ok("no_tactile", 4e5, 3e5, 5e5, "fit"), False), mode="auto")
    assert said.state == "insufficient_data" and said.reason.startswith("no_tactile: no tactile sample")


def test_auto_says_the_sampling_failure_once(unsampled):
    said = hybrid().estimate_stream(unsampled(Estimate.refuse("no_tactile", f"also {UNSAMPLED}"), True), mode="auto")
    assert said.reason.count(UNSAMPLED) == 1 and "no tactile sample: force and width only" in said.reason


def test_an_unsampled_grasp_in_auto_mode_is_autos_refusal():
    said = hybrid().estimate_sampled(SampledGrasp(reason=UNSAMPLED), mode="auto")
    assert (said.method, said.state, said.reason) == ("auto", "insufficient_data", UNSAMPLED)


@pytest.mark.parametrize("mode", ["cnn", "", "AUTO"])
def test_an_unknown_mode_is_refused(mode):
    with pytest.raises(ModelError, match="mode"):
        hybrid().estimate_sampled(sampled_grasp(), mode=mode)


# --------------------------------------------------------------------------- auto's policy and fallbacks


def test_model_mode_never_answers_with_the_series_fit():
    narrow = Estimate.ok("series", 2e6, 1.9e6, 2.1e6, "narrow")
    said = hybrid().estimate_sampled(sampled_grasp((narrow,)), mode="model")
    assert said.method == "hybrid" and said.e_pa != 2e6 and said.reason.startswith("stand-in model")


def test_auto_counts_distinct_frames_not_samples_before_taking_the_series_fit():
    narrow = Estimate.ok("series", 2e6, 1.9e6, 2.1e6, "narrow")
    repeated = sampled_grasp((narrow,), force_n=np.array([1.2, 1.2, 25.0]))  # a short loading phase: 2 frames
    assert hybrid().estimate_sampled(repeated, mode="auto").reason.startswith("model: ")
    distinct = sampled_grasp((narrow,), force_n=np.array([1.2, 8.0, 25.0]))
    assert hybrid().estimate_sampled(distinct, mode="auto").reason.startswith("series: series interval")


def test_a_policy_given_overrides_the_models():
    narrow = Estimate.ok("series", 2e6, 1.9e6, 2.1e6, "narrow")
    never = HybridEstimator(hybrid().predictor, settings=SETTINGS, policy=AutoPolicy(0.0))
    assert never.policy == AutoPolicy(0.0)
    assert never.estimate_sampled(sampled_grasp((narrow,)), mode="auto").reason.startswith("model: ")


def test_the_auto_policy_comes_from_the_metadata_else_its_default():
    assert DEFAULT_SERIES_INTERVAL_DECADES == 0.5  # as documented
    assert AutoPolicy.from_metadata({}) == AutoPolicy(0.5)
    assert AutoPolicy.from_metadata({"auto": {"max_series_interval_decades": 0.2}}) == AutoPolicy(0.2)
    assert hybrid().policy == AutoPolicy(0.5)  # the stand-in's metadata names none


@pytest.mark.parametrize("decades", [math.inf, math.nan, -0.1])
def test_an_auto_policy_needs_a_finite_threshold(decades):
    with pytest.raises(ModelError, match="max_series_interval_decades"):
        AutoPolicy(decades)


def test_auto_with_every_fit_refusing_says_so():
    predictor = StandInPredictor(PROBS, NO_FLOOR)
    predictor.calibration_smoothing_px = (1.0,)  # the model does not apply: auto falls back
    said = hybrid(predictor).estimate_sampled(
        sampled_grasp(measurements=SimpleNamespace(calibration_smoothing_px=0.0, segment=None)), mode="auto")
    assert said.state == "insufficient_data" and said.method == "auto"
    assert said.reason.endswith("; and every analytical method refuses")


def _without_the_model(fits) -> Estimate:
    """auto's answer for a grasp whose analytical fits are ``fits`` when the model does not apply."""
    predictor = StandInPredictor(PROBS, NO_FLOOR)
    predictor.calibration_smoothing_px = (1.0,)
    return hybrid(predictor).estimate_sampled(
        sampled_grasp(fits, measurements=SimpleNamespace(calibration_smoothing_px=0.0, segment=None)), mode="auto")


def test_autos_fallback_takes_series_then_hertz_then_elastic():
    fits = {m: Estimate.ok(m, e, e / 2, e * 2, m) for m, e in (("elastic", 3e5), ("hertz", 2e5), ("series", 1e5))}
    assert _without_the_model(tuple(fits.values())).reason.startswith("series: ")
    assert _without_the_model((fits["elastic"], fits["hertz"])).reason.startswith("hertz: ")
    assert _without_the_model((fits["elastic"],)).reason.startswith("elastic: ")


def test_autos_fallback_to_force_and_width_alone_says_their_reading_in_a_refusal():
    said = _without_the_model((Estimate.refuse("series", "-"), Estimate.ok("no_tactile", 4e5, 3e5, 5e5, "fw")))
    assert (said.method, said.state, said.e_pa) == ("auto", "insufficient_data", None)
    assert said.reason.startswith("no_tactile: the model does not apply") and said.reason.endswith("(it reads 4e+05 Pa)")


def test_autos_fallback_keeps_the_fits_own_reason():
    predictor = StandInPredictor(PROBS, NO_FLOOR)
    predictor.calibration_smoothing_px = (1.0,)
    fits = (Estimate.refuse("series", "-"), Estimate.ok("hertz", 2e5, 1e5, 4e5, "hertz's own words"))
    said = hybrid(predictor).estimate_sampled(
        sampled_grasp(fits, measurements=SimpleNamespace(calibration_smoothing_px=0.0, segment=None)), mode="auto")
    assert said.state == "ok" and said.reason.startswith("hertz: ") and said.reason.endswith("; hertz's own words")


def test_model_mode_refuses_in_the_models_own_name_when_it_does_not_apply():
    predictor = StandInPredictor(PROBS, NO_FLOOR)
    predictor.calibration_smoothing_px = (1.0,)
    fits = (Estimate.ok("hertz", 2e5, 1e5, 4e5, "hertz"),)
    said = hybrid(predictor).estimate_sampled(
        sampled_grasp(fits, measurements=SimpleNamespace(calibration_smoothing_px=0.0, segment=None)), mode="model")
    assert (said.method, said.state) == ("hybrid", "insufficient_data")
    assert said.reason.startswith("the model does not apply to this calibration")


def test_a_model_trained_on_several_smoothings_reads_any_of_them():
    predictor = StandInPredictor(PROBS, NO_FLOOR)
    predictor.calibration_smoothing_px = (0.0, 2.0)
    said = hybrid(predictor).estimate_sampled(
        sampled_grasp(measurements=SimpleNamespace(calibration_smoothing_px=2.0, segment=None)))
    assert said.state == "ok" and "smooths" not in said.reason


# --------------------------------------------------------------------------- the rig range


def test_a_rig_outside_widens_as_much_as_a_pad_covering_little_of_the_window():
    assert RIG_WIDENING == COVERAGE_WIDENING == 1.5  # as documented


def test_a_rig_outside_says_its_interval_was_widened_and_not_validated():
    predictor = StandInPredictor(PROBS, NO_FLOOR)
    predictor.rig_range = {"finger_stiffness_n_per_m": [1e4, 2e4]}
    said = hybrid(predictor).estimate_sampled(sampled_grasp(finger_stiffness_n_per_m=1e5))
    assert said.state == "ok" and f"widened {RIG_WIDENING:g} times" in said.reason
    assert "its coverage there is not validated" in said.reason


def test_the_reason_names_what_the_segmentation_flagged():
    segment = SimpleNamespace(describe=lambda: "force saturates at 30 N")
    said = hybrid().estimate_sampled(
        sampled_grasp(measurements=SimpleNamespace(calibration_smoothing_px=None, segment=segment)))
    assert said.state == "ok" and said.reason.endswith("; force saturates at 30 N")


def test_a_quantity_outside_is_named_after_one_the_grasp_does_not_record():
    rig = SimpleNamespace(gel_modulus_pa=None, gel_thickness_m=6e-3, finger_stiffness_n_per_m=5e6)
    notes = rig_notes(rig, {"gel_modulus_pa": [1e5, 4e5], "gel_thickness_m": [2e-3, 4e-3],
                            "finger_stiffness_n_per_m": [1e4, 1e6]})
    assert len(notes) == 2 and notes[0].startswith("gel thickness 6 mm") and notes[1].startswith("finger stiffness")


@pytest.mark.parametrize(("factor", "outside"), [(1.005, False), (0.995, False), (1.02, True), (0.98, True),
                                                 (1 + RIG_RANGE_TOLERANCE, False), (1 - RIG_RANGE_TOLERANCE, False)])
def test_the_rig_range_gives_or_takes_one_percent(factor, outside):
    assert RIG_RANGE_TOLERANCE == 0.01  # as documented
    bounds = [2e-3, 4e-3]
    value = (bounds[1] if factor > 1 else bounds[0]) * factor  # the ends given or taken: inside
    rig = SimpleNamespace(gel_modulus_pa=None, gel_thickness_m=value, finger_stiffness_n_per_m=None)
    assert bool(rig_notes(rig, {"gel_thickness_m": bounds})) is outside


# --------------------------------------------------------------------------- what the reason says


def test_a_probability_above_the_limit_equal_to_p_rigid_is_said_to_reach_it():
    probs = 0.2 * gaussian(5.0, 0.2) + 0.8 * gaussian(8.5, 0.2)
    p_above = describe_on_gel(probs, scale=1.0, limit_pa=SETTINGS.resolution_limit_pa, soft_pa=SOFT_PA, p_rigid=0.5,
                              gel_scale=1.0).p_above_limit
    said = stand_in_answer(probs, NO_FLOOR, p_rigid=p_above)
    assert said.state == "lower_bound"
    assert f"P(E >= the sensor's resolution limit) = {p_above:.2f} >= {p_above:g}" in said.reason


def test_the_floor_is_said_in_the_measuring_gels_moduli():
    floor_pa = 3e4  # on the reference gel
    said = stand_in_answer(gaussian(5.5, 0.15), (math.log10(floor_pa), "series"),
                           gel_modulus_pa=2 * REFERENCE_GEL_MODULUS_PA)
    assert said.state == "ok" and said.interval_pa[0] > 2 * floor_pa
    assert "its distribution floored at the series lower bound 6e+04 Pa" in said.reason


def test_an_answer_exactly_at_the_floor_is_not_said_to_lie_below_it():
    said = SimpleNamespace(state="ok", e_pa=1e5, low_pa=5e4, high_pa=2e5)
    text = hybrid_module._floor_said(said, "series", 1e5, 0.01)
    assert "lies below that bound" not in text and "still reaches below that bound (to 5e+04 Pa)" in text


def test_a_floor_that_prints_above_the_low_end_is_not_said_to_floor_it():
    said = SimpleNamespace(state="ok", e_pa=1e5, low_pa=6.666e4, high_pa=2e5)
    text = hybrid_module._floor_said(said, "series", 6.6651e4, 0.01)  # printed 6.67e+04, above 6.666e4
    assert "floored at" not in text and "still reaches below that bound" in text


def test_an_upper_bound_above_the_floor_says_its_interval_is_open_below():
    said = SimpleNamespace(state="upper_bound", e_pa=3.5e3, low_pa=None, high_pa=3.5e3)
    text = hybrid_module._floor_said(said, "series", 2e3, 0.01)
    assert text.endswith("; the interval is open below, as an upper bound is")


def test_an_open_interval_is_infinitely_wide():
    assert interval_decades(Estimate.at_least("series", 1e5, "stiff")) == math.inf
    assert interval_decades(Estimate.at_most("series", 1e5, "soft")) == math.inf
    assert interval_decades(Estimate.ok("series", 2e5, 1e5, 1e6)) == pytest.approx(1.0)
