"""From grasp records to estimates: measure_grasp, estimate_grasp and the two commands.

Records are built here the way hardware delivers them: a Hertz sphere squeezed by
fingers with compliance, force at 80 Hz and width at 10 Hz with noise, tactile
frames at 30 Hz rendered by the simulated camera from a gel surface computed in
this file (half-space Hertz inside the contact; the tail outside decays within a
gel thickness, as on a bonded layer). The sensor's gel is the thickest the settings
allow (20 mm), so that the half-space surface is what the estimator's layer model
expects for these small contacts, and the sphere compresses in bulk as the series
fit models it (extent over a ball's mean cross-section). The estimator sees only the record.
"""

from __future__ import annotations

import json
import math
from dataclasses import replace

import numpy as np
import pytest

from estimator.analytical import METHODS
from estimator.cli import main
from estimator.errors import CalibrationError, FitError, PerceptionError
from estimator.estimate import Estimate
from estimator.features import ContactFeatures
from estimator.measure import estimate_grasp, measure_grasp, no_contact_reference
from estimator.measurements import (
    calibration_path,
    median_frame,
)
from estimator.perception import fit_calibration, warp_and_crop
from estimator.segment import segment_grasp
from estimator.settings import estimator_settings
from estimator.stream import GraspStream
from teleop.errors import RecordError
from teleop.record import FrameStream, GraspRecord, Label, Provenance, Samples, write_record
from teleop.settings import CONFIG_DIR, SensorSettings, Settings, SimulationSettings
from teleop.sim.optics import OpticsRenderer
from teleop.sim.presses import simulate_presses

THICK_GEL_M = 2e-2
SENSOR = SensorSettings(finger="left", gel_thickness_m=THICK_GEL_M)
SIM = SimulationSettings()
SETTINGS = Settings()
K_GEL = SENSOR.gel_compliance_per_pa
NU = 0.4
STEEL = 200e9


@pytest.fixture(scope="module")
def calibration():
    camera = OpticsRenderer(SENSOR, sim=SIM, rng=np.random.default_rng(0))
    pack = simulate_presses(camera, n=12, ball_radius_m=2e-3, depth_range_m=(0.3e-3, 1.2e-3),
                            rng=np.random.default_rng(1))
    images = np.stack([warp_and_crop(im, SENSOR) for im in pack["imgs"]])
    return fit_calibration(warp_and_crop(pack["f0"], SENSOR), images, pack["touch_center"],
                           pack["touch_radius"], ball_radius_m=2e-3, pixel_pitch_m=SENSOR.pixel_pitch_m)


def gel_surface(approach_m, radius_m, share, shape=SENSOR.image_shape, pitch=SENSOR.pixel_pitch_m):
    """Gel indentation (m) when a sphere has approached by ``approach_m`` (see the module docstring)."""
    if approach_m <= 0:
        return np.zeros(shape, dtype=np.float32)
    rows, cols = shape
    y, x = np.indices(shape)
    r = np.hypot(x - (cols - 1) / 2, y - (rows - 1) / 2) * pitch
    a = math.sqrt(radius_m * approach_m)
    ro = np.maximum(r, a)
    outside = approach_m / (np.pi * a**2) * ((2 * a**2 - ro**2) * np.arcsin(a / ro)
                                             + ro * a * np.sqrt(np.clip(1 - a**2 / ro**2, 0, None)))
    taper = np.exp(-np.clip(r - a, 0, None) / 1.5e-3)
    total = np.where(r <= a, approach_m - r**2 / (2 * radius_m), outside * taper)
    return (share * total).astype(np.float32)


