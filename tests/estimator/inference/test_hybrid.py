"""Hybrid, CNN and auto estimates keep the Estimate invariants on hard inputs."""

from __future__ import annotations

import dataclasses
import json
import math
import shutil

import numpy as np
import pytest
import torch

from estimator.estimate import Estimate
from estimator.inference.distribution import quantile
from estimator.inference.hybrid import RIG_WIDENING, AutoPolicy, HybridEstimator, rig_notes
from estimator.inference.infer import CompliancePredictor
from estimator.inference.inputs import encode, gel_scale
from estimator.inference.sampling import SampledGrasp, decoded, sample_grasp
from estimator.perception import load_calibration
from estimator.training.export import export_onnx
from estimator.training.model import ComplianceNet
from teleop.record import read_record
from teleop.settings import load_settings

pytestmark = pytest.mark.slow  # every test needs the trained model fixture

SETTINGS = load_settings()


def _valid(estimate: Estimate) -> None:
    for value in (estimate.e_pa, *estimate.interval_pa):
        assert value is None or (math.isfinite(value) and value > 0)
    if estimate.state == "insufficient_data":
        assert estimate.reason and estimate.e_pa is None


def _sampled(synthetic, name: str, estimates: tuple[Estimate, ...] | None = None) -> SampledGrasp:
    s = synthetic.sample(name, 0, 0, rng=np.random.default_rng(0))
    return SampledGrasp(estimates=s.estimates if estimates is None else estimates, force_n=s.force_n,
                        width_m=s.width_m, depth_m=s.depth_m)


REFUSALS = tuple(Estimate.refuse(m, "nothing resolved") for m in ("no_tactile", "elastic", "hertz", "series"))
BOUNDS = (Estimate.at_least("series", 3e8, "stiffer than resolved"), Estimate.at_least("hertz", 1e9, "rigid"),
          Estimate.at_most("elastic", 1e4, "soft"), Estimate.refuse("no_tactile", "none"))


@pytest.mark.parametrize("estimates", [REFUSALS, BOUNDS], ids=["all_refused", "bounds"])
@pytest.mark.parametrize("mode", ["model", "auto"])
def test_hard_analytical_inputs_still_give_a_valid_model_estimate(trained_model, synthetic, estimates, mode):
    hybrid = HybridEstimator(CompliancePredictor(trained_model), settings=SETTINGS)
    result = hybrid.estimate_sampled(_sampled(synthetic, "metal_a", estimates), mode=mode)
    _valid(result)
    assert result.method == ("hybrid" if mode == "model" else "auto")
    if result.state == "lower_bound":  # a metal: at least the sensor's resolution limit, no more said
        assert result.interval_pa == (SETTINGS.resolution_limit_pa, None)
        assert result.e_pa == SETTINGS.resolution_limit_pa and "resolution limit" in result.reason
    else:
        assert result.state == "ok"
        low, high = result.interval_pa
        assert low <= result.e_pa <= high <= 1e12


def test_a_rig_outside_the_trained_ones_widens_the_interval_and_says_why(trained_model, synthetic, tmp_path):
    inside, outside = tmp_path / "inside", tmp_path / "outside"
    for dest, gels in ((inside, [2e5, 3e5]), (outside, [3e5, 4e5])):
        shutil.copytree(trained_model, dest)
        meta = json.loads((dest / "metadata.json").read_text())
        meta["data"]["rig_range"] = {"gel_modulus_pa": gels, "gel_thickness_m": [2e-3, 4e-3]}
        (dest / "metadata.json").write_text(json.dumps(meta))
    sampled = dataclasses.replace(_sampled(synthetic, "rubber_a"), gel_modulus_pa=2.5e5, gel_thickness_m=3e-3)
    said = {name: HybridEstimator(CompliancePredictor(d), settings=SETTINGS).estimate_sampled(sampled)
            for name, d in (("inside", inside), ("outside", outside))}
    assert said["inside"].state == said["outside"].state == "ok" and said["inside"].e_pa == said["outside"].e_pa
    assert "outside the training range" not in said["inside"].reason
    assert "gel modulus 250 kPa outside the 300-400 kPa trained on" in said["outside"].reason
    assert f"widened {RIG_WIDENING:g} times" in said["outside"].reason
    widths = {k: math.log10(e.interval_pa[1] / e.interval_pa[0]) for k, e in said.items()}
    assert widths["outside"] > widths["inside"]  # (clipped at the scale's ends: not always the full factor)
    assert rig_notes(sampled, {}) == ()  # a model that records no rig range says nothing


