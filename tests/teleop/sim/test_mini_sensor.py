"""A flat sensor (``model = "mini"``) is simulated as the estimator reads it: its raw frame is its grid."""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np
import pytest

from estimator.perception.grid import to_grid
from teleop.cli import main
from teleop.record import read_record
from teleop.settings import load_settings
from teleop.sim.camera_geometry import pad_view, warp_to_grid
from teleop.sim.optics import OpticsRenderer
from teleop.sim.presses import simulate_presses

# A mini's mirror corners, warped size and crop are not read: the shipped Wedge's (crop 25, which
# the simulator used to crash on) and a crop of 0 with the warped size = raw size (which it used to
# render silently through the Wedge's mirror homography).
GEOMETRIES = {
    "wedge corners, crop 25": {},
    "wedge corners, crop 0": {"crop_px": 0, "warped_width_px": 640, "warped_height_px": 480},
}


@pytest.fixture(scope="module")
def settings():
    return load_settings()


@pytest.mark.parametrize("finger", ["left", "right"])  # the right finger has markers
@pytest.mark.parametrize("geometry", GEOMETRIES.values(), ids=GEOMETRIES.keys())
def test_press_circles_are_where_the_estimator_sees_the_presses(settings, finger, geometry):
    mini = dataclasses.replace(settings.sensor(finger), model="mini", **geometry)
    camera = OpticsRenderer(mini, sim=settings.simulation, rng=np.random.default_rng(0))
    pack = simulate_presses(camera, n=3, ball_radius_m=2e-3, depth_range_m=(0.5e-3, 1.0e-3),
                            rng=np.random.default_rng(1))
    assert pack["imgs"].shape[1:3] == mini.image_shape == (480, 640)

    def seen(frame):  # as the estimator reads the sensor's frames
        return cv2.GaussianBlur(to_grid(frame, mini, binning=1).astype(np.float32), (0, 0), 1.5)

    rest = seen(pack["f0"])
    for img, (x, y), radius in zip(pack["imgs"], pack["touch_center"], pack["touch_radius"], strict=True):
        change = np.abs(seen(img) - rest).sum(axis=-1)
        ys, xs = np.nonzero(change > 20)  # well above noise and JPEG artefacts
        (cx, cy), found_radius = cv2.minEnclosingCircle(np.column_stack([xs, ys]).astype(np.float32))
        assert abs(cx - x) <= 2 and abs(cy - y) <= 2
        assert radius - 3 <= found_radius <= radius + 5


def test_a_mini_pad_is_its_whole_raw_frame_unwarped(settings):
    mini = dataclasses.replace(settings.sensor("left"), model="mini")
    view = pad_view(mini)
    assert (view.width_px, view.height_px, view.crop_px, view.mirrored) == (640, 480, 0, False)
    np.testing.assert_array_equal(view.raw_to_warped, np.eye(3))
    frame = np.random.default_rng(0).integers(0, 256, (480, 640, 3), dtype=np.uint8)
    np.testing.assert_array_equal(warp_to_grid(frame, mini), to_grid(frame, mini, binning=1))
    np.testing.assert_array_equal(warp_to_grid(frame, mini), frame)


@pytest.mark.slow
def test_simulate_renders_a_mini_rig(tmp_path, catalogue, quick_settings, capsys):
    mini_settings = tmp_path / "mini.toml"
    mini_settings.write_text(quick_settings.read_text().replace('model = "wedge"', 'model = "mini"'))
    assert all(s.model == "mini" for s in load_settings(mini_settings).sensors)
    out = tmp_path / "grasps"
    code = main(["simulate", "--objects", str(catalogue), "--seed", "3", "--out", str(out),
                 "--settings", str(mini_settings)])
    assert code == 0, capsys.readouterr().err
    (path,) = out.glob("*.grasp")
    record = read_record(path)
    for stream in record.frames:
        first, last = (cv2.imdecode(np.frombuffer(stream.encoded[i], np.uint8), cv2.IMREAD_COLOR) for i in (0, -1))
        assert first.shape == last.shape == (480, 640, 3)
        # The ball presses the middle of the gel: the middle of the raw frame, not of a mirror's view.
        change = cv2.GaussianBlur(np.abs(last.astype(np.float32) - first).sum(axis=-1), (0, 0), 3.0)
        row, col = np.unravel_index(np.argmax(change), change.shape)
        assert abs(row - 240) < 60 and abs(col - 320) < 60, (stream.finger, row, col)