def build_record(
    e_pa, *, sensor=SENSOR, radius_m=6e-3, target_n=8.0, camera_lag_s=0.0, seed=0, force_noise_n=0.02,
    width_noise_m=2e-5, force_scale=1.0, frame_times=None, label=None, speed=0.0375, gap_m=0.02,
    width_delay_s=0.0, hold_s=0.15, bulk=True,
):
    """A grasp of a sphere of modulus ``e_pa``: fingers close at ``speed`` (m/s) from ``gap_m``
    before touching until ``target_n``."""
    rng = np.random.default_rng(seed)
    stiffness, diameter = SETTINGS.gripper.finger_stiffness_n_per_m, 0.03
    e_star = 1 / (K_GEL + (1 - NU**2) / e_pa)
    share = K_GEL * e_star
    approach = np.linspace(0, 30e-3, 300001)
    force = 4 / 3 * e_star * math.sqrt(radius_m) * approach**1.5
    compression = force * diameter / (e_pa * math.pi * diameter**2 / 6) if bulk else 0.0
    closure = 2 * approach + compression + force / stiffness  # motor travel since touch
    start_width = diameter + gap_m
    t_touch = (start_width - diameter) / speed
    t_stop = t_touch + np.interp(target_n, force, closure) / speed

    def state(t):
        travel = np.clip(speed * np.minimum(t, t_stop) - (start_width - diameter), 0, None)
        return start_width - speed * np.minimum(t, t_stop), np.interp(travel, closure, approach), np.interp(travel, closure, force)

    end = t_stop + hold_s
    tf = np.arange(0, end, 1 / 80)
    tw = np.arange(0.003, end, 1 / 10)
    tc = np.arange(0.011, end, 1 / 30) if frame_times is None else np.asarray(frame_times)
    f = state(tf)[2] * force_scale + rng.normal(0, force_noise_n, tf.size)
    w = state(tw)[0] + rng.normal(0, width_noise_m, tw.size)
    camera = OpticsRenderer(sensor, sim=SIM, rng=rng)
    finite_tc = np.nan_to_num(tc, nan=0.0)
    frames = [camera.capture(gel_surface(d, radius_m, share, shape=sensor.image_shape)) for d in state(finite_tc - camera_lag_s)[1]]
    stream = FrameStream(sensor.finger, tc, tuple(frames), encoding="jpeg", jpeg_quality=SIM.jpeg_quality,
                         shape=(sensor.raw_height_px, sensor.raw_width_px, 3))
    return GraspRecord(sensors=(sensor,), frames=(stream,), force_n=Samples(tf, f),
                       width_m=Samples(tw + width_delay_s, w),
                       provenance=Provenance("simulated", seed=seed), label=label)


def log_error(est, truth):
    return abs(math.log10(est.e_pa) - math.log10(truth))


def assert_sound(est):
    assert isinstance(est, Estimate) and est.reason
    values = [v for v in (est.e_pa, *est.interval_pa) if v is not None]
    assert all(math.isfinite(v) and v > 0 for v in values)


# --------------------------------------------------------------------------- measure_grasp


def test_measurements_cover_every_loading_frame(calibration):
    record = build_record(3e5)
    m = measure_grasp(record, settings=SETTINGS, calibration=calibration)
    n = m.segment.frame_index.size
    binning = estimator_settings(SETTINGS).depth_binning
    assert binning == 2 and m.depth_binning == binning and m.grid.image_shape == (125, 175)
    assert n >= 5 and len(m.features) == n and m.depth_m.shape == (n, *m.grid.image_shape)
    assert m.depth_m.dtype == np.float32 and np.all(np.isfinite(m.depth_m))
    assert m.sample.size == estimator_settings(SETTINGS).n_frames
    assert np.all(np.diff(m.features.peak_depth_m) > 0) and np.all(np.diff(m.approach_m) > 0)
    assert m.force_n == pytest.approx(np.interp(m.t_s, record.force_n.t_s, record.force_n.value), abs=0.1)


@pytest.mark.parametrize("e_pa", [1e5, 3e5])
def test_series_and_hertz_through_the_whole_pipeline(calibration, e_pa):
    m = measure_grasp(build_record(e_pa), settings=SETTINGS, calibration=calibration)
    for method in ("series", "hertz"):
        est = estimate_grasp(m, method, settings=SETTINGS)
        assert est.state == "ok", est
        assert log_error(est, e_pa) < 0.3, est


