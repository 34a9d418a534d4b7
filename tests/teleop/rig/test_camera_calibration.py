"""``teleop calibrate camera`` end to end: the OpenCV camera on a loopback MJPG stream of simulated
Wedge frames, and the serial HX711 over a pseudo-terminal for the latency.

The frames are the simulator's raw Wedge frames (:class:`~teleop.sim.optics.OpticsRenderer`) of a
sensor whose mirror corners the test sets; the settings file given to the command starts with
other corners. For the latency a ball taps the gel on a schedule: the fake firmware writes the
tap's force at 80 Hz, the stream serves each frame as the gel looks ``LATENCY_S`` earlier.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import threading
import time
import tty

import cv2
import numpy as np
import pytest
from support.cameras import FakeFrame, ListCamera

from teleop.cli import main
from teleop.devices.hx711_bridge import FakeHx711
from teleop.errors import DeviceTimeoutError, TeleopError
from teleop.rig import camera_calibration
from teleop.rig.camera_latency import LatencyFit, image_change, measure_latency
from teleop.rig.gel_corners import CornerFit, draw_corners, find_gel_corners
from teleop.settings import SensorSettings, SimulationSettings, default_settings_path, load_settings
from teleop.sim.optics import OpticsRenderer
from teleop.sim.presses import sphere_press_height

FPS = 30.0
TRUE_CORNERS = ((61.3, 72.8), (455.6, 110.2), (48.7, 431.4), (430.9, 380.5))
START_CORNERS = [[46.0, 87.0], [439.0, 121.0], [52.0, 425.0], [446.0, 368.0]]  # the shipped left sensor's
LATENCY_S = 0.1
TAP_PEAK_N = 5.0
TAP_SIGMA_S = 0.05
TAP_EVERY_S = 1.3  # any few seconds of recording hold two taps
TAP_LEVELS = 12  # the tap's depth is rendered at this many steps


def wedge(**changes) -> SensorSettings:
    return SensorSettings(finger="left", serial="test-wedge", warp_corners_px=TRUE_CORNERS, **changes)


def renderer(sensor: SensorSettings) -> OpticsRenderer:
    return OpticsRenderer(sensor, sim=SimulationSettings(), rng=np.random.default_rng(7))


def decode(jpeg: bytes) -> np.ndarray:
    return cv2.imdecode(np.frombuffer(jpeg, np.uint8), cv2.IMREAD_COLOR)


def write_settings(tmp_path, url: str, *, camera_latency_s: float = 0.0, **load_cell) -> os.PathLike:
    path = tmp_path / "rig.toml"
    lines = ["# the rig on the bench", "[sensors.left]", 'model = "wedge"', 'camera_backend = "opencv"',
             f'camera_source = "{url}"', "# read off a picture, roughly", f"warp_corners_px = {START_CORNERS}"]
    if camera_latency_s:
        lines.append(f"camera_latency_s = {camera_latency_s}")
    if load_cell:
        lines += ["", "[load_cell]", *(f"{k} = {json.dumps(v)}" for k, v in load_cell.items())]
    path.write_text("\n".join(lines) + "\n")
    return path


def calibrate(capsys, *argv) -> tuple[int, dict, str]:
    code = main(["calibrate", "camera", *argv, "--json"])
    out, err = capsys.readouterr()
    return code, json.loads(out.strip().splitlines()[-1]), err


# --------------------------------------------------------------------------- corners


@pytest.mark.parametrize("markers", [False, True])
def test_corners_of_a_simulated_wedge_are_recovered_and_written(tmp_path, mjpg_server, capsys, markers):
    sensor = wedge(markers=markers)
    camera = renderer(sensor)
    jpegs = [camera.capture(np.zeros(sensor.image_shape)) for _ in range(20)]
    path = write_settings(tmp_path, mjpg_server(jpegs, fps=FPS).url)
    png = tmp_path / "overlay.png"
    code, report, err = calibrate(capsys, "--settings", str(path), "--out-png", str(png))
    assert code == 0, err
    found = np.array(load_settings(path).sensor("left").warp_corners_px)
    # Measured: at most 0.4 px off without markers, 0.9 px with them.
    np.testing.assert_allclose(found, TRUE_CORNERS, atol=2.0)
    assert report["corners"]["reason"] == "" and report["corners"]["edge_rms_px"] < 1.0
    assert report["changes"][0]["key"] == "sensors.left.warp_corners_px"
    assert report["changes"][0]["old"] == START_CORNERS
    text = path.read_text()
    assert "# read off a picture, roughly" in text and "camera_latency_s" not in text
    overlay = cv2.imread(str(png))
    assert overlay.shape == (480, 640, 3)
    assert np.abs(overlay.astype(int) - decode(jpegs[0]).astype(int)).max() > 100  # lines and labels drawn


def test_a_frame_without_a_gel_is_refused_and_nothing_written(tmp_path, mjpg_server, capsys):
    dark = np.random.default_rng(0).integers(5, 25, (480, 640, 3), dtype=np.uint8)
    jpeg = cv2.imencode(".jpg", dark)[1].tobytes()
    path = write_settings(tmp_path, mjpg_server([jpeg] * 20, fps=FPS).url)
    before = path.read_text()
    code, report, err = calibrate(capsys, "--settings", str(path))
    assert code == 1
    assert "no bright region" in report["corners"]["reason"] and "not changed" in err
    assert report["changes"] == [] and path.read_text() == before
    assert (tmp_path / "rig-left-corners.png").is_file()  # the overlay shows what was seen


def test_a_frame_of_another_size_than_the_settings_is_refused_and_nothing_written(tmp_path, mjpg_server,
                                                                                   capsys):
    sensor = wedge()
    frame = cv2.resize(decode(renderer(sensor).capture(np.zeros(sensor.image_shape))), (960, 720))
    path = write_settings(tmp_path, mjpg_server([cv2.imencode(".jpg", frame)[1].tobytes()] * 20, fps=FPS).url)
    before = path.read_text()
    assert main(["calibrate", "camera", "--settings", str(path)]) == 2
    err = capsys.readouterr().err
    assert "gives 960x720 px frames, but raw_width_px x raw_height_px = 640x480" in err
    assert path.read_text() == before and not (tmp_path / "rig-left-corners.png").exists()


def test_a_gel_off_the_frame_faint_or_with_a_bent_side_is_refused_an_occluded_edge_is_not():
    sensor = wedge()
    frame = renderer(sensor).render(np.zeros(sensor.image_shape))
    size = (sensor.warped_width_px, sensor.warped_height_px)
    shifted = np.zeros_like(frame)
    shifted[:, :-50] = frame[:, 50:]  # the left edge out of view
    assert "runs off the frame" in find_gel_corners(shifted, warped_size_px=size).reason
    assert "levels brighter than the housing" in find_gel_corners(frame // 10, warped_size_px=size).reason
    occluded = frame.copy()
    cv2.circle(occluded, (250, 105), 30, (10, 10, 10), -1)  # a dark speck over the top edge: outvoted
    np.testing.assert_allclose(find_gel_corners(occluded, warped_size_px=size).corners_px, TRUE_CORNERS, atol=1.0)
    bent = np.full_like(frame, 12)
    x = np.linspace(80.0, 560.0, 50)
    # A side bulging by 10 % of its length; a lens's bow of 3 %, as the real Wedge's, is followed (test_gel_corners).
    top = np.column_stack([x, 100.0 - 48.0 * (1.0 - ((x - 320.0) / 240.0) ** 2)])
    cv2.fillPoly(bent, [np.vstack([top, [[560.0, 400.0], [80.0, 400.0]]]).astype(np.int32)], (150, 140, 130))
    fit = find_gel_corners(bent, warped_size_px=size)
    assert not fit and "not straight" in fit.reason
    assert draw_corners(bent, fit).shape == frame.shape


# --------------------------------------------------------------------------- latency


def tap_force_n(t_s: float, t0_s: float) -> float:
    """Taps of TAP_PEAK_N every TAP_EVERY_S from t0_s + 0.8 s, each a Gaussian pulse."""
    phase = (t_s - t0_s - 0.8) % TAP_EVERY_S
    phase = min(phase, TAP_EVERY_S - phase)
    return TAP_PEAK_N * float(np.exp(-0.5 * (phase / TAP_SIGMA_S) ** 2))


class TapFrames:
    """The stream's frames: each shows the gel as the tap pressed it LATENCY_S before it is sent."""

    def __init__(self, camera: OpticsRenderer, t0_s: float):
        sensor = camera.sensor
        self.t0_s = t0_s
        self.jpegs = []
        for depth in np.linspace(0.0, 1.5e-3, TAP_LEVELS):
            height = sphere_press_height(sensor.image_shape, center_px=(175.0, 125.0), ball_radius_m=0.02,
                                         depth_m=depth, pixel_pitch_m=sensor.pixel_pitch_m)
            self.jpegs.append(camera.capture(height))

    def __iter__(self):
        for _ in range(int(30 * FPS)):
            level = tap_force_n(time.monotonic() - LATENCY_S, self.t0_s) / TAP_PEAK_N
            yield self.jpegs[round(level * (TAP_LEVELS - 1))]


