"""Tactile optics: the simulated GelSight camera (teleop.sim.optics)."""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np
import pytest
from scipy.spatial import cKDTree

from teleop.errors import SimulationError
from teleop.geometry import raw_to_warped_matrix
from teleop.settings import SimulationSettings
from teleop.sim.camera_geometry import warp_to_grid
from teleop.sim.optics import OpticsRenderer, load_background
from teleop.sim.presses import contact_radius_m, sphere_press_height
from teleop.sim.wedge_optics import procedural_background


@pytest.fixture(scope="module")
def sensor(settings):
    return settings.sensor("left")


@pytest.fixture(scope="module")
def marker_sensor(settings):
    return dataclasses.replace(settings.sensor("left"), markers=True)


@pytest.fixture(scope="module")
def camera(sensor, settings):
    return OpticsRenderer(sensor, sim=settings.simulation, rng=np.random.default_rng(7))


@pytest.fixture(scope="module")
def marker_camera(marker_sensor, settings):
    return OpticsRenderer(marker_sensor, sim=settings.simulation, rng=np.random.default_rng(7))


def press(sensor, *, row, col, radius_m=2e-3, depth_m=0.6e-3):
    return sphere_press_height(sensor.image_shape, center_px=(col, row), ball_radius_m=radius_m,
                               depth_m=depth_m, pixel_pitch_m=sensor.pixel_pitch_m)


def grid_change(camera, frame):
    """Warped-and-cropped frame minus the rest frame, float (rows, cols, 3)."""
    sensor = camera.sensor
    return (warp_to_grid(frame, sensor).astype(np.float64)
            - warp_to_grid(camera.rest_frame, sensor).astype(np.float64))


def decode(jpeg: bytes) -> np.ndarray:
    return cv2.imdecode(np.frombuffer(jpeg, np.uint8), cv2.IMREAD_COLOR)


def test_zero_height_renders_the_background(camera, sensor):
    zero = np.zeros(sensor.image_shape)
    np.testing.assert_array_equal(camera.render(zero), camera.background)
    captured = decode(camera.capture(zero)).astype(np.float64)
    error = captured - camera.background
    assert np.abs(error.mean()) < 0.5
    assert 0.5 < error.std() < 2.0 * camera.sim.camera_noise


def test_capture_is_jpeg_of_the_raw_shape(camera, sensor):
    jpeg = camera.capture(press(sensor, row=100, col=100))
    assert jpeg[:2] == b"\xff\xd8"
    assert decode(jpeg).shape == (480, 640, 3)


def test_noise_has_the_configured_spread(camera):
    flat = np.full((480, 640, 3), 128, np.uint8)
    noise = camera.add_noise(flat).astype(np.float64) - 128
    assert noise.std() == pytest.approx(camera.sim.camera_noise, rel=0.05)
    assert abs(noise.mean()) < 0.02


@pytest.mark.parametrize("which", ["camera", "marker_camera"])
def test_press_changes_only_pixels_near_it_inside_the_pad(request, which):
    camera = request.getfixturevalue(which)
    sensor = camera.sensor
    row, col, depth_m = 80, 240, 0.6e-3
    radius_px = contact_radius_m(2e-3, depth_m) / sensor.pixel_pitch_m
    changed = np.any(camera.render(press(sensor, row=row, col=col, depth_m=depth_m))
                     != camera.rest_frame, axis=-1)
    assert changed.sum() > 0.5 * np.pi * radius_px**2  # a raw px is about a grid px here
    ys, xs = np.nonzero(changed)
    grid = cv2.perspectiveTransform(np.column_stack([xs, ys]).astype(np.float64)[:, None],
                                    raw_to_warped_matrix(sensor))[:, 0]
    assert (grid >= -1).all()
    assert (grid[:, 0] <= sensor.warped_width_px + 1).all()
    assert (grid[:, 1] <= sensor.warped_height_px + 1).all()
    distance = np.hypot(grid[:, 0] - sensor.crop_px - col, grid[:, 1] - sensor.crop_px - row)
    assert distance.max() < radius_px + 6  # membrane blur, slopes and warp reach a few px


