"""Model inputs: variants, scales, the analytical encoding and batching, and sampling a grasp's frames."""

from __future__ import annotations

import math
from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest

from estimator.errors import ModelError
from estimator.estimate import Estimate
from estimator.inference.inputs import (
    ANALYTICAL_METHODS,
    FEATURES_PER_METHOD,
    LOG10_E_RANGE,
    REFERENCE_GEL_MODULUS_PA,
    RIG_FEATURES,
    Variant,
    analytical_features,
    encode,
    gel_scale,
    reduce_images,
)
from estimator.inference.sampling import SampledGrasp, sample_stream


@pytest.mark.parametrize("text", ["depth", "rgb+markers", "depth+fw+analytical", "rgb+markers+fw+analytical"])
def test_variant_names_round_trip(text):
    variant = Variant.parse(text, n_frames=5, size_px=(125, 175))
    assert variant.name == text
    assert Variant.parse(variant.name, n_frames=5, size_px=(125, 175)) == variant
    assert variant.method == ("hybrid" if "analytical" in text else "cnn")


def test_input_shapes_follow_the_flags():
    assert Variant.parse("depth", n_frames=3, size_px=(64, 88)).input_shapes == {"frames": (3, 1, 64, 88)}
    shapes = Variant.parse("rgb+markers+fw+analytical", n_frames=2, size_px=(32, 44)).input_shapes
    assert list(shapes) == ["frames", "force_width", "analytical"]
    assert shapes["frames"] == (2, 6, 32, 44)
    assert shapes["force_width"] == (4 + RIG_FEATURES,)
    assert shapes["analytical"] == (FEATURES_PER_METHOD * len(ANALYTICAL_METHODS),)


@pytest.mark.parametrize(("text", "kwargs", "expected"), [
    ("colour", {}, "expected depth or rgb"),
    ("depth+fw+fw2", {}, "expected depth or rgb"),
    ("depth", {"n_frames": 0}, "n_frames"),
    ("depth", {"size_px": (4, 88)}, "size_px"),
    ("depth", {"size_px": (64, 400)}, "size_px"),
])
def test_bad_variants_are_refused(text, kwargs, expected):
    with pytest.raises(ModelError, match=expected):
        Variant.parse(text, **kwargs)


def test_analytical_features_encode_states_bounds_and_widths():
    estimates = [
        Estimate.ok("series", 1e6, 1e5, 1e7, "two decades wide"),
        Estimate.at_least("hertz", 1e9, "stiffer than resolved"),
        Estimate.refuse("elastic", "no contact"),
    ]  # no_tactile missing: encoded as a refusal
    f = analytical_features(estimates).reshape(len(ANALYTICAL_METHODS), FEATURES_PER_METHOD)
    rows = dict(zip(ANALYTICAL_METHODS, f, strict=True))
    assert rows["series"][0] == pytest.approx((6 - 3) / 9) and rows["series"][1] == pytest.approx(2 / 9)
    assert rows["series"][2:].tolist() == [1, 0, 0, 0]
    assert rows["hertz"][0] == pytest.approx((9 - 3) / 9) and rows["hertz"][1] == 1.0  # open interval
    assert rows["hertz"][2:].tolist() == [0, 1, 0, 0]
    for refused in ("elastic", "no_tactile"):
        assert rows[refused].tolist() == [0, 1, 0, 0, 0, 1]
    assert f.dtype == np.float32 and np.all(np.isfinite(f))


def test_encode_batches_every_input_at_its_scale(synthetic):
    rng = np.random.default_rng(0)
    samples = [synthetic.sample(name, 0, 0, rng=rng, markers=True) for name in ("rubber_a", "metal_a")]
    variant = Variant.parse("rgb+markers+fw+analytical", n_frames=synthetic.N_FRAMES, size_px=synthetic.SIZE)
    batch = encode(variant, samples)
    assert {k: v.shape for k, v in batch.items()} == {k: (2, *s) for k, s in variant.input_shapes.items()}
    assert all(v.dtype == np.float32 for v in batch.values())
    np.testing.assert_allclose(batch["frames"][0, :, :3], np.moveaxis(samples[0].rgb_diff, -1, 1) / 64.0, rtol=1e-6)
    np.testing.assert_allclose(batch["force_width"][1],
                               np.r_[samples[1].force_n / 30.0, samples[1].width_m / 0.08, 0.0, 0.0], rtol=1e-6)
    depth = encode(Variant.parse("depth", n_frames=synthetic.N_FRAMES, size_px=synthetic.SIZE), samples)["frames"]
    np.testing.assert_allclose(depth[:, :, 0], np.stack([s.depth_m for s in samples]) * 1e3, rtol=1e-6)