@pytest.fixture
def tapping_cell():
    """A serial HX711 on a pseudo-terminal whose firmware reads the taps' force: its port, and t0."""
    master, slave = os.openpty()
    tty.setraw(slave)
    t0 = time.monotonic()
    fake = FakeHx711(counts_per_n=1000.0, rate_hz=80.0, noise_counts=20.0,
                     force_n=lambda _t: tap_force_n(time.monotonic(), t0))
    stop = threading.Event()

    def firmware():
        while not stop.is_set():
            os.write(master, b"%d\r\n" % fake())

    thread = threading.Thread(target=firmware, daemon=True)
    thread.start()
    yield os.ttyname(slave), t0
    stop.set()
    thread.join(timeout=1.0)
    os.close(master)
    os.close(slave)


@pytest.mark.slow
@pytest.mark.parametrize("configured_s", [0.0, 0.04])
def test_latency_against_the_load_cell_is_measured_from_taps(tmp_path, mjpg_server, tapping_cell, capsys,
                                                             configured_s):
    # A latency already configured shifts the frames the calibration reads: it measures the rest.
    port, t0 = tapping_cell
    sensor = wedge()
    server = mjpg_server(TapFrames(renderer(sensor), t0), fps=FPS)
    path = write_settings(tmp_path, server.url, camera_latency_s=configured_s, backend="serial", port=port,
                          counts_per_n=1000.0)
    code, report, err = calibrate(capsys, "--settings", str(path), "--latency", "--duration-s", "3")
    assert code == 0, err
    latency = load_settings(path).sensor("left").camera_latency_s
    # Measured: 0.097 to 0.099 s (the pty delivers the force a few ms late).
    assert latency == pytest.approx(LATENCY_S, abs=1.0 / FPS)
    assert report["latency"]["correlation"] > 0.8
    assert [c["key"] for c in report["changes"]] == ["sensors.left.warp_corners_px", "sensors.left.camera_latency_s"]
    assert "tap the gel" in err