def test_distant_presses_render_independently(camera, sensor):
    first, second = press(sensor, row=60, col=60), press(sensor, row=190, col=290)
    both = camera.render(first + second).astype(int)
    alone = camera.render(first).astype(int)
    near_first = (slice(130, 240), slice(90, 220))  # raw px around the first press, far from the second
    assert np.any(alone[near_first] != camera.background[near_first])
    assert np.abs(both[near_first] - alone[near_first]).max() <= 1


@pytest.mark.parametrize("row, col", [(125, 175), (20, 20), (230, 330), (20, 330), (230, 20)])
def test_forward_warp_puts_a_press_back_where_it_was(camera, sensor, row, col):
    change = np.abs(grid_change(camera, camera.render(press(sensor, row=row, col=col)))).sum(-1)
    ys, xs = np.nonzero(change > 10)
    assert len(ys) > 100
    (cx, cy), _ = cv2.minEnclosingCircle(np.column_stack([xs, ys]).astype(np.float32))
    assert abs(cx - col) <= 2 and abs(cy - row) <= 2
    assert abs(xs.mean() - col) <= 2 and abs(ys.mean() - row) <= 2


def test_colour_encodes_slope_direction_like_the_wedge(camera, sensor):
    """Green lights from the left, red from the top, blue from the bottom."""
    row, col, depth_m = 125, 175, 0.8e-3
    radius_px = contact_radius_m(2e-3, depth_m) / sensor.pixel_pitch_m
    change = grid_change(camera, camera.render(press(sensor, row=row, col=col, depth_m=depth_m)))
    rows, cols = np.indices(sensor.image_shape)
    dx, dy = cols - col, rows - row
    ring = (np.hypot(dx, dy) > 0.3 * radius_px) & (np.hypot(dx, dy) < 0.9 * radius_px)
    left, right = ring & (dx < -np.abs(dy)), ring & (dx > np.abs(dy))
    top, bottom = ring & (dy < -np.abs(dx)), ring & (dy > np.abs(dx))
    blue, green, red = (change[..., c] for c in range(3))
    # The press's left flank faces the left light: brighter green there, darker on the right.
    assert green[left].mean() > 10 and green[right].mean() < -10
    assert red[top].mean() > 10 and red[bottom].mean() < -10
    assert blue[bottom].mean() > 10 and blue[top].mean() < -10
    # A flank lit by no light of a colour barely changes in it.
    assert abs(green[top].mean()) < 0.5 * green[left].mean()


def test_a_ramp_facing_the_left_light_brightens_green(camera, sensor):
    rows, cols = sensor.image_shape
    ramp = np.zeros(sensor.image_shape)
    ramp[:, 100:250] = np.arange(150) * sensor.pixel_pitch_m * 0.3  # depth grows to the right
    change = grid_change(camera, camera.render(ramp))[60:190, 120:230]
    blue, green, red = (change[..., c].mean() for c in range(3))
    assert green > 15
    assert green > 3 * abs(red) and green > 3 * abs(blue)


def test_illumination_is_a_property_of_the_sensor_not_of_the_rng(sensor, settings):
    background = procedural_background(sensor, rng=np.random.default_rng(0))
    height = press(sensor, row=60, col=60)
    renders = [
        OpticsRenderer(sensor, sim=settings.simulation, rng=np.random.default_rng(seed),
                      background=background).render(height)
        for seed in (1, 2)
    ]
    np.testing.assert_array_equal(*renders)


def test_same_seed_same_bytes_other_seed_other_bytes(sensor, settings):
    height = press(sensor, row=120, col=200)

    def capture(seed):
        cam = OpticsRenderer(sensor, sim=settings.simulation, rng=np.random.default_rng(seed))
        return [cam.capture(height) for _ in range(2)]

    first = capture(3)
    assert first == capture(3)
    assert first[0] != first[1]  # fresh noise per frame
    assert first != capture(4)