def test_steel_gives_lower_bounds_through_the_whole_pipeline(calibration):
    m = measure_grasp(build_record(STEEL), settings=SETTINGS, calibration=calibration)
    for method, least in (("series", 1e6), ("hertz", 1e6), ("elastic", 1e5)):
        est = estimate_grasp(m, method, settings=SETTINGS)
        assert est.state == "lower_bound", est
        assert least < est.e_pa < STEEL


def test_soft_foam_through_the_whole_pipeline(calibration):
    m = measure_grasp(build_record(2e4, target_n=3.0), settings=SETTINGS, calibration=calibration)
    # Hertz ignores the foam's bulk compression, which the series fit models.
    for method, tolerance in (("series", 0.4), ("hertz", 0.6)):
        est = estimate_grasp(m, method, settings=SETTINGS)
        assert est.state == "ok" and log_error(est, 2e4) < tolerance, est


@pytest.mark.parametrize(("radius_m", "target_n"), [(0.3, 8.0), (1e-4, 1.0)], ids=["larger-than-pad", "needle"])
def test_hard_geometries_give_sound_estimates(calibration, radius_m, target_n):
    record = build_record(1e6, radius_m=radius_m, target_n=target_n, speed=0.01, gap_m=0.008)
    m = measure_grasp(record, settings=SETTINGS, calibration=calibration)
    assert m.segment and len(m.features) >= 3
    for method in METHODS:
        assert_sound(estimate_grasp(m, method, settings=SETTINGS))


def test_markers_are_masked_before_reconstruction(calibration):
    sensor = SensorSettings(finger="left", markers=True, gel_thickness_m=THICK_GEL_M)
    record = build_record(3e5, sensor=sensor)
    full_grid = SETTINGS.with_section(replace(estimator_settings(SETTINGS), depth_binning=1))
    m = measure_grasp(record, settings=full_grid, calibration=calibration)
    est = estimate_grasp(m, "series", settings=full_grid)
    assert est.state == "ok" and log_error(est, 3e5) < 0.3
    # Marker dots are found on the full grid only: a binned measurement of them is refused, naming the fix.
    with pytest.raises(PerceptionError, match="markers.*binning 1"):
        measure_grasp(record, settings=SETTINGS, calibration=calibration)


def test_no_tactile_decodes_no_frame(calibration):
    record = build_record(3e5)
    stream = record.frames[0]
    broken = FrameStream("left", stream.t_s, tuple(b"not a jpeg" for _ in stream.encoded), encoding="jpeg")
    record = GraspRecord(sensors=record.sensors, frames=(broken,), force_n=record.force_n,
                         width_m=record.width_m, provenance=record.provenance)
    est = estimate_grasp(record, "no_tactile", settings=SETTINGS)
    assert est.state == "ok" and est.latency_s > 0
    with pytest.raises(RecordError, match="does not decode"):  # not one frame decodes: a broken record
        estimate_grasp(record, "series", settings=SETTINGS, calibration=calibration)


def test_missing_calibration_names_the_fix():
    with pytest.raises(CalibrationError, match="--calibration"):
        estimate_grasp(build_record(3e5), "series", settings=SETTINGS)
    assert calibration_path(SensorSettings(calibration="cal/left.npz")) == CONFIG_DIR / "cal/left.npz"


def test_calibration_for_another_image_is_refused(calibration):
    sensor = SensorSettings(finger="left", crop_px=20)
    with pytest.raises(CalibrationError, match="image"):
        measure_grasp(build_record(3e5, sensor=sensor), settings=SETTINGS, calibration=calibration)


def test_air_grasp_is_refused_by_every_method(calibration):
    record = build_record(3e5, force_scale=0.05)
    for method in METHODS:
        est = estimate_grasp(record, method, settings=SETTINGS, calibration=calibration)
        assert not est and "no contact" in est.reason


def test_one_loading_frame_only(calibration):
    record = build_record(3e5)
    seg = segment_grasp(record.force_n.t_s, record.force_n.value, record.width_m.t_s, record.width_m.value,
                        record.frames[0].t_s, contact_force_n=0.75, n_frames=3)
    times = np.concatenate([np.arange(0.011, seg.t_onset_s - 0.15, 1 / 30), [seg.t_peak_s - 0.01]])
    m = measure_grasp(build_record(3e5, frame_times=times), settings=SETTINGS, calibration=calibration)
    assert m.segment.frame_index.size == 1 and "too_few_samples" in m.segment.flags
    for method in ("series", "hertz"):
        est = estimate_grasp(m, method, settings=SETTINGS)
        assert_sound(est)
        assert est and log_error(est, 3e5) < 0.5