def test_the_interval_is_that_of_the_grasps_force_band_and_says_so(trained_model, synthetic):
    sampled = _sampled(synthetic, "rubber_a")
    peak_n = float(np.max(sampled.force_n))
    predictor = CompliancePredictor(trained_model)
    said = {}
    for name, edge_n in (("light", 2.0 * peak_n), ("firm", 0.5 * peak_n)):
        predictor.metadata = dataclasses.replace(predictor.metadata, force_band_edges_n=(edge_n,),
                                                 p_rigids=(0.9, 0.9), interval_scales=(0.4, 0.2))
        said[name] = HybridEstimator(predictor, settings=SETTINGS).estimate_sampled(sampled)
    assert said["light"].state == said["firm"].state == "ok"
    assert all(e.interval_pa[0] <= e.e_pa <= e.interval_pa[1] for e in said.values())
    # Below the median (above it the interval may open at the censored end) the half-width is the band's.
    median = float(quantile(predictor.predict_distribution([sampled])[0], 0.5)[0]) - math.log10(
        gel_scale(sampled.gel_modulus_pa))
    below = {k: median - math.log10(e.interval_pa[0]) for k, e in said.items()}
    assert below["light"] == pytest.approx(2.0 * below["firm"], rel=1e-6)
    assert f"validation objects' grasps below {2.0 * peak_n:g} N" in said["light"].reason
    assert f"validation objects' grasps from {0.5 * peak_n:g} N" in said["firm"].reason


def test_an_unsampled_grasp_is_refused_with_its_reason(trained_model):
    hybrid = HybridEstimator(CompliancePredictor(trained_model), settings=SETTINGS)
    for mode in ("model", "auto"):
        result = hybrid.estimate_sampled(SampledGrasp(reason="no tactile frame within the loading phase"), mode=mode)
        assert result.state == "insufficient_data" and "no tactile frame" in result.reason and not result


def test_a_non_finite_model_output_is_never_returned(trained_model, synthetic, caplog):
    hybrid = HybridEstimator(CompliancePredictor(trained_model), settings=SETTINGS, policy=AutoPolicy(0.0))
    broken = dataclasses.replace(_sampled(synthetic, "rubber_a"), depth_m=np.full((3, 16, 22), np.nan, np.float32))
    with caplog.at_level("WARNING", logger="estimator.inference.hybrid"):
        refused = hybrid.estimate_sampled(broken, mode="model")
    assert refused.state == "insufficient_data" and "not finite" in refused.reason
    assert "the model gives no estimate" in caplog.text  # a served model failing on live grasps is heard of
    fallback = hybrid.estimate_sampled(broken, mode="auto")  # the series estimate, relabelled
    assert fallback.method == "auto" and fallback.state == "ok" and fallback.reason.startswith("series: the model")
    all_refused = dataclasses.replace(broken, estimates=REFUSALS)
    assert hybrid.estimate_sampled(all_refused, mode="auto").state == "insufficient_data"


@pytest.mark.parametrize("end", [-1, 0], ids=["saturated_high", "saturated_low"])
def test_a_saturated_model_gives_the_bounds_at_the_ends(trained_model, synthetic, tmp_path, end):
    dest = tmp_path / "model"
    shutil.copytree(trained_model, dest)
    predictor = CompliancePredictor(trained_model)
    model = ComplianceNet(predictor.variant).eval()
    with torch.no_grad():  # all the mass in the first or the last bin of the scale
        model.estimation[1].weight.zero_()
        model.estimation[1].bias.zero_()
        model.estimation[1].bias[end] = 60.0
    sample = _sampled(synthetic, "foam_a")
    export_onnx(model, dest / "model.onnx", example=encode(predictor.variant, [sample, sample]))
    result = HybridEstimator(CompliancePredictor(dest), settings=SETTINGS).estimate_sampled(sample)
    _valid(result)
    if end == -1:  # a terapascal: no more than "at least the resolution limit"
        assert result.state == "lower_bound" and result.e_pa == SETTINGS.resolution_limit_pa
    else:  # a kilopascal: no less than "at most the softest training label"
        assert result.state == "upper_bound" and result.e_pa == predictor.metadata.soft_pa


