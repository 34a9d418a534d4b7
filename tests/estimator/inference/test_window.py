"""The model reads a fixed gel window in millimetres, whatever sensor measured the grasp; grasps
outside what it was trained on widen its interval or are refused, with the reason."""

from __future__ import annotations

import dataclasses
import json
import math
import shutil
from types import SimpleNamespace

import cv2
import numpy as np
import pytest

from estimator.errors import EstimatorError, ModelError
from estimator.inference.inputs import Variant, default_window_m, reduce_images
from estimator.inference.sampling import SampledGrasp, sampled_input_range
from estimator.inference.window import (
    COVERAGE_WIDENING,
    EDGE_WIDENING,
    MAX_PITCH_RATIO,
    MIN_COVERAGE,
    input_range,
    window_bounds,
    window_images,
)
from estimator.perception.grid import DepthGrid, depth_grid
from teleop.settings import SensorSettings, load_settings

WEDGE = SensorSettings()  # the simulated Wedge the shipped models were trained on: 250 x 350 px at 1/11 mm
SIZE = (64, 88)


def _sensor(rows: int, cols: int, pitch_m: float) -> SensorSettings:
    """A flat (unwarped) sensor of ``rows`` x ``cols`` px at ``pitch_m``."""
    return SensorSettings(model="mini", raw_width_px=cols, raw_height_px=rows, warped_width_px=cols,
                          warped_height_px=rows, crop_px=0, pixel_pitch_m=pitch_m)


R15 = _sensor(480, 640, 0.0295e-3)  # a GelSight R1.5: 14.16 x 18.88 mm, smaller than the Wedge's pad
LARGE = _sensor(600, 800, 0.05e-3)  # 30 x 40 mm, larger than the Wedge's pad
COARSE = _sensor(40, 56, 0.6e-3)  # 24 x 33.6 mm at 0.6 mm: coarser than the model's 0.36 mm input pitch


def _sphere(grid: DepthGrid, *, radius_m: float = 3e-3, peak_m: float = 0.5e-3,
            offset_m: tuple[float, float] = (1.5e-3, -2.0e-3)) -> np.ndarray:
    """(1, H, W) float32 depth of a spherical cap of contact radius ``radius_m`` centred ``offset_m``
    (down, right) from the pad's centre, on ``grid``'s pixels."""
    rows, cols = grid.image_shape
    pitch = grid.pixel_pitch_m
    y = (np.arange(rows) + 0.5) * pitch - rows * pitch / 2 - offset_m[0]
    x = (np.arange(cols) + 0.5) * pitch - cols * pitch / 2 - offset_m[1]
    r2 = y[:, None] ** 2 + x[None, :] ** 2
    return (peak_m * np.clip(1.0 - r2 / radius_m**2, 0.0, None)).astype(np.float32)[None]


def _contact(image: np.ndarray, threshold_m: float) -> tuple[float, np.ndarray]:
    """Equivalent radius (window px) and centroid (row, col; window px) of ``image >= threshold_m``."""
    mask = image >= threshold_m
    rows, cols = np.nonzero(mask)
    return math.sqrt(mask.sum() / math.pi), np.array([rows.mean(), cols.mean()])


# --------------------------------------------------------------------------- resampling


@pytest.mark.parametrize(("binning", "pitch_m"), [(2, WEDGE.pixel_pitch_m), (1, WEDGE.pixel_pitch_m), (2, 9.0909e-5)],
                         ids=["binned", "full_grid", "settings_pitch"])