def test_frames_starting_in_contact_have_no_reference(calibration):
    record = build_record(3e5, frame_times=np.arange(0.62, 0.9, 1 / 30))
    est = estimate_grasp(record, "series", settings=SETTINGS, calibration=calibration)
    assert not est and "reference" in est.reason


def test_nan_and_duplicate_timestamps_in_a_record(calibration):
    record = build_record(3e5)
    f, w, s = record.force_n, record.width_m, record.frames[0]
    t_force = f.t_s.copy()
    t_force[[5, 40]] = np.nan
    t_frames = s.t_s.copy()
    t_frames[3] = np.nan
    t_frames[20] = t_frames[19]
    messy = GraspRecord(
        sensors=record.sensors, frames=(FrameStream("left", t_frames, s.encoded, encoding="jpeg"),),
        force_n=Samples(np.concatenate([t_force, f.t_s[:30]]), np.concatenate([f.value, f.value[:30]])),
        width_m=Samples(np.concatenate([w.t_s, [np.nan]]), np.concatenate([w.value, [0.0]])),
        provenance=record.provenance,
    )
    est = estimate_grasp(messy, "series", settings=SETTINGS, calibration=calibration)
    assert est.state == "ok" and log_error(est, 3e5) < 0.3
    assert "non-finite values or timestamps, or duplicate" in est.reason


def test_widths_not_in_metres_are_refused_with_the_reason(calibration):
    record = build_record(3e5)
    w = record.width_m
    in_mm = replace(record, width_m=Samples(w.t_s, w.value * 1e3))
    for method in ("no_tactile", "series"):
        est = estimate_grasp(in_mm, method, settings=SETTINGS, calibration=calibration)
        assert est.state == "insufficient_data" and "outside the gripper's 0-0.08 m opening" in est.reason


def test_widths_read_only_after_the_onset_refuse_in_words(calibration):
    record = build_record(3e5)
    f, w = record.force_n, record.width_m
    late = w.t_s > f.t_s[np.argmax(f.value > 1.0)]
    est = estimate_grasp(replace(record, width_m=Samples(w.t_s[late], w.value[late])), "no_tactile",
                         settings=SETTINGS, calibration=calibration)
    assert est.state == "insufficient_data" and "got no width reading" in est.reason, est.reason


def test_exact_readings_of_a_rigid_object_bound_it_at_a_modulus_a_sensor_resolves(calibration):
    # Noise-free force, and widths that stop exactly at contact: no reading is exact, so the bound
    # rests on the least noise a reading carries, not on a resolution of zero (it was 1e20 Pa).
    record = build_record(3e5, force_noise_n=0.0, width_noise_m=0.0)
    f, w = record.force_n, record.width_m
    touch_s = f.t_s[np.argmax(f.value > 0.1)]
    stopped = np.where(w.t_s < touch_s, w.value, np.interp(touch_s, w.t_s, w.value))
    rigid = replace(record, width_m=Samples(w.t_s, stopped))
    est = estimate_grasp(rigid, "no_tactile", settings=SETTINGS, calibration=calibration)
    assert est.state == "lower_bound" and 1e5 < est.e_pa < 1e9, (est.e_pa, est.reason)


def test_forces_not_in_newtons_are_refused_with_the_reason(calibration):
    record = build_record(3e5)
    f = record.force_n
    in_grams = replace(record, force_n=Samples(f.t_s, f.value * 1e3 / 9.81))
    for method in ("no_tactile", "series"):
        est = estimate_grasp(in_grams, method, settings=SETTINGS, calibration=calibration)
        assert est.state == "insufficient_data" and "maximum grasp force" in est.reason