def test_simulated_devices_have_nothing_to_calibrate(capsys):
    assert main(["calibrate", "camera", "--settings", str(default_settings_path())]) == 2
    assert "simulated" in capsys.readouterr().err


def test_latency_is_refused_without_a_tap_or_when_the_signals_disagree():
    rng = np.random.default_rng(0)
    t_force = np.arange(0.0, 4.0, 1 / 80)
    t_frame = np.arange(0.0, 4.0, 1 / FPS) + 0.01
    force = np.array([tap_force_n(t, 0.0) for t in t_force]) + rng.normal(0, 0.02, t_force.size)
    change = 1.2 + np.array([tap_force_n(t - 0.05, 0.0) for t in t_frame]) / 5 + rng.normal(0, 0.01, t_frame.size)
    fit = measure_latency(t_frame, change, t_force, force)
    assert fit and fit.latency_s == pytest.approx(0.05, abs=0.01)
    assert "no tap in the force" in measure_latency(t_frame, change, t_force, rng.normal(0, 0.02, t_force.size)).reason
    assert "no tap in the image" in measure_latency(t_frame, 1.2 + rng.normal(0, 0.01, t_frame.size),
                                                    t_force, force).reason
    unrelated = 1.2 + (np.sin(7 * t_frame) > 0.9) + rng.normal(0, 0.01, t_frame.size)
    assert not measure_latency(t_frame, unrelated, t_force, force)
    assert "overlap" in measure_latency(t_frame + 10.0, change, t_force, force).reason