def test_procedural_background_looks_like_a_wedge(sensor):
    frame = procedural_background(sensor, rng=np.random.default_rng(0))
    assert frame.shape == (480, 640, 3) and frame.dtype == np.uint8
    pad = warp_to_grid(frame, sensor).astype(np.float64)
    assert frame[:30, :30].mean() < 40  # dark housing
    assert pad.mean() > 90  # bright gel
    centre = pad[100:150, 150:200].mean(axis=(0, 1))
    # Coloured edges: red along the top, blue along the bottom, green at the left.
    assert pad[:5, 100:250, 2].mean() > centre[2] + 15
    assert pad[-5:, 100:250, 0].mean() > centre[0] + 15
    full = cv2.warpPerspective(frame, raw_to_warped_matrix(sensor), (400, 300)).astype(np.float64)
    assert full[100:200, 1:5, 1].mean() > centre[1] + 30


def test_real_wedge_background_is_used_as_given(shared_dir, sensor, settings):
    background = load_background(shared_dir / "seed" / "wedge_init_frame_raw_640x480.png")
    cam = OpticsRenderer(sensor, sim=settings.simulation, rng=np.random.default_rng(0),
                        background=background)
    np.testing.assert_array_equal(cam.render(np.zeros(sensor.image_shape)), background)
    assert np.any(cam.render(press(sensor, row=125, col=175)) != background)


def test_background_file_from_settings(shared_dir, sensor):
    sim = SimulationSettings(background=str(shared_dir / "seed" / "wedge_init_frame_raw_640x480.png"))
    cam = OpticsRenderer(sensor, sim=sim, rng=np.random.default_rng(0))
    assert cam.background[240, 320].sum() > 300  # the real pad, not a procedural one
    np.testing.assert_array_equal(cam.background, load_background(sim.background))


def dark_dots(frame, sensor):
    """Centroids (x, y) of the marker dots in the grid image of ``frame``."""
    gray = cv2.cvtColor(warp_to_grid(frame, sensor), cv2.COLOR_BGR2GRAY).astype(np.float32)
    dark = (gray < 0.6 * cv2.blur(gray, (15, 15))).astype(np.uint8)
    _, _, stats, centroids = cv2.connectedComponentsWithStats(dark)
    return centroids[1:][stats[1:, cv2.CC_STAT_AREA] >= 5]


def test_markers_move_with_the_given_shear(marker_camera, marker_sensor):
    rows, cols = marker_sensor.image_shape
    rest = dark_dots(marker_camera.rest_frame, marker_sensor)
    assert len(rest) > 100
    shear = np.zeros((rows, cols, 2))
    shear[...] = (0.2e-3, -0.1e-3)  # [d_col, d_row] in metres
    moved = dark_dots(marker_camera.render(np.zeros((rows, cols)), shear_m=shear), marker_sensor)
    _, nearest = cKDTree(moved).query(rest)
    shift = moved[nearest] - rest
    inner = (rest[:, 0] > 30) & (rest[:, 0] < cols - 30) & (rest[:, 1] > 30) & (rest[:, 1] < rows - 30)
    expected = np.array([0.2e-3, -0.1e-3]) / marker_sensor.pixel_pitch_m
    np.testing.assert_allclose(np.median(shift[inner], axis=0), expected, atol=0.3)