def test_on_the_wedge_the_window_is_the_whole_grid_and_the_inputs_are_as_before(binning, pitch_m):
    grid = depth_grid(SensorSettings(pixel_pitch_m=pitch_m), binning)
    rng = np.random.default_rng(binning)
    depth = (_sphere(grid) + rng.normal(0.0, 2e-5, (3, *grid.image_shape))).astype(np.float32)
    colour = rng.normal(0.0, 10.0, (3, *grid.image_shape, 3)).astype(np.float32)
    window = default_window_m()
    assert window == pytest.approx((250 / 11 * 1e-3, 350 / 11 * 1e-3))
    assert window_bounds(grid.image_shape, grid.pixel_pitch_m, window) == ((0, grid.image_shape[0]),
                                                                           (0, grid.image_shape[1]))
    for images in (depth, colour):
        assert window_images(images, grid.pixel_pitch_m, window) is images
        before = np.stack([cv2.resize(i, SIZE[::-1], interpolation=cv2.INTER_AREA) for i in images])
        np.testing.assert_array_equal(reduce_images(images, SIZE, pitch_m=grid.pixel_pitch_m, window_m=window),
                                      before)
        np.testing.assert_array_equal(reduce_images(images, SIZE), before)


@pytest.mark.parametrize("grid", [depth_grid(R15, 1), depth_grid(R15, 2), depth_grid(LARGE, 1)], ids=["r15", "r15_binned", "larger_pad"])
def test_a_sphere_contact_has_its_physical_size_and_place_in_the_window_on_any_sensor(grid):
    window = default_window_m()
    pitch = np.array(window) / SIZE  # the model's input pitch (rows, cols), about 0.36 mm
    wedge = depth_grid(WEDGE, 2)
    on_wedge = reduce_images(_sphere(wedge), SIZE, pitch_m=wedge.pixel_pitch_m, window_m=window)[0]
    on_other = reduce_images(_sphere(grid), SIZE, pitch_m=grid.pixel_pitch_m, window_m=window)[0]
    threshold = 0.25e-3  # half the peak: the cap of radius a / sqrt(2) = 2.12 mm, about 6 window px
    radius_wedge, centre_wedge = _contact(on_wedge, threshold)
    radius_other, centre_other = _contact(on_other, threshold)
    assert abs(radius_other - radius_wedge) <= 1.0
    assert np.all(np.abs(centre_other - centre_wedge) <= 1.0)
    # ... and that is the contact's physical radius and place (the window centred on the pad's centre).
    expected_px = 3e-3 / math.sqrt(2) / math.sqrt(pitch.prod())
    assert abs(radius_other - expected_px) <= 1.0
    expected_centre = (np.array(SIZE) - 1) / 2 + np.array([1.5e-3, -2.0e-3]) / pitch
    assert np.all(np.abs(centre_other - expected_centre) <= 1.0)
    assert on_other.max() == pytest.approx(0.5e-3, rel=0.05)


def test_a_larger_pad_is_cut_about_its_centre_and_a_smaller_one_padded_with_untouched_gel():
    window = default_window_m()
    (r0, r1), (c0, c1) = window_bounds(LARGE.image_shape, LARGE.pixel_pitch_m, window)
    assert (r1 - r0, c1 - c0) == (455, 636) and (r0, c0) == (72, 82)  # 22.75 x 31.8 mm about the centre
    (r0, r1), (c0, c1) = window_bounds(R15.image_shape, R15.pixel_pitch_m, window)
    assert (r1 - r0, c1 - c0) == (770, 1079) and r0 < 0 < 480 < r1 and c0 < 0 < 640 < c1
    ones = np.ones((1, *R15.image_shape), np.float32)
    windowed = window_images(ones, R15.pixel_pitch_m, window)
    assert windowed.shape == (1, 770, 1079) and windowed.sum() == ones.sum()
    assert windowed[0, -r0:-r0 + 480, -c0:-c0 + 640].min() == 1.0  # the pad, in the middle
    coverage = input_range(window, SIZE, pitch_m=R15.pixel_pitch_m, grid_shape=R15.image_shape).coverage
    reduced = reduce_images(ones, SIZE, pitch_m=R15.pixel_pitch_m, window_m=window)
    assert coverage == pytest.approx(480 * 640 / (770 * 1079)) and reduced.mean() == pytest.approx(coverage, rel=1e-4)
    with pytest.raises(ModelError, match="pixel pitch"):
        reduce_images(ones, SIZE, window_m=window)