def test_image_change_is_the_mean_absolute_difference_to_the_gel_at_rest():
    rest = np.full((4, 4, 3), 100, np.uint8)
    assert image_change([rest + 2, rest, rest - 3], rest).tolist() == [2.0, 0.0, 3.0]


def test_a_rest_frame_between_two_levels_is_not_rounded():
    # the median of an even number of frames: half-way between 127 and 128
    rest = np.median(np.stack([np.full((2, 2), 127, np.uint8), np.full((2, 2), 128, np.uint8)]), axis=0)
    assert image_change([np.full((2, 2), 128, np.uint8)], rest).tolist() == [0.5]


def test_a_read_only_settings_file_is_refused_before_the_camera_is_read(tmp_path, capsys, monkeypatch):
    path = write_settings(tmp_path, "http://127.0.0.1:1/stream.mjpg")
    path.chmod(0o444)
    monkeypatch.setattr(camera_calibration, "make_camera", lambda sensor: pytest.fail("the camera was read"))
    assert main(["calibrate", "camera", "--settings", str(path)]) == 2
    assert f"error: settings file {path} is read-only (mode 444)" in capsys.readouterr().err


@pytest.mark.parametrize("duration_s", ["inf", "nan", "0"])
def test_a_duration_that_is_no_finite_time_is_refused_before_the_camera_is_read(duration_s, tmp_path, capsys,
                                                                                monkeypatch):
    monkeypatch.setattr(camera_calibration, "make_camera", lambda sensor: pytest.fail("the camera was read"))
    with pytest.raises(SystemExit) as exited:
        main(["calibrate", "camera", "--settings", str(write_settings(tmp_path, "http://127.0.0.1:1/x.mjpg")),
              "--latency", "--duration-s", duration_s])
    assert exited.value.code == 2 and f"--duration-s: {duration_s!r}: expected a number > 0" in capsys.readouterr().err


# --------------------------------------------------------------------------- the steps, with fake devices


def test_the_no_contact_frame_leaves_out_the_frames_while_exposure_settles():
    camera = ListCamera([FakeFrame(0.0, 10)] * 5 + [FakeFrame(0.0, 200)] * 5)  # dark while exposure settles
    frame = camera_calibration.no_contact_frame(camera)
    assert frame.dtype == np.uint8 and (frame == 200).all()


def test_a_tap_recording_drops_frames_stamped_before_it_began():
    class Cell:
        def read(self, timeout_s=None):
            raise DeviceTimeoutError("nothing")

    stale = [FakeFrame(-5.0, 0), FakeFrame(-4.0, 0)]  # queued before the recording
    frames, force = camera_calibration.record_tap(ListCamera(stale), Cell(), duration_s=0.02)
    assert frames == [] and len(force) == 0


def test_an_overlay_png_that_cannot_be_written_is_an_error(tmp_path):
    sensor = SensorSettings(finger="left", serial="test-wedge")
    frame = np.zeros((sensor.raw_height_px, sensor.raw_width_px, 3), np.uint8)
    with pytest.raises(TeleopError, match="cannot write the overlay PNG there"):
        camera_calibration._corners(frame, sensor, tmp_path / "no such folder" / "corners.png")


def test_refused_corners_write_nothing_and_no_tap_is_asked_for(tmp_path, monkeypatch, capsys):
    path = tmp_path / "rig.toml"
    path.write_text('[sensors.left]\nmodel = "wedge"\ncamera_backend = "opencv"\ncamera_source = "0"\n\n'
                    '[load_cell]\nbackend = "serial"\nport = "/dev/ttyUSB9"\n')
    before = path.read_bytes()
    taps = []
    monkeypatch.setattr(camera_calibration, "make_camera",
                        lambda sensor: contextlib.nullcontext(argparse.Namespace(sensor=sensor)))
    monkeypatch.setattr(camera_calibration, "no_contact_frame", lambda camera: None)
    monkeypatch.setattr(camera_calibration, "_declared_size", lambda frame, sensor, path: frame)
    monkeypatch.setattr(camera_calibration, "_corners", lambda frame, sensor, png: CornerFit(reason="no gel"))
    monkeypatch.setattr(camera_calibration, "_latency", lambda *a: taps.append(a) or LatencyFit(latency_s=0.05))
    args = argparse.Namespace(settings=str(path), finger="left", out_png=None, latency=True, duration_s=1.0, json=True)
    assert camera_calibration.run(args) == 1
    assert taps == [] and path.read_bytes() == before
    assert "camera refused: corners: no gel" in capsys.readouterr().err


