"""One contract for every tactile-camera backend: sim replay, OpenCV on a loopback MJPG stream, a real camera."""

from __future__ import annotations

import contextlib
import functools
import http.server
import socketserver
import threading
from dataclasses import dataclass

import cv2
import numpy as np
import pytest
from support.contract import assert_every_backend_covered, param_names
from support.threads import close_during_read

from teleop.devices.camera import BACKENDS, CameraFrame, TactileCamera, make_camera
from teleop.devices.playback import GraspPlayback
from teleop.errors import (
    BackendNotFoundError,
    DeviceError,
    DeviceNotConnectedError,
    DeviceTimeoutError,
)
from teleop.settings import SensorSettings

FPS = 30.0
N_FRAMES = 12


@dataclass
class Rig:
    camera: TactileCamera
    expected: list[bytes] | None  # the bytes the source sends, None for real hardware
    shape: tuple[int, int, int]
    start: callable = lambda: None  # make the source begin streaming


# A backend's name runs the suite on it; "hardware" runs it on a real camera.
# opencv decodes a served MJPEG stream (seconds a test): make test runs it, make check the simulated camera.
PARAMS = ["sim", pytest.param("opencv", marks=pytest.mark.slow), pytest.param("hardware", marks=pytest.mark.hardware)]


def test_every_backend_in_the_table_runs_the_suite():
    assert_every_backend_covered("camera", BACKENDS, param_names(PARAMS), fixture="rig",
                                 where="tests/teleop/devices/test_camera_contract.py")


@pytest.fixture(params=PARAMS)
def rig(request, make_record, jpeg_frames, mjpg_server, hardware_env) -> Rig:
    if request.param == "sim":
        record = make_record(duration_s=N_FRAMES / FPS, camera_hz=FPS, frame_shape=(120, 160, 3))
        playback = GraspPlayback(record)
        camera = make_camera(SensorSettings(finger="right"), playback=playback)
        rig = Rig(camera, list(record.stream("right").encoded), (120, 160, 3), playback.start)
    elif request.param == "opencv":
        jpegs = jpeg_frames(N_FRAMES)
        server = mjpg_server(jpegs, fps=FPS, then="stall")
        camera = make_camera(SensorSettings(camera_backend="opencv", camera_source=server.url), read_timeout_s=1.0)
        rig = Rig(camera, jpegs, (480, 640, 3))
    else:
        sensor = SensorSettings(camera_backend="opencv", camera_source=hardware_env("COMPLIANCE_TELEOP_CAMERA"))
        rig = Rig(make_camera(sensor), None, (sensor.raw_height_px, sensor.raw_width_px, 3))
    yield rig
    rig.camera.close()


def test_unconnected_and_closed_cameras_refuse_reads(rig):
    with pytest.raises(DeviceNotConnectedError, match="connect"):
        rig.camera.read()
    with rig.camera:
        assert rig.camera.connected
    with pytest.raises(DeviceNotConnectedError, match="closed"):
        rig.camera.read()


def test_frames_arrive_in_order_as_captured_and_stamped_on_arrival(rig):
    with rig.camera:
        rig.start()
        frames = [rig.camera.read(timeout_s=2.0) for _ in range(N_FRAMES)]
    assert [f.index for f in frames] == list(range(N_FRAMES))
    assert {f.finger for f in frames} == {rig.camera.sensor.finger}
    t = np.array([f.t_s for f in frames])
    assert np.all(np.diff(t) > 0)
    assert np.median(np.diff(t)) == pytest.approx(1.0 / FPS, rel=0.35)
    assert frames[0].image().shape == rig.shape and frames[0].image().dtype == np.uint8
    if rig.expected is not None:
        assert [f.encoded for f in frames] == rig.expected[:N_FRAMES]  # byte for byte, never re-encoded
        assert {f.encoding for f in frames} == {"jpeg"}


@contextlib.contextmanager
def _fallen_silent(rig):
    """The camera connected and its recording read out: it sends nothing more."""
    if rig.expected is None:
        pytest.skip("a real camera does not fall silent on request")
    with rig.camera:
        rig.start()
        for _ in range(N_FRAMES):
            rig.camera.read(timeout_s=2.0)
        yield rig.camera


def test_a_silent_source_times_out(rig):
    with _fallen_silent(rig) as camera, pytest.raises(DeviceTimeoutError, match="no frame within 0.2 s"):
        camera.read(timeout_s=0.2)


def test_bad_timeouts_are_refused(rig):
    with rig.camera:
        for timeout in (0.0, -1.0, float("nan"), True):
            with pytest.raises(DeviceError, match="timeout_s"):
                rig.camera.read(timeout_s=timeout)


def test_close_wakes_a_read_waiting_in_another_thread(rig):
    with _fallen_silent(rig) as camera:
        ended = close_during_read(lambda: camera.read(timeout_s=3.0), camera.close, errors=DeviceError, waiting_s=0.2)
    # Woken by close(), not by the 3 s timeout: bounded well below it, as a loaded machine is slow.
    assert isinstance(ended.outcome, DeviceNotConnectedError) and ended.ended_s < 2.0


# --------------------------------------------------------------------------- backend specifics