@pytest.mark.parametrize("pitch_m", [0.0, -1e-4, math.nan, math.inf])
def test_a_pitch_that_is_not_a_positive_length_is_refused(pitch_m):
    with pytest.raises(ModelError, match="pixel pitch"):
        window_images(np.zeros((1, 8, 8)), pitch_m, (8e-4, 8e-4))


# --------------------------------------------------------------------------- range checks


def test_the_training_sensor_is_in_range_even_with_a_contact_at_its_edge():
    grid = depth_grid(WEDGE, 2)
    for touches in (False, True):  # a contact cut by the pad's edge is what the model was trained on
        fit = input_range(default_window_m(), SIZE, pitch_m=grid.pixel_pitch_m, grid_shape=grid.image_shape,
                          touches_edge=touches)
        assert fit and fit.coverage == 1.0 and fit.widen == 1.0 and not fit.reasons
        assert fit.pitch_ratio == pytest.approx(grid.pixel_pitch_m / (default_window_m()[0] / SIZE[0]))
    big = input_range(default_window_m(), SIZE, pitch_m=LARGE.pixel_pitch_m, grid_shape=LARGE.image_shape,
                      touches_edge=True)  # the pad's edge lies outside the window
    assert big and big.coverage == 1.0 and big.widen == 1.0


def test_a_pad_covering_little_of_the_window_widens_the_interval_and_says_why():
    fit = input_range(default_window_m(), SIZE, pitch_m=R15.pixel_pitch_m, grid_shape=R15.image_shape)
    assert fit and fit.coverage == pytest.approx(0.37, abs=0.01)
    assert fit.widen == COVERAGE_WIDENING and len(fit.notes) == 1
    assert "14.16 x 18.88 mm pad covers 37% of the model's 22.73 x 31.82 mm window" in fit.notes[0]
    edge = input_range(default_window_m(), SIZE, pitch_m=R15.pixel_pitch_m, grid_shape=R15.image_shape,
                       touches_edge=True)
    assert edge.widen == COVERAGE_WIDENING * EDGE_WIDENING and "contact reaches the edge" in edge.notes[1]
    # A pad a little smaller than the window (over 80 % of it): only a contact cut off by its edge widens.
    near = _sensor(230, 330, WEDGE.pixel_pitch_m)
    for touches, widen in ((False, 1.0), (True, EDGE_WIDENING)):
        fit = input_range(default_window_m(), SIZE, pitch_m=near.pixel_pitch_m, grid_shape=near.image_shape,
                          touches_edge=touches)
        assert fit and fit.coverage > 0.8 and fit.widen == widen and len(fit.notes) == int(touches)


def test_a_pad_covering_under_the_minimum_share_widens_and_one_at_it_does_not():
    window, size = (10e-3, 10e-3), (100, 100)  # input pitch 0.1 mm
    low = input_range(window, size, pitch_m=1e-4, grid_shape=(70, 100))  # covers 70 %
    assert low and low.coverage == pytest.approx(0.7) and low.coverage < MIN_COVERAGE
    assert low.widen == COVERAGE_WIDENING and any("covers 70%" in n for n in low.notes)
    at = input_range(window, size, pitch_m=1e-4, grid_shape=(80, 100))  # covers 80 %, the minimum
    assert at.coverage == pytest.approx(MIN_COVERAGE) and at.widen == 1.0 and not at.notes


def test_a_grid_much_coarser_than_the_input_pitch_is_refused_naming_the_pitch():
    fit = input_range(default_window_m(), SIZE, pitch_m=COARSE.pixel_pitch_m, grid_shape=COARSE.image_shape)
    assert not fit and fit.pitch_ratio > MAX_PITCH_RATIO
    assert "pitch 0.600 mm is 1.69 times the model's input pitch 0.355 mm" in fit.refusal
    assert fit.reasons[0] == fit.refusal
    # Just within the limit (0.5 mm, 1.4 times): answered.
    assert input_range(default_window_m(), SIZE, pitch_m=0.5e-3, grid_shape=(46, 64))