def test_markers_flow_outward_under_a_press_without_shear(marker_camera, marker_sensor):
    col, row, radius_m, depth_m = 175, 125, 6e-3, 1.5e-3
    radius_px = contact_radius_m(radius_m, depth_m) / marker_sensor.pixel_pitch_m
    height = press(marker_sensor, row=row, col=col, radius_m=radius_m, depth_m=depth_m)
    rest = dark_dots(marker_camera.rest_frame, marker_sensor)
    moved = dark_dots(marker_camera.render(height), marker_sensor)
    _, nearest = cKDTree(moved).query(rest)
    offset = rest - (col, row)
    distance = np.hypot(*offset.T)
    outward = ((moved[nearest] - rest) * offset).sum(axis=1) / np.maximum(distance, 1e-9)
    inside = (distance > 0.3 * radius_px) & (distance < 0.9 * radius_px)
    assert inside.sum() >= 6
    assert (outward[inside] > 1.0).all()
    assert np.abs(outward[distance > radius_px + 10]).max() < 0.5


def test_no_markers_means_shear_changes_nothing(camera, sensor):
    shear = np.full((*sensor.image_shape, 2), 0.3e-3)
    np.testing.assert_array_equal(camera.render(np.zeros(sensor.image_shape), shear_m=shear),
                                  camera.background)


@pytest.mark.parametrize(
    "height, shear, match",
    [
        (np.zeros((250, 349)), None, "height_m has shape"),
        (np.full((250, 350), np.nan), None, "NaN"),
        (np.zeros((250, 350)), np.zeros((250, 350)), "shear_m has shape"),
        (np.zeros((250, 350), dtype=bool), None, "dtype"),
    ],
)
def test_bad_fields_are_named(camera, height, shear, match):
    with pytest.raises(SimulationError, match=match):
        camera.render(height, shear_m=shear)


def test_bad_backgrounds_are_refused(sensor, settings, tmp_path):
    with pytest.raises(SimulationError, match="background"):
        OpticsRenderer(sensor, sim=settings.simulation, rng=np.random.default_rng(0),
                      background=np.zeros((480, 640), np.uint8))
    with pytest.raises(SimulationError, match="cannot read background"):
        load_background(tmp_path / "missing.png")


@pytest.mark.parametrize("which", ["camera", "marker_camera"])
def test_a_series_renders_each_mix_as_render_would(request, which):
    camera = request.getfixturevalue(which)
    sensor = camera.sensor
    bases = np.stack([press(sensor, row=125, col=175, radius_m=10e-3, depth_m=d) for d in (0.3e-3, 0.8e-3)])
    shears = np.zeros((*bases.shape, 2))
    shears[1, 100:150, 150:200] = (30e-6, -20e-6)
    weights = np.array([[0.0, 0.0], [0.5, 0.0], [0.25, 0.75], [0.0, 1.0], [0.25, 0.75]])
    frames = camera.render_series(bases, weights, shear_m=shears)
    assert len(frames) == len(weights)
    np.testing.assert_array_equal(frames[0], camera.rest_frame)
    for frame, w in zip(frames[1:], weights[1:], strict=True):
        alone = camera.render(np.tensordot(w, bases, axes=1), shear_m=np.tensordot(w, shears, axes=1))
        # Mixing the bases' slopes equals the slopes of the mixed surface up to float rounding.
        assert np.abs(frame.astype(int) - alone).max() <= 1
        assert np.any(frame != camera.rest_frame)
    assert frames[2] is frames[4]  # equal weights: one render


def test_a_series_refuses_bad_weights(camera, sensor):
    bases = np.zeros((2, *sensor.image_shape))
    with pytest.raises(SimulationError, match="weights"):
        camera.render_series(bases, np.ones((3, 3)))
    with pytest.raises(SimulationError, match="weights"):
        camera.render_series(bases, np.full((3, 2), np.nan))
    with pytest.raises(SimulationError, match="height_m has shape"):
        camera.render_series(np.zeros((2, 10, 10)), np.ones((1, 2)))