def test_unknown_backend_lists_the_names():
    with pytest.raises(BackendNotFoundError) as info:
        make_camera(SensorSettings(), backend="gstreamer")
    assert all(name in str(info.value) for name in BACKENDS)


def test_opencv_stream_that_ends_is_an_error(jpeg_frames, mjpg_server):
    server = mjpg_server(jpeg_frames(3), fps=60.0, then="close")
    with make_camera(SensorSettings(camera_backend="opencv", camera_source=server.url), read_timeout_s=1.0) as camera:
        assert camera.passthrough
        for _ in range(3):
            camera.read(timeout_s=2.0)
        with pytest.raises(DeviceError, match="ended"):
            camera.read(timeout_s=2.0)


def test_opencv_source_that_cannot_open_is_an_error():
    camera = make_camera(
        SensorSettings(camera_backend="opencv", camera_source="http://127.0.0.1:1/?action=stream"), read_timeout_s=0.5
    )
    # the setting to check, in the error itself: every command opening the camera says it
    with pytest.raises(DeviceError, match=r"OpenCV cannot open the source: check the camera or its stream server "
                                          r"and `camera_source` in \[sensors\.left\]$"):
        camera.connect()
    with pytest.raises(DeviceError, match="no source"):
        make_camera(SensorSettings(camera_backend="opencv"))


def test_sim_camera_waits_for_the_replay_and_serves_its_finger_only(make_record):
    record = make_record(duration_s=0.2)
    playback = GraspPlayback(record)
    with make_camera(SensorSettings(finger="left"), playback=playback) as camera:
        with pytest.raises(DeviceTimeoutError):
            camera.read(timeout_s=0.1)  # not started: nothing is due
        playback.start()
        frame = camera.read(timeout_s=1.0)
    assert frame.encoded == record.stream("left").encoded[0]
    assert frame.t_s == pytest.approx(playback.live_time(record.stream("left").t_s[0]))
    with pytest.raises(KeyError):
        make_camera(SensorSettings(finger="thumb"), playback=playback)


def test_opencv_stream_that_is_not_mjpg_is_decoded_and_encoded(tmp_path):
    # An MPEG-4 file over HTTP: its packets are not JPEG, so the camera decodes and encodes.
    writer = cv2.VideoWriter(str(tmp_path / "clip.mp4"), cv2.VideoWriter_fourcc(*"mp4v"), 30, (160, 120))
    if not writer.isOpened():
        pytest.skip("this OpenCV build has no MPEG-4 encoder")
    for level in range(0, 200, 20):
        writer.write(np.full((120, 160, 3), level, dtype=np.uint8))
    writer.release()
    handler = functools.partial(http.server.SimpleHTTPRequestHandler, directory=str(tmp_path))
    handler.log_message = lambda *args: None
    with socketserver.ThreadingTCPServer(("127.0.0.1", 0), handler) as httpd:
        threading.Thread(target=httpd.serve_forever, daemon=True).start()
        url = f"http://127.0.0.1:{httpd.server_address[1]}/clip.mp4"
        with make_camera(SensorSettings(camera_backend="opencv", camera_source=url), read_timeout_s=1.0) as camera:
            assert not camera.passthrough
            frames = [camera.read(timeout_s=2.0) for _ in range(10)]
        httpd.shutdown()
    assert all(f.encoded.startswith(b"\xff\xd8") for f in frames)
    levels = [f.image().mean() for f in frames]
    assert levels == pytest.approx(list(range(0, 200, 20)), abs=4.0)


def test_a_calibrated_latency_puts_frames_on_the_load_cells_clock(make_record):
    """Every backend's frames come through the base class: its latency comes off their times."""
    record = make_record(duration_s=N_FRAMES / FPS, camera_hz=FPS, frame_shape=(120, 160, 3))
    for latency_s in (0.0, 0.04):
        playback = GraspPlayback(record)
        sensor = SensorSettings(finger="right", camera_latency_s=latency_s)
        with make_camera(sensor, playback=playback) as camera:
            playback.start()
            frames = [camera.read(timeout_s=2.0) for _ in range(4)]
        # The sim camera stamps a frame with the live time it was due.
        due = np.array([playback.frame_due_s("right", f.index) for f in frames])
        assert np.array([f.t_s for f in frames]) == pytest.approx(due - latency_s, abs=1e-9)


@pytest.mark.parametrize(("ext", "encoding"), [(".png", "png"), (".jpg", "jpeg")])
def test_a_grayscale_frame_decodes_to_three_channels(ext, encoding):
    gray = np.tile(np.arange(0, 240, 10, dtype=np.uint8), (16, 1))  # 16 x 24, one channel
    encoded = cv2.imencode(ext, gray)[1].tobytes()
    image = CameraFrame("left", 0, 1.0, encoded, encoding).image()
    assert image.shape == (16, 24, 3) and image.dtype == np.uint8


def test_bytes_that_do_not_decode_are_a_device_error_naming_the_frame():
    frame = CameraFrame("right", 7, 1.0, b"\xff\xd8" + b"\x00" * 64, "jpeg")
    with pytest.raises(DeviceError, match=r"frame 7 of finger 'right': jpeg data does not decode"):
        frame.image()