def test_clipped_force_in_a_record(calibration):
    record = build_record(3e5)
    clipped = Samples(record.force_n.t_s, np.minimum(record.force_n.value, 5.0))
    record = GraspRecord(sensors=record.sensors, frames=record.frames, force_n=clipped,
                         width_m=record.width_m, provenance=record.provenance)
    m = measure_grasp(record, settings=SETTINGS, calibration=calibration)
    assert "clipped" in m.segment.flags and m.force_n.max() <= 5.0
    for method in METHODS:
        assert_sound(estimate_grasp(m, method, settings=SETTINGS))
    assert log_error(estimate_grasp(m, "series", settings=SETTINGS), 3e5) < 0.3


def test_camera_lag_is_estimated_and_corrected(calibration):
    # Without bulk compression: with it the tactile onset is found 0.2 s early (a known gap).
    record = build_record(3e5, camera_lag_s=0.03, bulk=False)
    m = measure_grasp(record, settings=SETTINGS, calibration=calibration, correct_camera_lag=True)
    assert m.camera_lag_s == pytest.approx(0.03, abs=0.02)
    assert m.t_s == pytest.approx(record.frames[0].t_s[m.segment.frame_index] - m.camera_lag_s)


def test_late_width_stamps_are_estimated_and_corrected(calibration):
    # A host that stamps a width read when it returns is late by about one read: after the
    # fingers stop, the stale widths make the approach look larger than it is.
    record = build_record(3e5, width_delay_s=0.1, hold_s=0.5)
    m = measure_grasp(record, settings=SETTINGS, calibration=calibration, correct_width_lag=True)
    assert m.width_lag_s == pytest.approx(0.1, abs=0.03)
    stale = measure_grasp(record, settings=SETTINGS, calibration=calibration)
    # The hold frames see the stopped fingers: uncorrected, the stale widths add ~v * lag / 2.
    e_star = 1 / (K_GEL + (1 - NU**2) / 3e5)
    force = m.hold_force_n
    hertz_m = (force / (4 / 3 * e_star * math.sqrt(6e-3))) ** (2 / 3)
    true_m = hertz_m + 0.5 * force * 0.03 / (3e5 * math.pi * 0.03**2 / 6)
    assert m.hold_approach_m.size and m.hold_approach_m == pytest.approx(true_m, abs=0.15e-3)
    assert np.all(stale.hold_approach_m > true_m + 1e-3)
    assert log_error(estimate_grasp(m, "series", settings=SETTINGS), 3e5) < 0.15


def only_frames(record, keep):
    """``record`` with every frame but ``keep`` replaced by bytes that do not decode."""
    s = record.frames[0]
    encoded = tuple(b if i in set(keep) else b"not a jpeg" for i, b in enumerate(s.encoded))
    stream = FrameStream(s.finger, s.t_s, encoded, encoding=s.encoding, jpeg_quality=s.jpeg_quality, shape=s.shape)
    return GraspRecord(sensors=record.sensors, frames=(stream,), force_n=record.force_n, width_m=record.width_m,
                       provenance=record.provenance)