def test_capture_series_gives_fresh_noise_per_frame(sensor, settings):
    cam = OpticsRenderer(sensor, sim=settings.simulation, rng=np.random.default_rng(5))
    bases = press(sensor, row=125, col=175)[None]
    jpegs = cam.capture_series(bases, np.ones((3, 1)))
    assert len(set(jpegs)) == 3
    again = OpticsRenderer(sensor, sim=settings.simulation, rng=np.random.default_rng(5))
    assert again.capture_series(bases, np.ones((3, 1))) == jpegs


class _RepeatingDraws:
    """Stands in for a camera's rng: draws the given noise-pool offsets in turn."""

    def __init__(self, offsets):
        self.offsets = iter(offsets)

    def integers(self, high):
        return next(self.offsets)


def test_a_camera_never_gives_two_frames_the_same_noise(sensor, settings):
    # Two frames of one scene with identical noise would look like a frozen camera.
    cam = OpticsRenderer(sensor, sim=settings.simulation, rng=np.random.default_rng(3))
    assert cam.sim.camera_noise > 0
    cam.rng = _RepeatingDraws([7, 7, 1000])  # the second frame first draws the first one's offset
    first, second = cam.add_noise(cam.rest_frame), cam.add_noise(cam.rest_frame)
    assert not np.array_equal(first, second)


def test_a_frame_larger_than_the_raw_frame_is_refused(camera, sensor):
    for shape in ((sensor.raw_height_px + 10, sensor.raw_width_px, 3),
                  (4 * sensor.raw_height_px, 4 * sensor.raw_width_px, 3)):
        with pytest.raises(SimulationError, match="larger than the camera's raw frame"):
            camera.add_noise(np.zeros(shape, np.uint8))


def test_the_given_background_is_copied_not_taken_over(sensor, settings):
    # The caller's array stays writable, and the camera's frames do not follow later writes to it.
    given = np.full((sensor.raw_height_px, sensor.raw_width_px, 3), 90, np.uint8)
    cam = OpticsRenderer(sensor, sim=settings.simulation, rng=np.random.default_rng(0), background=given)
    given[:] = 10  # the caller reuses its buffer
    assert int(cam.background[0, 0, 0]) == 90
    assert int(cam.render(np.zeros(sensor.image_shape))[0, 0, 0]) == 90


def test_a_flat_punch_over_the_whole_pad_shades_nothing(camera, sensor):
    # The gel beyond the grid continues at the grid's edge height: a drop back to rest there would
    # be a cliff, shading a bright rim along the grid's border.
    frame = camera.render(np.full(sensor.image_shape, 0.3e-3))
    assert np.abs(frame.astype(int) - camera.rest_frame.astype(int)).max() <= 1


@pytest.mark.slow
def test_noise_is_independent_between_frames_and_pixels(settings, sensor):
    """The pooled noise: right spread, no correlation between frames, neighbours or channels."""
    cam = OpticsRenderer(sensor, sim=settings.simulation, rng=np.random.default_rng(11))
    flat = np.full((480, 640, 3), 128, np.uint8)
    noise = np.stack([cam.add_noise(flat) for _ in range(40)]).astype(np.float64) - 128
    sigma = settings.simulation.camera_noise
    assert noise.std() == pytest.approx(sigma, rel=0.05)
    assert noise.std(axis=0).mean() == pytest.approx(sigma, rel=0.05)  # over time, at each pixel

    def correlation(a, b):
        return float(np.corrcoef(a.ravel(), b.ravel())[0, 1])

    bound = 5 / np.sqrt(noise[0].size)  # five standard errors of a zero correlation
    for i, j in ((0, 1), (0, 39), (17, 18)):
        assert abs(correlation(noise[i], noise[j])) < bound
    assert abs(correlation(noise[:, :, 1:], noise[:, :, :-1])) < bound  # horizontal neighbours
    assert abs(correlation(noise[..., 0], noise[..., 1])) < bound  # blue and green
    # The difference of two frames of one scene: sqrt(2) sigma, as from a real camera.
    assert (noise[3] - noise[4]).std() == pytest.approx(np.sqrt(2) * sigma, rel=0.05)