def test_auto_takes_a_narrow_series_fit_and_skips_the_model(trained_model, synthetic):
    predictor = CompliancePredictor(trained_model)
    narrow = Estimate.ok("series", 2e6, 1.5e6, 2.5e6, "narrow")
    wide = Estimate.ok("series", 2e6, 2e4, 2e8, "four decades")
    hybrid = HybridEstimator(predictor, settings=SETTINGS, policy=AutoPolicy(0.5))
    taken = hybrid.estimate_sampled(_sampled(synthetic, "rubber_a", (narrow,)), mode="auto")
    assert taken.method == "auto" and taken.e_pa == 2e6 and taken.reason.startswith("series: series interval 0.22")
    model = hybrid.estimate_sampled(_sampled(synthetic, "rubber_a", (wide,)), mode="auto")
    assert model.reason.startswith("model:") and model.e_pa != 2e6
    never = HybridEstimator(predictor, settings=SETTINGS, policy=AutoPolicy(0.0))
    assert never.estimate_sampled(_sampled(synthetic, "rubber_a", (narrow,)), mode="auto").reason.startswith("model:")
    # A stiff object's grasp: one frame repeated and the peak frame. The series fit's narrow interval is its
    # resolution alone (no scatter to show the model's miss), so the model answers.
    short = dataclasses.replace(_sampled(synthetic, "rubber_a", (narrow,)), force_n=np.array([1.2, 1.2, 25.0]))
    assert hybrid.estimate_sampled(short, mode="auto").reason.startswith("model:")
    chosen = predictor.metadata.raw["auto"]["max_series_interval_decades"]
    assert HybridEstimator(predictor, settings=SETTINGS).policy == AutoPolicy(chosen)  # from training


def test_records_end_to_end(trained_model, sim_grasps):
    records, calibration = sim_grasps
    hybrid = HybridEstimator(CompliancePredictor(trained_model), settings=SETTINGS, calibration=calibration)
    for path in sorted(records.glob("*.grasp")):
        record = read_record(path)
        for mode in ("model", "auto"):
            result = hybrid.estimate(record, mode=mode)
            _valid(result)
            assert result.latency_s > 0
        sampled = sample_grasp(record, settings=SETTINGS, calibration=calibration, n_frames=3, size_px=(16, 22))
        again = sample_grasp(decoded(record), settings=SETTINGS, calibration=calibration, n_frames=3,
                             size_px=(16, 22))  # frames decoded up front (as the bench times it): same result
        assert again.reason == sampled.reason
        assert [e.with_latency(0) for e in again.estimates] == [e.with_latency(0) for e in sampled.estimates]
        if sampled:  # the model saw exactly what the dataset builder stores
            assert sampled.depth_m.shape == (3, 16, 22) and len(sampled.estimates) == 4
            np.testing.assert_array_equal(again.depth_m, sampled.depth_m)


def test_the_models_reason_names_what_the_segmentation_flagged_as_the_fits_do(trained_model, sim_grasps):
    records, calibration = sim_grasps
    hybrid = HybridEstimator(CompliancePredictor(trained_model), settings=SETTINGS, calibration=calibration)
    record = read_record(sorted(records.glob("*.grasp"))[0])
    force = record.force_n
    clip_n = 0.5 * float(force.value.max())  # a load cell saturating halfway up
    saturated = dataclasses.replace(record, force_n=dataclasses.replace(force, value=np.minimum(force.value, clip_n)))
    said = hybrid.estimate(saturated, mode="model")
    assert said.state != "insufficient_data" and f"force saturates at {clip_n:.4g} N" in said.reason
    series = next(e for e in sample_grasp(saturated, settings=SETTINGS, calibration=calibration, n_frames=3,
                                          size_px=(16, 22)).estimates if e.method == "series")
    assert "force saturates" in series.reason


def test_depth_from_a_calibration_smoothed_otherwise_is_refused_with_the_fix(trained_model, sim_grasps, tmp_path):
    records, cal_path = sim_grasps
    smoothed = dataclasses.replace(load_calibration(cal_path), smoothing_px=2.0)
    record = read_record(sorted(records.glob("*.grasp"))[0])
    predictor = CompliancePredictor(trained_model)
    assert predictor.calibration_smoothing_px == (0.0,)  # trained on unsmoothed calibrations
    hybrid = HybridEstimator(predictor, settings=SETTINGS, calibration=smoothed, policy=AutoPolicy(0.0))
    refused = hybrid.estimate(record)
    assert refused.state == "insufficient_data"
    assert "smooths the colours by 2 px" in refused.reason and "--smoothing-px 0" in refused.reason
    auto = hybrid.estimate(record, mode="auto")  # answered by an analytical fit instead
    assert auto.state != "insufficient_data" and "the model does not apply to this calibration" in auto.reason
    # A model trained on calibrations smoothing by 2 px reads it.
    shutil.copytree(trained_model, tmp_path / "smoothed")
    meta = json.loads((tmp_path / "smoothed" / "metadata.json").read_text())
    meta["data"]["calibration_smoothing_px"] = [2.0]
    (tmp_path / "smoothed" / "metadata.json").write_text(json.dumps(meta))
    reads = HybridEstimator(CompliancePredictor(tmp_path / "smoothed"), settings=SETTINGS, calibration=smoothed)
    assert "smooths the colours" not in reads.estimate(record).reason