def test_a_softer_gel_reads_as_the_reference_gel_under_more_force(synthetic):
    """The gel scale (module notes): half the reference gel's modulus doubles forces and moduli."""
    sample = synthetic.sample("rubber_a", 0, 0, rng=np.random.default_rng(0))
    soft = replace(sample, gel_modulus_pa=REFERENCE_GEL_MODULUS_PA / 2, gel_thickness_m=6e-3,
                   finger_stiffness_n_per_m=2e4)
    variant = Variant.parse("depth+fw+analytical", n_frames=synthetic.N_FRAMES, size_px=synthetic.SIZE)
    plain, scaled = encode(variant, [sample]), encode(variant, [soft])
    n = synthetic.N_FRAMES
    np.testing.assert_allclose(scaled["force_width"][0, :n], 2 * plain["force_width"][0, :n], rtol=1e-6)
    np.testing.assert_allclose(scaled["force_width"][0, n:2 * n], plain["force_width"][0, n:2 * n])
    np.testing.assert_allclose(scaled["force_width"][0, 2 * n:], [1.0, -1.0], rtol=1e-6)  # log2 6/3, log10 20/200
    np.testing.assert_array_equal(scaled["frames"], plain["frames"])  # depth needs no scaling
    shift = np.log10(2) / (LOG10_E_RANGE[1] - LOG10_E_RANGE[0])
    values = slice(0, None, FEATURES_PER_METHOD)  # each method's normalised log10 E
    answered = plain["analytical"][0, values] != 0
    np.testing.assert_allclose(scaled["analytical"][0, values][answered], plain["analytical"][0, values][answered] + shift,
                               rtol=1e-5)
    assert gel_scale(None) == 1.0 and gel_scale(REFERENCE_GEL_MODULUS_PA / 2) == 2.0


def test_encode_names_what_does_not_fit(synthetic):
    sample = synthetic.sample("foam_a", 0, 0, rng=np.random.default_rng(0), markers=False)
    with pytest.raises(ModelError, match="needs depth_markers_m"):
        encode(Variant.parse("depth+markers", n_frames=synthetic.N_FRAMES, size_px=synthetic.SIZE), [sample])
    with pytest.raises(ModelError, match="variant depth expects 3 frames of 32 x 44 px"):
        encode(Variant.parse("depth", n_frames=synthetic.N_FRAMES, size_px=(32, 44)), [sample])
    with pytest.raises(ModelError, match="nothing to encode"):
        encode(Variant(), [])


def test_reduce_images_area_averages_each_frame():
    stack = np.zeros((2, 250, 350), np.float32)
    stack[1, :125, :175] = 4.0  # one quadrant
    small = reduce_images(stack, (125, 175))
    assert small.shape == (2, 125, 175) and small.dtype == np.float32
    assert small[1].mean() == pytest.approx(1.0) and small[0].max() == 0.0
    colour = reduce_images(np.ones((1, 250, 350, 3), np.float32), (64, 88))
    assert colour.shape == (1, 64, 88, 3) and math.isclose(float(colour.mean()), 1.0, rel_tol=1e-6)
    assert reduce_images(stack, None) is stack


def _segment(frame_t_s, t_contact_s, t_peak_s):
    from estimator.segment import Segment

    return Segment(reason="", frame_reason="", frame_t_s=np.asarray(frame_t_s, dtype=np.float64),
                   t_contact_s=t_contact_s, t_peak_s=t_peak_s)


def test_sample_sets_spread_over_the_loading_phase_and_shift_by_a_frame():
    from estimator.inference.sampling import sample_positions

    t = np.arange(10) / 30.0  # ten loading frames at 30 Hz
    segment = _segment(t, t_contact_s=0.0, t_peak_s=t[-1])
    assert sample_positions(segment, 3, 0).tolist() in ([0, 4, 9], [0, 5, 9])
    assert sample_positions(segment, 3, 2)[0] == 2 and sample_positions(segment, 3, 2)[-1] == 9
    assert np.all(np.diff(sample_positions(segment, 3, 4)) > 0)  # distinct frames when shifted
    assert "shift 8 leaves 2 of the 3" in sample_positions(segment, 3, 8)
    short = _segment([0.01, 0.03], t_contact_s=0.0, t_peak_s=0.05)  # a stiff object: two loading frames
    assert sample_positions(short, 3, 0).tolist() == [0, 0, 1]  # frames repeat rather than the grasp being lost
    assert isinstance(sample_positions(short, 3, 1), str)