def test_a_sample_without_measurements_or_a_variant_without_window_is_not_checked():
    assert sampled_input_range(SampledGrasp(), Variant(window_m=default_window_m())) == sampled_input_range(
        SampledGrasp(measurements=_measured(R15)), Variant())
    assert sampled_input_range(SampledGrasp(), Variant()).widen == 1.0


def _measured(grid: DepthGrid, touches: bool = False) -> SimpleNamespace:
    """What :func:`sampled_input_range` reads of a grasp's measurements on ``grid``."""
    return SimpleNamespace(grid=grid, depth_m=None, features=SimpleNamespace(touches_edge=np.array([False, touches])),
                           calibration_smoothing_px=0.0)


def test_variant_windows_are_checked():
    assert Variant(window_m=[0.01, 0.02]).window_m == (0.01, 0.02)
    assert Variant(window_m=(0.0128, 0.0176), size_px=(64, 88)).input_pitch_m == pytest.approx((2e-4, 2e-4))
    assert Variant().input_pitch_m is None
    for bad in ((0.01,), (-0.01, 0.02), (0.01, math.nan), (1.0, 0.02), "ab"):
        with pytest.raises(ModelError, match="window_m"):
            Variant(window_m=bad)


# --------------------------------------------------------------------------- the model


def _sampled(synthetic, grid: DepthGrid, touches: bool = False) -> SampledGrasp:
    s = synthetic.sample("rubber_a", 0, 0, rng=np.random.default_rng(0))
    return SampledGrasp(measurements=_measured(grid, touches), estimates=s.estimates, force_n=s.force_n,
                        width_m=s.width_m, depth_m=s.depth_m)


def _estimate(trained_model, synthetic, grid: DepthGrid, *, touches: bool = False, mode: str = "model"):
    from estimator.inference.hybrid import AutoPolicy, HybridEstimator
    from estimator.inference.infer import CompliancePredictor

    sampled = _sampled(synthetic, grid, touches)
    predictor = CompliancePredictor(trained_model)
    # The few-epoch model's calibrated interval spans most of the scale; a fifth of it is clipped by neither
    # end and, about a median above the resolution limit, still reaches below it (else a lower bound).
    predictor.metadata = dataclasses.replace(predictor.metadata,
                                             interval_scales=tuple(s / 5 for s in predictor.metadata.interval_scales))
    hybrid = HybridEstimator(predictor, settings=load_settings(), policy=AutoPolicy(0.0))
    return hybrid.estimate_sampled(sampled, mode=mode)


def _below(estimate, median: float) -> float:
    """Decades from the interval's low end to the distribution's ``median`` (log10 Pa), which the
    interval is centred on (its high end is clipped above 100 MPa)."""
    return median - math.log10(estimate.interval_pa[0])


def _median(trained_model, synthetic) -> float:
    from estimator.inference.distribution import quantile
    from estimator.inference.infer import CompliancePredictor

    probs = CompliancePredictor(trained_model).predict_distribution([_sampled(synthetic, depth_grid(WEDGE, 2))])
    return float(quantile(probs[0], 0.5)[0])


@pytest.mark.slow
def test_the_model_widens_its_interval_where_the_pad_covers_little_of_its_window(trained_model, synthetic):
    wedge = _estimate(trained_model, synthetic, depth_grid(WEDGE, 2))
    small = _estimate(trained_model, synthetic, depth_grid(R15, 2))
    median = _median(trained_model, synthetic)
    assert wedge.state == small.state == "ok" and small.e_pa == wedge.e_pa  # widening moves the interval only
    assert _below(small, median) == pytest.approx(COVERAGE_WIDENING * _below(wedge, median), rel=1e-6)
    assert "widened 1.5 times" not in wedge.reason and "outside the training range" not in wedge.reason
    assert "widened 1.5 times" in small.reason and "pad covers 37% of the model's" in small.reason
    cut = _estimate(trained_model, synthetic, depth_grid(R15, 2), touches=True)
    assert _below(cut, median) == pytest.approx(COVERAGE_WIDENING * EDGE_WIDENING * _below(wedge, median), rel=1e-6)
    assert "widened 2.25 times" in cut.reason and "contact reaches the edge" in cut.reason
    # On the training sensor a contact at the pad's edge is nothing new.
    assert _estimate(trained_model, synthetic, depth_grid(WEDGE, 2), touches=True) == wedge