def test_a_flat_sensor_without_latency_is_refused_before_the_camera_is_read(tmp_path, monkeypatch, capsys):
    path = tmp_path / "rig.toml"
    path.write_text('[sensors.left]\nmodel = "mini"\ncamera_backend = "opencv"\ncamera_source = "0"\n')
    monkeypatch.setattr(camera_calibration, "make_camera",
                        lambda sensor: (_ for _ in ()).throw(AssertionError("the camera was opened")))
    assert main(["calibrate", "camera", "--settings", str(path), "--finger", "left"]) == 2
    assert "is a flat sensor (model = 'mini'): it has no mirror corners" in capsys.readouterr().err


# --------------------------------------------------------------------------- latency from recorded signals


def _tap(t, at_s, height, width_s=0.03):
    """A Gaussian bump of ``height`` at ``at_s``."""
    return height * np.exp(-0.5 * ((t - at_s) / width_s) ** 2)


def _signals(latency_s, *, duration_s=4.0, rate_hz=1000.0, force_noise=0.0, change_noise=0.0, tap_n=2.0):
    """(frame times, image change, force times, force) of one tap at 1.5 s seen ``latency_s`` late."""
    rng = np.random.default_rng(3)
    t = np.arange(0.0, duration_s, 1.0 / rate_hz)
    force = _tap(t, 1.5, tap_n) + rng.normal(0.0, force_noise, t.size) if force_noise else _tap(t, 1.5, tap_n)
    change = 1.0 + _tap(t, 1.5 + latency_s, 3.0) + (rng.normal(0.0, change_noise, t.size) if change_noise else 0.0)
    return t, change, t, force


def test_a_latency_between_grid_steps_is_interpolated_to_a_fraction_of_a_step():
    fit = measure_latency(*_signals(0.0337))
    assert fit and fit.latency_s == pytest.approx(0.0337, abs=2e-4)


def test_a_lag_beyond_the_search_window_is_refused_not_clipped():
    fit = measure_latency(*_signals(0.35))
    assert not fit and "at the search limit" in fit.reason and np.isnan(fit.latency_s)


def test_recordings_overlapping_less_than_twice_the_search_window_are_refused():
    fit = measure_latency(*_signals(0.02, duration_s=0.45))
    assert not fit and "overlap for 0.45 s" in fit.reason


def test_three_samples_are_too_little():
    t = np.array([0.0, 2.0, 4.0])
    fit = measure_latency(t, [1.0, 9.0, 1.0], *_signals(0.0)[2:])
    assert not fit and fit.reason.startswith("too little recorded: 3 frames")


def test_a_force_peak_within_its_noise_is_no_tap():
    # 0.3 N tap over the 0.2 N minimum, but the force scatters 0.1 N: 8 noise deviations are needed.
    fit = measure_latency(*_signals(0.03, tap_n=0.3, force_noise=0.1))
    assert not fit and fit.reason.startswith("no tap in the force")


def test_an_image_change_within_its_noise_is_no_tap():
    t, change, tf, force = _signals(0.03)
    rng = np.random.default_rng(4)
    change = 1.0 + _tap(t, 1.53, 0.8) + rng.normal(0.0, 0.2, t.size)  # 0.8 levels over 0.5, noise 0.2
    fit = measure_latency(t, change, tf, force)
    assert not fit and fit.reason.startswith("no tap in the image")


def test_an_image_change_with_events_the_force_lacks_is_refused_as_not_following():
    t, change, tf, force = _signals(0.03)
    change = change + _tap(t, 2.6, 3.0) + _tap(t, 3.4, 3.0)  # two camera-only bumps: not the tap
    fit = measure_latency(t, change, tf, force)
    assert not fit and "does not follow the force" in fit.reason and fit.correlation < 0.7