def test_chosen_frames_are_measured_as_in_the_full_measurement(calibration):
    record = build_record(3e5)
    full = measure_grasp(record, settings=SETTINGS, calibration=calibration)
    first = measure_grasp(record, settings=SETTINGS, tactile=False)
    loading = first.segment.frame_index
    frames = np.array([0, loading.size // 2, loading.size - 1])
    m = GraspStream.from_record(record, settings=SETTINGS, calibration=calibration).measurements(frames=frames)
    np.testing.assert_array_equal(m.depth_m, full.depth_m[frames])
    np.testing.assert_array_equal(m.image_bgr, full.image_bgr[frames])
    np.testing.assert_array_equal(m.reference_bgr, full.reference_bgr)
    np.testing.assert_array_equal(m.reference_bgr, no_contact_reference(record, "left", first.segment,
                                                                        binning=first.depth_binning))
    for name in ContactFeatures.__dataclass_fields__:  # each frame measured alone: the same floats
        np.testing.assert_array_equal(getattr(m.features, name), getattr(full.features, name)[frames])
    for name in ("t_s", "force_n", "width_m", "approach_m"):
        np.testing.assert_array_equal(getattr(m, name), getattr(full, name)[frames])
    assert m.image_bgr.shape == (3, *m.grid.image_shape, 3) and m.image_bgr.dtype == np.uint8


def test_a_records_frame_that_does_not_decode_is_skipped_as_a_live_stream_drops_it(calibration):
    record = build_record(3e5)
    t = record.frames[0].t_s
    broken = int(measure_grasp(record, settings=SETTINGS, tactile=False).segment.frame_index[1])  # a loading frame
    damaged = only_frames(record, set(range(t.size)) - {broken})
    live = GraspStream(settings=SETTINGS, calibration=calibration, sensors=record.sensors)
    live.add_force(record.force_n.t_s, record.force_n.value)
    live.add_width(record.width_m.t_s, record.width_m.value)
    for i, (t_s, data) in enumerate(zip(t, damaged.frames[0].encoded, strict=True)):
        if i == broken:
            with pytest.raises(PerceptionError, match="does not decode"):
                live.add_frame("left", t_s, data, "jpeg")
        else:
            live.add_frame("left", t_s, data, "jpeg")
    offline = GraspStream.from_record(damaged, settings=SETTINGS, calibration=calibration).estimate()
    live_estimate = live.estimate()
    assert [(e.method, e.e_pa, e.interval_pa, e.state) for e in offline.estimates] == [
        (e.method, e.e_pa, e.interval_pa, e.state) for e in live_estimate.estimates]
    np.testing.assert_array_equal(offline.segment.frame_t_s, live_estimate.segment.frame_t_s)
    assert t[broken] not in offline.segment.frame_t_s
    series = estimate_grasp(damaged, "series", settings=SETTINGS, calibration=calibration)
    assert series.state != "insufficient_data" and "skipped 1 frames of finger 'left': " in series.reason


@pytest.mark.parametrize("tactile", [True, False])
def test_frames_are_distinct_loading_positions_that_restrict_the_measurements_with_or_without_tactile(
        calibration, tactile):
    stream = GraspStream.from_record(build_record(3e5), settings=SETTINGS, calibration=calibration)
    segment = stream.segment()
    count = segment.frame_index.size
    every = stream.measurements(segment, tactile=False)
    last = stream.measurements(segment, frames=np.array([count - 1]), tactile=tactile)
    for name in ("t_s", "force_n", "width_m", "approach_m"):
        np.testing.assert_array_equal(getattr(last, name), getattr(every, name)[-1:])
    for bad in ([count], [-1], [0, 0], [0.5]):  # one past the last loading frame, a negative, a repeat, a float
        with pytest.raises(FitError, match=rf"expected distinct positions 0\.\.{count - 1} of the loading frames"):
            stream.measurements(segment, frames=np.array(bad), tactile=tactile)


def test_hold_frames_are_measured_only_when_the_fits_use_them(calibration):
    record = build_record(3e5, width_delay_s=0.1, hold_s=0.5)
    lagged = measure_grasp(record, settings=SETTINGS, calibration=calibration, correct_width_lag=True)
    assert lagged.width_lag_s is not None and len(lagged.hold_features) == lagged.segment.hold_index.size > 0
    hold = lagged.segment.hold_index
    uncorrected = measure_grasp(only_frames(record, np.setdiff1d(np.arange(record.frames[0].t_s.size), hold)),
                                settings=SETTINGS, calibration=calibration)  # hold frames never decoded
    assert uncorrected.hold_features is None and uncorrected.hold_force_n.size == hold.size


def test_a_reference_needs_a_frame_before_the_onset(calibration):
    record = build_record(3e5, frame_times=np.arange(0.62, 0.9, 1 / 30))
    segment = measure_grasp(record, settings=SETTINGS, tactile=False).segment
    with pytest.raises(PerceptionError, match="no-contact reference"):
        no_contact_reference(record, "left", segment)


@pytest.mark.parametrize("n", [1, 2, 3, 4, 5, 6])
def test_median_frame_is_numpys_median_rounded(n):
    frames = np.random.default_rng(n).integers(0, 256, (n, 30, 40, 3), dtype=np.uint8)
    frames[:, 0, 0], frames[0, 1, 1], frames[-1, 1, 1] = 7, 255, 254  # ties and extremes
    median = median_frame(frames)
    assert median.dtype == np.uint8
    np.testing.assert_array_equal(median, np.rint(np.median(frames, axis=0)).astype(np.uint8))


# --------------------------------------------------------------------------- commands


@pytest.fixture(scope="module")
def grasp_dir(tmp_path_factory, calibration):
    root = tmp_path_factory.mktemp("grasps")
    cal_path = calibration.save(root / "cal.npz")
    objects = [("ball_rubber", 3e5, "rubber", "sphere"), ("ball_soft", 1e5, "rubber", "sphere"),
               ("ball_steel", STEEL, "metal", "sphere")]
    for i, (name, e_pa, material, shape) in enumerate(objects):
        label = Label(object_name=name, modulus_pa=e_pa, material=material, shape=shape)
        write_record(build_record(e_pa, seed=i, label=label), root / f"{name}.grasp")
    write_record(build_record(3e5, seed=9), root / "unlabelled.grasp")
    return root, cal_path


def test_estimate_command_prints_json(grasp_dir, capsys):
    root, cal = grasp_dir
    assert main(["estimate", str(root / "ball_rubber.grasp"), "--method", "series", "--calibration", str(cal),
                 "--json"]) == 0
    out = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert out["state"] == "ok" and out["latency_ms"] > 0
    low, high = out["interval_pa"]
    assert low <= out["E_pa"] <= high
    assert main(["estimate", str(root / "ball_steel.grasp"), "--method", "series", "--calibration", str(cal),
                 "--json"]) == 0
    out = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert out["state"] == "lower_bound" and out["interval_pa"][1] is None


def test_estimate_command_reads_folders_and_names_the_records_it_cannot_read(grasp_dir, capsys, tmp_path):
    root, cal = grasp_dir
    bad = tmp_path / "bad.grasp"
    bad.write_text("not a record")
    options = ["--method", "series", "--calibration", str(cal), "--json"]
    assert main(["estimate", str(root), str(bad), *options]) == 2
    captured = capsys.readouterr()
    lines = [json.loads(line) for line in captured.out.strip().splitlines()]
    assert [line["grasp"] for line in lines] == [*map(str, sorted(root.rglob("*.grasp"))), str(bad)]
    assert all(line["state"] for line in lines[:-1]) and "not a grasp record" in lines[-1]["error"]
    [error] = captured.err.strip().splitlines()  # names the record, once
    assert error.startswith("estimator estimate: error: ") and error.count(str(bad)) == 1
    assert error.endswith(lines[-1]["error"])
    # The untimed first estimate changes no answer: each record reads as it does on its own.
    for line in lines[:-1]:
        assert main(["estimate", line["grasp"], *options]) == 0
        alone = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
        assert {k: alone[k] for k in ("E_pa", "interval_pa", "state", "reason")} == {
            k: line[k] for k in ("E_pa", "interval_pa", "state", "reason")}
    empty = tmp_path / "empty"
    empty.mkdir()
    assert main(["estimate", str(empty)]) == 2
    assert "no .grasp record" in capsys.readouterr().err


def test_estimate_command_names_an_empty_folder_as_it_does_a_missing_record_and_estimates_the_others(
        grasp_dir, capsys, tmp_path):
    root, cal = grasp_dir
    empty, missing = tmp_path / "empty", tmp_path / "missing.grasp"
    empty.mkdir()
    assert main(["estimate", "--method", "series", "--calibration", str(cal), "--json",
                 str(root / "ball_rubber.grasp"), str(empty), str(missing)]) == 2
    captured = capsys.readouterr()
    good, folder, absent = (json.loads(line) for line in captured.out.strip().splitlines())
    assert good["grasp"] == str(root / "ball_rubber.grasp") and good["state"] == "ok"
    assert folder == {"grasp": str(empty), "error": f"{empty}: a folder with no .grasp record in it"}
    assert absent["grasp"] == str(missing) and "no such grasp record" in absent["error"]
    errors = captured.err.strip().splitlines()
    assert len(errors) == 2 and all(e.startswith("estimator estimate: error: ") for e in errors)
    assert errors[0].count(str(empty)) == 1


def test_estimate_command_answers_as_the_live_service_by_default(grasp_dir, capsys):
    root, cal = grasp_dir
    assert main(["estimate", str(root / "ball_rubber.grasp"), "--calibration", str(cal), "--json"]) == 0
    out = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    # The service's default: auto mode over the shipped model, which names itself.
    assert out["method"] == "auto" and out["model"].startswith("default-")


def test_estimate_command_errors_are_one_line(grasp_dir, capsys):
    root, _ = grasp_dir
    assert main(["estimate", str(root / "ball_rubber.grasp"), "--method", "hertz"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "calibration" in err
    assert main(["estimate", str(root / "missing.grasp")]) == 2
    assert "no such grasp record" in capsys.readouterr().err


@pytest.mark.slow
def test_evaluate_command_summarises_every_method(grasp_dir, capsys, tmp_path):
    root, cal = grasp_dir
    png = tmp_path / "pred.png"
    assert main(["evaluate", str(root), "--calibration", str(cal), "--json", "--plot", str(png)]) == 0
    out = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert out["records"] == 4 and out["labelled"] == 3 and out["skipped"] == {"unlabelled": 1}
    # Every analytical method, and the shipped model's hybrid with its auto policy.
    assert set(out["methods"]) == {*METHODS, "hybrid", "auto"}
    series = out["methods"]["series"]
    assert series["n"] == 3 and series["states"]["lower_bound"] == 1 and series["states"]["ok"] == 2
    assert series["log10_error"] >= 0 and 0 <= series["within_10x"] <= 1
    assert set(series["per_material"]) == {"metal", "rubber"} and set(series["per_shape"]) == {"sphere"}
    assert out["methods"]["hertz"]["paper"] == {"log10_error": 1.68, "within_10x": 0.289}
    assert out["methods"]["series"]["paper"] is None
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert main(["evaluate", str(root), "--calibration", str(cal), "--json", "--workers", "2"]) == 0
    parallel = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert parallel["methods"] == out["methods"]


def test_evaluate_help_says_how_bounds_and_refusals_count(capsys):
    with pytest.raises(SystemExit):
        main(["evaluate", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "bound with its bound value" in text and "refusals" in text
    assert "geometric middle of the bound" in text and "1e12 Pa" in text
    for option in ("--methods", "--workers", "--plot", "--calibration", "--settings", "--json"):
        assert option in text


def test_evaluate_without_records_is_an_error(tmp_path, capsys):
    assert main(["evaluate", str(tmp_path)]) == 2
    assert "no .grasp records" in capsys.readouterr().err


def test_an_approach_no_width_read_saw_gives_only_a_lower_bound(calibration):
    # A stiff object loads within one 10 Hz width period: the widths bracket the stop of the fingers,
    # so the approach interpolated between them is too large and E only bounded below.
    # Touch at 0.31 s, peak ~60 ms later; widths are read at 0.303 s and 0.403 s.
    record = build_record(5e7, target_n=20.0, radius_m=0.2, speed=0.075, gap_m=0.31 * 0.075)
    stiff = measure_grasp(record, settings=SETTINGS, calibration=calibration)
    assert "width_unread" in stiff.segment.flags
    assert estimate_grasp(stiff, "no_tactile", settings=SETTINGS).state == "lower_bound"
    for method in ("no_tactile", "elastic", "series"):
        est = estimate_grasp(stiff, method, settings=SETTINGS)
        assert est.state != "ok" and (est.state != "lower_bound" or est.e_pa <= 5e7), (method, est)
    # A soft one loads over several width readings: nothing to bound.
    soft = measure_grasp(build_record(3e5), settings=SETTINGS, calibration=calibration)
    assert "width_unread" not in soft.segment.flags
    assert estimate_grasp(soft, "no_tactile", settings=SETTINGS).state == "ok"
