"""Sampling a grasp's frames for the learned model, audited on a stand-in stream: which frames are sampled,
how repeated frames carry their values, what is refused and why, the marker finger, and the record path."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from estimator.estimate import Estimate
from estimator.inference import sampling
from estimator.inference.inputs import Variant
from estimator.inference.sampling import (
    SampledGrasp,
    calibration_for,
    decoded,
    record_stream,
    sample_positions,
    sample_stream,
    sampled_input_range,
)
from estimator.inference.window import input_range
from estimator.perception.calibration import Calibration
from estimator.segment import Segment
from estimator.settings import estimator_settings
from teleop.record import FrameStream, GraspRecord, Provenance, Samples
from teleop.settings import SensorSettings, Settings


def loading(frame_t_s, *, t_contact_s=0.0, reason="", frame_reason="") -> Segment:
    t = np.asarray(frame_t_s, dtype=np.float64)
    return Segment(reason=reason, frame_reason=frame_reason, frame_t_s=t, t_contact_s=t_contact_s,
                   t_peak_s=float(t[-1]) if t.size else 0.0, frame_index=np.arange(t.size) + 5)


class StandInStream:
    """The part of a GraspStream that sampling reads: loading frames ``frame_index`` 5, 6, ... whose depth,
    colour, force and width are their frame index (plus ``offset``), measured on demand."""

    def __init__(self, segment: Segment, *, finger="left", sensors=(), offset=0.0, features=True,
                 tactile_reason="", marker_stream=None):
        self.finger, self.sensors, self.offset = finger, list(sensors), offset
        self._segment, self.features, self.tactile_reason = segment, features, tactile_reason
        self.marker_stream, self.measured, self.asked = marker_stream, [], None

    def segment(self, *, n_frames):
        self.n_frames = n_frames
        return self._segment

    def skipping_bad_frames(self, compute):
        return compute()

    def measurements(self, segment, *, frames):
        self.measured.append(frames.tolist())
        value = segment.frame_index[frames] + self.offset
        return SimpleNamespace(
            features=SimpleNamespace(touches_edge=np.zeros(frames.size, bool)) if self.features else None,
            tactile_reason=self.tactile_reason, force_n=value * 1.0, width_m=value * 1e-3,
            image_bgr=np.broadcast_to(value[:, None, None, None], (frames.size, 2, 2, 3)).astype(np.uint8),
            reference_bgr=np.full((2, 2, 3), 7, np.uint8), grid=SimpleNamespace(pixel_pitch_m=1e-4),
            sensor=SimpleNamespace(gel_modulus_pa=1.5e5, gel_thickness_m=4e-3), finger_stiffness_n_per_m=3e4)

    def reduced_depths(self, index, size_px, window_m):
        return np.stack([np.full((2, 2), i + self.offset, np.float32) for i in index])

    def for_finger(self, finger, *, calibration):
        self.asked = (finger, calibration)
        return self.marker_stream


@pytest.fixture(autouse=True)
def stub_fits(monkeypatch):
    """The analytical fits need real measurements; here each method only says it ran."""
    monkeypatch.setattr(sampling, "estimate_measurements", lambda m, method: Estimate.refuse(method, "stand-in"))


def test_sampling_starts_at_contact_not_at_the_first_loading_frame():
    t = 0.2 + np.arange(10) / 30.0  # contact 0.2 s before the first loading frame
    assert sample_positions(loading(t, t_contact_s=0.0), 4, 0).tolist() == [0, 0, 4, 9]


def test_a_shift_that_leaves_exactly_the_frames_needed_is_sampled():
    t = np.arange(10) / 30.0
    assert sample_positions(loading(t), 3, 7).tolist() == [7, 8, 9]


def test_a_shift_past_every_loading_frame_says_none_are_left():
    assert "shift 12 leaves 0 of the 3 loading frames" in sample_positions(loading(np.arange(10) / 30.0), 3, 12)


def test_a_repeated_sample_position_is_measured_once_and_repeats_its_values():
    stream = StandInStream(loading([0.01, 0.03], t_contact_s=0.0))  # a stiff object: positions 0, 0, 1
    sampled = sample_stream(stream, n_frames=3, size_px=None, rgb=True)
    assert sampled and stream.measured == [[0, 1]]
    assert sampled.depth_m[:, 0, 0].tolist() == [5, 5, 6]
    assert sampled.rgb_diff[:, 0, 0, 0].tolist() == [-2, -2, -1]  # below the reference: no 8-bit wrap-around
    assert sampled.force_n.tolist() == [5, 5, 6] and sampled.width_m.tolist() == pytest.approx([5e-3, 5e-3, 6e-3])
    assert [e.method for e in sampled.estimates] == list(sampling.ANALYTICAL_METHODS)


def test_the_sample_carries_the_rig_that_measured_it():
    stream = StandInStream(loading(np.arange(10) / 30.0))
    sampled = sample_stream(stream, n_frames=4, size_px=None)
    assert stream.n_frames == 4 and sampled.rgb_diff is None  # colour only when asked
    assert (sampled.gel_modulus_pa, sampled.gel_thickness_m, sampled.finger_stiffness_n_per_m) == (1.5e5, 4e-3, 3e4)


@pytest.mark.parametrize(("reason", "frame_reason"), [("no contact", ""), ("", "no tactile frame within the loading")])
def test_a_grasp_without_usable_loading_frames_is_refused_with_the_segments_reason(reason, frame_reason):
    sampled = sample_stream(StandInStream(loading(np.arange(10) / 30.0, reason=reason, frame_reason=frame_reason)),
                            n_frames=3, size_px=None)
    assert not sampled and sampled.reason == (reason or frame_reason)


@pytest.mark.parametrize(("tactile_reason", "expected"), [("frame 3 is blank", "frame 3 is blank"),
                                                          ("", "tactile features were not measured")])
def test_frames_without_tactile_features_are_refused_with_the_measurements_reason(tactile_reason, expected):
    stream = StandInStream(loading(np.arange(10) / 30.0), features=False, tactile_reason=tactile_reason)
    sampled = sample_stream(stream, n_frames=3, size_px=None)
    assert not sampled and sampled.reason == expected


def _with_markers(monkeypatch, marker_stream):
    monkeypatch.setattr(sampling, "calibration_for", lambda sensor, cal: ("calibration", sensor.finger, cal))
    sensors = [SimpleNamespace(finger="left", markers=False), SimpleNamespace(finger="right", markers=False),
               SimpleNamespace(finger="thumb", markers=True)]
    return StandInStream(loading(np.arange(10) / 30.0), sensors=sensors, marker_stream=marker_stream)


def test_the_marker_finger_is_another_finger_with_markers_read_with_its_own_calibration(monkeypatch):
    marker = StandInStream(loading(np.arange(10) / 30.0), finger="thumb", offset=100.0)
    stream = _with_markers(monkeypatch, marker)
    sampled = sample_stream(stream, n_frames=3, size_px=None, rgb=True, markers=True, marker_calibration="thumb.npz")
    assert sampled and stream.asked == ("thumb", ("calibration", "thumb", "thumb.npz"))
    assert sampled.depth_m[:, 0, 0].min() < 100 <= sampled.depth_markers_m[:, 0, 0].min()
    assert sampled.rgb_diff_markers[:, 0, 0, 0].tolist() == (sampled.rgb_diff[:, 0, 0, 0] + 100).tolist()


def test_the_marker_finger_is_sampled_at_the_same_shift(monkeypatch):
    marker = StandInStream(loading(np.arange(10) / 30.0), finger="thumb", offset=100.0)
    sampled = sample_stream(_with_markers(monkeypatch, marker), n_frames=3, size_px=None, shift=1, markers=True)
    assert sampled.depth_m[:, 0, 0].tolist() == [6, 10, 14]
    assert sampled.depth_markers_m[:, 0, 0].tolist() == [106, 110, 114]


def test_a_marker_finger_that_cannot_be_sampled_refuses_the_grasp_naming_it(monkeypatch):
    marker = StandInStream(loading(np.arange(10) / 30.0, reason="no contact"), finger="thumb")
    sampled = sample_stream(_with_markers(monkeypatch, marker), n_frames=3, size_px=None, markers=True)
    assert not sampled and sampled.reason == "marker finger 'thumb': no contact"


@pytest.mark.parametrize(("markers", "binning"), [(True, 1), (False, 2)])
def test_a_record_from_a_marker_sensor_is_measured_on_its_full_grid(monkeypatch, markers, binning):
    settings = Settings()
    assert estimator_settings(settings).depth_binning == 2
    monkeypatch.setattr(sampling, "finger_sensor", lambda record, finger: SensorSettings(finger=finger, markers=markers))
    monkeypatch.setattr(sampling, "calibration_for", lambda sensor, cal: cal)
    monkeypatch.setattr(sampling, "GraspStream", SimpleNamespace(
        from_record=lambda record, *, settings, calibration: settings))
    assert estimator_settings(record_stream(None, settings=settings, calibration="c")).depth_binning == binning


def test_a_loaded_calibration_is_used_as_it_is():
    calibration = Calibration(lut=np.zeros((1, 1, 2, 2, 2, 2), np.float32), image_shape=(4, 4), pixel_pitch_m=1e-4,
                              ball_radius_m=2e-3)
    assert calibration_for(SensorSettings(finger="left"), calibration) is calibration


def test_decoded_frames_are_looked_up_at_their_reduction_and_decoded_at_any_other():
    image = np.arange(8 * 8 * 3, dtype=np.uint8).reshape(8, 8, 3)
    stream = FrameStream.from_frames("left", np.arange(2) / 30.0, [image, image], encoding="png")
    record = GraspRecord(sensors=(SensorSettings(finger="left"),), frames=(stream,),
                         force_n=Samples(np.zeros(1), np.zeros(1)), width_m=Samples(np.zeros(1), np.zeros(1)),
                         provenance=Provenance("simulated"))
    frames = decoded(record, reduce=2).frames[0]
    assert np.shares_memory(frames.frame(1, reduce=2), frames.images) and frames.images.shape[1:3] == (4, 4)
    np.testing.assert_array_equal(frames.frame(1), image)


VARIANT = Variant(size_px=(16, 22), window_m=(0.02, 0.03))


def _range(depth_shape, touches_edge, grid_shape=(200, 300)):
    m = SimpleNamespace(grid=SimpleNamespace(pixel_pitch_m=1e-4, image_shape=grid_shape),
                        depth_m=None if depth_shape is None else np.zeros((3, *depth_shape), np.float32),
                        features=SimpleNamespace(touches_edge=np.array(touches_edge)))
    return sampled_input_range(SampledGrasp(measurements=m), VARIANT)


def test_a_contact_at_the_edge_in_any_sampled_frame_counts_as_cut_off():
    small = (100, 150)  # a 10 x 15 mm pad in a 20 x 30 mm window
    cut = input_range(VARIANT.window_m, VARIANT.size_px, pitch_m=1e-4, grid_shape=small, touches_edge=True)
    assert cut != input_range(VARIANT.window_m, VARIANT.size_px, pitch_m=1e-4, grid_shape=small)
    assert _range(None, [False, True, False], grid_shape=small) == cut


def test_the_pad_is_the_measured_depths_not_the_sensors_image_grid():
    measured = input_range(VARIANT.window_m, VARIANT.size_px, pitch_m=1e-4, grid_shape=(100, 150))
    assert measured != input_range(VARIANT.window_m, VARIANT.size_px, pitch_m=1e-4, grid_shape=(200, 300))
    assert _range((100, 150), [False, False]) == measured