@pytest.mark.parametrize(("shift", "n_frames"), [(-1, 3), (0, 0)])
def test_a_negative_shift_or_no_frames_is_refused(shift, n_frames):
    with pytest.raises(ModelError, match="expected shift >= 0 and n_frames >= 1"):
        sample_stream(SimpleNamespace(), n_frames=n_frames, size_px=None, shift=shift)


def _one_finger_stream(sampled: SampledGrasp, *, markers: bool) -> SimpleNamespace:
    """A stream whose only sensor is its own finger's (with ``markers`` or not), sampling as ``sampled``."""
    return SimpleNamespace(finger="left", sensors=[SimpleNamespace(finger="left", markers=markers)],
                           skipping_bad_frames=lambda _frames: sampled)


def test_a_marker_variant_does_not_read_its_own_finger_as_the_marker_finger():
    stream = _one_finger_stream(SampledGrasp(force_n=np.array([1.0, 2.0, 3.0])), markers=True)
    sampled = sample_stream(stream, n_frames=3, size_px=None, markers=True)
    assert not sampled and "no finger with markers besides 'left'" in sampled.reason


def test_a_marker_variant_keeps_the_reason_its_own_finger_gave():
    stream = _one_finger_stream(SampledGrasp(reason="no loading phase"), markers=False)
    sampled = sample_stream(stream, n_frames=3, size_px=None, markers=True)
    assert not sampled and sampled.reason == "no loading phase"


@pytest.mark.slow
def test_sampling_decodes_only_the_reference_and_sampled_frames(sim_grasps):
    from dataclasses import replace

    from estimator.inference.sampling import sample_grasp
    from estimator.measurements import REFERENCE_FRAMES, REFERENCE_GUARD_S
    from teleop.record import FrameStream, read_record
    from teleop.settings import load_settings

    records, calibration = sim_grasps
    settings = load_settings()
    finger = settings.sensing.finger
    record = read_record(records / "stress_ball.grasp")
    sampled = sample_grasp(record, settings=settings, calibration=calibration, n_frames=3, size_px=(16, 22), rgb=True)
    m = sampled.measurements
    stream = record.stream(finger)
    sampled_frames = m.segment.frame_index[np.searchsorted(m.segment.frame_t_s, m.t_s)]
    reference = np.flatnonzero(stream.t_s < m.segment.t_onset_s - REFERENCE_GUARD_S)[-REFERENCE_FRAMES:]
    keep = {*sampled_frames.tolist(), *reference.tolist()}
    broken = FrameStream(stream.finger, stream.t_s, tuple(b if i in keep else b"not a jpeg"
                                                         for i, b in enumerate(stream.encoded)),
                         encoding=stream.encoding, jpeg_quality=stream.jpeg_quality, shape=stream.shape)
    frames = tuple(broken if s.finger == finger else s for s in record.frames)
    again = sample_grasp(replace(record, frames=frames), settings=settings, calibration=calibration, n_frames=3,
                         size_px=(16, 22), rgb=True)
    np.testing.assert_array_equal(again.depth_m, sampled.depth_m)
    np.testing.assert_array_equal(again.rgb_diff, sampled.rgb_diff)
    diff = reduce_images(m.image_bgr.astype(np.float32) - m.reference_bgr.astype(np.float32), (16, 22))
    assert sampled.rgb_diff.shape == (3, 16, 22, 3)
    assert all(any(np.array_equal(row, d) for d in diff) for row in sampled.rgb_diff)  # frame minus reference


@pytest.mark.slow
def test_the_colour_difference_is_cut_to_the_same_window_as_the_depth(sim_grasps):
    from estimator.inference.sampling import sample_grasp
    from teleop.record import read_record
    from teleop.settings import load_settings

    records, calibration = sim_grasps
    record = read_record(records / "stress_ball.grasp")
    settings = load_settings()
    whole = sample_grasp(record, settings=settings, calibration=calibration, n_frames=3, size_px=None)
    grid = whole.measurements.grid
    window = tuple(n * grid.pixel_pitch_m / 2 for n in grid.image_shape)  # half the pad each way
    sampled = sample_grasp(record, settings=settings, calibration=calibration, n_frames=3, size_px=(16, 22),
                           rgb=True, window_m=window)
    m = sampled.measurements
    diff = reduce_images(m.image_bgr.astype(np.float32) - m.reference_bgr.astype(np.float32), (16, 22),
                         pitch_m=grid.pixel_pitch_m, window_m=window)
    assert sampled.rgb_diff.shape == (3, 16, 22, 3)
    assert all(any(np.allclose(row, d) for d in diff) for row in sampled.rgb_diff)