@pytest.mark.slow
def test_the_model_refuses_a_sensor_much_coarser_than_its_input_pitch(trained_model, synthetic):
    # The fixture model reads 16 x 22 px of the Wedge's pad: 1.42 mm pitch; a 2.5 mm grid is 1.76 times that.
    coarse = SimpleNamespace(pixel_pitch_m=2.5e-3, image_shape=(10, 14))
    refused = _estimate(trained_model, synthetic, coarse)
    assert refused.state == "insufficient_data" and not refused and refused.e_pa is None
    assert "does not apply to this sensor" in refused.reason and "pitch 2.500 mm is 1.76 times" in refused.reason
    fallback = _estimate(trained_model, synthetic, coarse, mode="auto")  # the series estimate, relabelled
    assert fallback.method == "auto" and fallback.state == "ok"
    assert fallback.reason.startswith("series: the model does not apply to this sensor") and "2.500 mm" in fallback.reason
    assert _estimate(trained_model, synthetic, COARSE).state == "ok"  # 0.6 mm is fine at that pitch


# --------------------------------------------------------------------------- metadata


@pytest.mark.slow
def test_the_window_round_trips_through_the_metadata(trained_model, tmp_path, caplog):
    from estimator.inference.infer import CompliancePredictor

    meta = json.loads((trained_model / "metadata.json").read_text())
    # Trained on a dataset whose manifest records no window: the default sensor's pad, written down.
    assert meta["variant"]["window_m"] == pytest.approx(list(default_window_m()))
    assert CompliancePredictor(trained_model).variant.window_m == tuple(meta["variant"]["window_m"])
    dest = tmp_path / "model"
    shutil.copytree(trained_model, dest)
    meta["variant"]["window_m"] = [0.015, 0.02]
    (dest / "metadata.json").write_text(json.dumps(meta))
    assert CompliancePredictor(dest).variant.window_m == (0.015, 0.02)
    del meta["variant"]["window_m"]  # a model from before the key reads the Wedge's pad
    (dest / "metadata.json").write_text(json.dumps(meta))
    with caplog.at_level("INFO", logger="estimator.inference.infer"):
        legacy = CompliancePredictor(dest)
    assert legacy.variant.window_m == default_window_m() and "no variant.window_m" in caplog.text
    for bad, expected in (([-0.01, 0.02], "window_m"), ("wide", "missing or malformed")):
        meta["variant"]["window_m"] = bad
        (dest / "metadata.json").write_text(json.dumps(meta))
        with pytest.raises(ModelError, match=expected):
            CompliancePredictor(dest)


@pytest.mark.train
def test_a_dataset_records_its_window_and_a_model_must_read_it(synthetic, tmp_path):
    from estimator.training.dataset_cli import parse_window_mm
    from estimator.training.splits import dataset_window
    from estimator.training.train import train_model

    assert parse_window_mm("14.16x18.88") == pytest.approx((14.16e-3, 18.88e-3))
    assert dataset_window({"window_m": [0.014, 0.019]}, "x") == (0.014, 0.019)
    assert dataset_window({}, "x") == default_window_m()
    data = synthetic.write_dataset(tmp_path / "data")
    manifest = json.loads((data / "dataset.json").read_text())
    (data / "dataset.json").write_text(json.dumps({**manifest, "window_m": [0.014, 0.019]}))
    variant = Variant.parse("depth", n_frames=synthetic.N_FRAMES, size_px=synthetic.SIZE, window_m=default_window_m())
    with pytest.raises(EstimatorError, match="window"):
        train_model(data, tmp_path / "m", variant=variant, progress=False)
