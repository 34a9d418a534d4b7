"""Table optics: frames rendered through a real GelSight's measured tables (teleop.sim.table_optics)."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import cv2
import numpy as np
import pytest

from estimator.cli import main as estimator_main
from estimator.perception import (
    fit_sphere,
    load_calibration,
    load_presses,
    reconstruct_depth,
    split_presses,
)
from teleop.cli import main as teleop_main
from teleop.errors import SimulationError
from teleop.settings import CONFIG_DIR, load_settings
from teleop.sim import table_optics
from teleop.sim.optics import OpticsRenderer
from teleop.sim.presses import contact_radius_m, sphere_press_height
from teleop.sim.table_optics import (
    TableCamera,
    colour_change,
    feature_planes,
    load_tables,
    lookup_tables,
)

RIGS = {"gelsight": CONFIG_DIR / "rigs" / "gelsight.toml", "gelsight_mini": CONFIG_DIR / "rigs" / "gelsight_mini.toml"}
BALL_RADIUS_M = 2.0e-3


@pytest.fixture(scope="module")
def calib_dir(taxim_calib_dir) -> Path:
    return taxim_calib_dir


@pytest.fixture(scope="module")
def rig(taxim_calib_dir):
    return load_settings(RIGS["gelsight"])


@pytest.fixture(scope="module")
def sensor(rig):
    return rig.sensor("left")


def camera(sensor, sim, seed=0, **changes):
    return OpticsRenderer(sensor, sim=dataclasses.replace(sim, **changes), rng=np.random.default_rng(seed))


def ball(sensor, center_px, depth_m=0.6e-3):
    return sphere_press_height(sensor.image_shape, center_px=center_px, ball_radius_m=BALL_RADIUS_M,
                               depth_m=depth_m, pixel_pitch_m=sensor.pixel_pitch_m)


def decode(jpeg: bytes) -> np.ndarray:
    return cv2.imdecode(np.frombuffer(jpeg, np.uint8), cv2.IMREAD_COLOR)


def test_optics_dispatch_and_the_default_rig_is_unchanged(sensor, rig):
    assert type(OpticsRenderer(sensor, sim=rig.simulation, rng=np.random.default_rng(0))) is TableCamera
    default = load_settings()
    assert [s.optics for s in default.sensors] == ["wedge", "wedge"]
    assert default.simulation.illumination_gain == 1.0
    assert type(OpticsRenderer(default.sensor("left"), sim=default.simulation, rng=np.random.default_rng(0))) \
        is OpticsRenderer
    with pytest.raises(SimulationError, match="no measured tables"):
        TableCamera(default.sensor("left"), sim=default.simulation, rng=np.random.default_rng(0))


def test_no_contact_frame_is_the_recorded_f0_up_to_noise(sensor, rig, calib_dir):
    with np.load(calib_dir / "gelsight" / "dataPack.npz") as pack:
        f0 = pack["f0"]
    cam = camera(sensor, rig.simulation)
    zero = np.zeros(sensor.image_shape)
    np.testing.assert_array_equal(cam.render(zero), f0)
    np.testing.assert_array_equal(cam.rest_frame, f0)
    captured = decode(cam.capture(zero)).astype(np.float64) - f0
    assert abs(captured.mean()) < 0.3
    # Camera noise (2 levels) through JPEG at 90: a little less, never a structured change.
    assert 0.8 < captured.std() < 2.5
    assert np.percentile(np.abs(captured), 99.9) < 12


def test_a_ball_changes_colour_where_and_only_where_the_gel_moved(sensor, rig):
    cam = camera(sensor, rig.simulation)
    centre = (300.0, 220.0)  # grid px (x, y)
    change = cam.render(ball(sensor, centre)).astype(np.float64) - cam.background
    contact_px = contact_radius_m(BALL_RADIUS_M, 0.6e-3) / sensor.pixel_pitch_m
    rows, cols = np.indices(change.shape[:2])
    c = sensor.crop_px  # identity warp: raw = grid + crop
    r = np.hypot(cols - centre[0] - c, rows - centre[1] - c)
    magnitude = np.abs(change).max(axis=-1)
    # The height is blurred by 2 px before it is differentiated: its reach is 4 sigma + 1.
    assert (magnitude[r > contact_px + 10] == 0).all()
    inside = (r > 0.3 * contact_px) & (r < 0.9 * contact_px)
    assert np.median(magnitude[inside]) > 10
    assert (magnitude[inside] >= 2).mean() > 0.99
    # Opposite sides of the ball slope opposite ways: their colours move opposite ways.
    left = change[(np.abs(rows - centre[1] - c) < 5) & (np.abs(cols - centre[0] - c + 0.6 * contact_px) < 5)]
    right = change[(np.abs(rows - centre[1] - c) < 5) & (np.abs(cols - centre[0] - c - 0.6 * contact_px) < 5)]
    assert (np.sign(left.mean(axis=0)) == -np.sign(right.mean(axis=0))).all()


@pytest.mark.parametrize("optics", ["gelsight", "gelsight_mini"])
@pytest.mark.parametrize(("mag_bin", "dir_bin"), [(9, 3), (30, 70), (60, 111)])
def test_colour_change_follows_the_measured_polynomial(optics, mag_bin, dir_bin, calib_dir):
    # A tilted plane has one gradient everywhere: put it at the centre of a table bin, where the
    # interpolation gives the bin's own polynomial, and evaluate that polynomial by hand.
    settings = load_settings(RIGS[optics])
    sensor = settings.sensor("left")
    with np.load(calib_dir / optics / "polycalib.npz") as poly:
        tables = [poly[name] for name in ("grad_r", "grad_g", "grad_b")]  # B, G, R of the frames
    bins = tables[0].shape[0]
    magnitude = math.tan((mag_bin + 0.5) * 0.5 * math.pi / (bins - 1))
    direction = -math.pi + (dir_bin + 0.5) * 2.0 * math.pi / (bins - 1)  # atan2(dz/dy, dz/dx)
    gx, gy = magnitude * math.cos(direction), magnitude * math.sin(direction)
    rows, cols = np.indices(sensor.image_shape, dtype=np.float64)
    height = (gx * cols + gy * rows) * sensor.pixel_pitch_m
    height -= height.min()
    cam = camera(sensor, settings.simulation)
    frame = cam.render(height).astype(np.float64)
    c = sensor.crop_px
    for y, x in [(240, 320), (100, 100), (400, 560), (60, 500)]:  # raw px, away from the grid's edges
        terms = np.array([x * x, y * y, x * y, x, y, 1.0])
        expected = [t[mag_bin, dir_bin] @ terms - t[0, dir_bin] @ terms for t in tables]
        want = np.clip(cam.background[y, x] + np.array(expected), 0, 255)
        np.testing.assert_allclose(frame[y, x], want, atol=0.51 + 1e-6)
        assert rows[0, 0] == 0 and c <= y < c + sensor.image_shape[0]
    # The pure function agrees to float precision on a patch.
    lookup = lookup_tables(optics)
    slopes = [np.full((3, 4), s / 0.02, np.float32) for s in (gx, gy)]
    features = feature_planes((480, 640))[:, 200:203, 300:304]
    got = colour_change(lookup, features, *slopes, slope_unit=0.02)
    x, y = 301, 201
    terms = np.array([x * x, y * y, x * y, x, y, 1.0])
    expected = [t[mag_bin, dir_bin] @ terms - t[0, dir_bin] @ terms for t in tables]
    np.testing.assert_allclose(got[1, 1], expected, atol=1e-3)


def test_a_real_press_rendered_from_its_geometry_looks_like_the_recording(sensor, rig, calib_dir):
    # Within the contact the table reproduces the recorded presses: measured correlation 0.99 near
    # the pad's centre, 0.82-0.97 towards its edges (median 0.97 over the 48). Outside the contact
    # the real gel sinks in around the ball, which a bare spherical cap does not.
    with np.load(calib_dir / "gelsight" / "dataPack.npz") as pack:
        f0, images = pack["f0"].astype(np.float32), pack["imgs"]
        centres, radii = pack["touch_center"], pack["touch_radius"]
    cam = camera(sensor, rig.simulation)
    c, r_px = sensor.crop_px, BALL_RADIUS_M / sensor.pixel_pitch_m
    rows, cols = np.indices(f0.shape[:2])
    correlations, gains = [], []
    for i, image in enumerate(images):
        contact_px = 0.9 * radii[i]  # the set draws its circles a few px wide
        depth_m = (r_px - math.sqrt(r_px**2 - contact_px**2)) * sensor.pixel_pitch_m
        rendered = cam.render(ball(sensor, (centres[i][0] - c, centres[i][1] - c), depth_m)) - f0
        real = cv2.GaussianBlur(image.astype(np.float32) - f0, (0, 0), 1.0)
        inside = np.hypot(cols - centres[i][0], rows - centres[i][1]) < 0.9 * contact_px
        correlations.append(np.corrcoef(rendered[inside].ravel(), real[inside].ravel())[0, 1])
        gains.append((rendered[inside] * real[inside]).sum() / (rendered[inside] ** 2).sum())
    correlations = np.array(correlations)
    assert np.median(correlations) > 0.95 and correlations.min() > 0.7
    assert (correlations[[0, 8, 20, 24]] > 0.98).all()  # presses near the centre
    assert 0.9 < np.median(gains) < 1.25


def test_illumination_gain_scales_the_change_in_both_optics(sensor, rig):
    wedge = load_settings()
    for s, sim in ((sensor, rig.simulation), (wedge.sensor("left"), wedge.simulation)):
        height = ball(s, (150.0, 120.0), 0.8e-3)
        base, brighter = (camera(s, sim, illumination_gain=g) for g in (1.0, 1.4))
        assert base.rest_frame is not None
        np.testing.assert_array_equal(base.rest_frame, brighter.rest_frame)
        unit = base.render(height).astype(np.float64) - base.rest_frame
        scaled = brighter.render(height).astype(np.float64) - brighter.rest_frame
        free = (base.render(height) > 5) & (base.render(height) < 250) & (brighter.render(height) < 250)
        np.testing.assert_allclose(scaled[free], 1.4 * unit[free], atol=1.21)
        assert np.abs(unit).max() > 20


def test_frames_are_deterministic_per_seed(sensor, rig):
    height = ball(sensor, (200.0, 150.0))
    bases = np.stack([height, 0.5 * height])
    weights = np.array([[0.0, 0.0], [0.0, 1.0], [1.0, 0.0], [1.0, 0.0]])

    def run(seed):
        cam = camera(sensor, rig.simulation, seed=seed)
        return [cam.capture(height), *cam.capture_series(bases, weights)]

    first = run(3)
    assert run(3) == first
    assert run(4) != first
    frames = camera(sensor, rig.simulation).render_series(bases, weights)
    np.testing.assert_array_equal(frames[2], camera(sensor, rig.simulation).render(height))
    assert frames[2] is frames[3]


def test_markers_darken_the_gel_and_move_with_it(sensor, rig):
    marked = dataclasses.replace(sensor, markers=True)
    cam = camera(marked, rig.simulation)
    rest = cam.rest_frame.astype(np.float64)
    assert (rest <= cam.background + 0.5).all() and (rest < cam.background - 20).any()
    pressed = cam.render(ball(marked, (300.0, 220.0), 0.8e-3))
    assert np.any(pressed != cam.rest_frame)


def test_mistakes_are_named(sensor, rig, monkeypatch):
    # The raw size is checked before the background, whose size error would also name 480.
    with pytest.raises(SimulationError, match="800x480 px raw frame: .* tables were measured on 640x480 px frames"):
        TableCamera(dataclasses.replace(sensor, raw_width_px=800, warp_corners_px=(
            (0.0, 0.0), (800.0, 0.0), (0.0, 480.0), (800.0, 480.0)), warped_width_px=800),
            sim=rig.simulation, rng=np.random.default_rng(0))
    monkeypatch.setattr(table_optics.importlib.util, "find_spec", lambda name: None)
    with pytest.raises(SimulationError, match="pip install taxim"):
        table_optics.calibration_dir("gelsight")


@pytest.mark.parametrize("optics", ["gelsight", "gelsight_mini"])
def test_the_height_blur_is_taxims_two_raw_pixels(optics, taxim_calib_dir):
    # params.json gives the sigmas relative to the frame's width and height: unscaled, they would
    # blur by 0.004 px, i.e. not at all, and sharpen every press rim.
    assert load_tables(optics).blur_px == pytest.approx(2.0)


@pytest.mark.parametrize("optics", ["gelsight", "gelsight_mini"])
def test_the_colour_is_continuous_across_the_slope_direction_of_plus_minus_pi(optics, taxim_calib_dir):
    # A slope facing -x has direction +-pi: its colour must not depend on whether its dz/dy is a
    # hair above or below zero (the lookup's wrap-around columns).
    lookup, features = lookup_tables(optics), feature_planes((480, 640))[:, 200:201, 300:302]
    for steep in (0.05, 0.3, 1.0):  # slopes in units of 1 (slope_unit 1)
        slope_x = np.full((1, 2), -steep, np.float32)
        slope_y = np.array([[1e-4, -1e-4]], np.float32) * steep
        change = colour_change(lookup, features, slope_x, slope_y)
        across = colour_change(lookup, features, slope_x, np.zeros((1, 2), np.float32))
        assert np.abs(change[0, 0] - change[0, 1]).max() <= 0.05 * max(1.0, np.abs(across).max()), (steep, change)


@pytest.mark.parametrize("optics", ["gelsight", "gelsight_mini"])
def test_the_rigs_name_calibrations_fitted_for_their_sensors(optics, taxim_calib_dir):
    settings = load_settings(RIGS[optics])
    tables = load_tables(optics)
    for s in settings.sensors:
        assert s.optics == optics and (s.raw_height_px, s.raw_width_px) == tables.raw_shape
        assert s.pixel_pitch_m == pytest.approx(tables.pixel_pitch_m)
        calibration = load_calibration(CONFIG_DIR / s.calibration)
        assert calibration.image_shape == s.image_shape
        assert calibration.pixel_pitch_m == pytest.approx(s.pixel_pitch_m)
        assert calibration.ball_radius_m == BALL_RADIUS_M


@pytest.mark.slow
def test_presses_through_the_gelsight_tables_calibrate_to_the_ball(tmp_path, rig, sensor):
    # As a user would: simulate presses on the rig, calibrate with `estimator calibrate`, then
    # reconstruct the held-out presses: spheres of the ball's radius.
    rig_file = str(RIGS["gelsight"])
    presses_path, calibration_path = tmp_path / "presses.npz", tmp_path / "cal.npz"
    assert teleop_main(["simulate-presses", "--settings", rig_file, "--finger", "left", "--n", "24",
                        "--seed", "3", "--out", str(presses_path)]) == 0
    assert estimator_main(["calibrate", "--presses", str(presses_path), "--settings", rig_file,
                           "--finger", "left", "--out", str(calibration_path)]) == 0
    calibration = load_calibration(calibration_path)
    presses = load_presses(presses_path).in_sensor_frame(sensor)
    held_out = np.setdiff1d(np.arange(len(presses)), split_presses(len(presses), 0.5))
    fits = [fit_sphere(reconstruct_depth(presses.images[i], presses.reference, calibration),
                       pixel_pitch_m=calibration.pixel_pitch_m) for i in held_out]
    assert all(fits), [f.reason for f in fits if not f]
    radii = np.array([f.radius_m for f in fits])
    # Measured: median radius 1.99 mm, median error 1.2 %, worst 18 % (12 held-out presses).
    assert abs(np.median(radii) - BALL_RADIUS_M) < 0.05 * BALL_RADIUS_M
    assert np.median(np.abs(radii - BALL_RADIUS_M)) < 0.05 * BALL_RADIUS_M
