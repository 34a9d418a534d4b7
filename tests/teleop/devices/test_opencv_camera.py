"""OpenCVCamera on a scripted capture (no stream server): queue overflow, reconnects, open failures."""

from __future__ import annotations

import threading

import cv2
import numpy as np
import pytest

import teleop.devices.opencv_camera as opencv_camera
from teleop.devices.camera import make_camera
from teleop.errors import DeviceError, DeviceTimeoutError
from teleop.settings import SensorSettings


def _jpeg(i: int) -> bytes:
    image = np.full((24, 32, 3), (i * 23) % 256, dtype=np.uint8)
    return cv2.imencode(".jpg", image)[1].tobytes()


class ScriptedCapture:
    """A capture that hands out ``frames`` (JPEG bytes, or BGR images), then ends the stream,
    or (``then_block``) stays quiet until ``unblock`` is set.

    ``hold_before`` (an index into ``frames``) makes the grab of that frame wait for ``unblock``
    first: a grab that outlives the camera's close.
    """

    def __init__(self, frames, *, then_block: bool = False, hold_before: int | None = None):
        self.frames = list(frames)
        self.then_block = then_block
        self.hold_before = hold_before
        self.grabbed = 0
        self.exhausted = threading.Event()  # set once every frame was handed out (and queued)
        self.unblock = threading.Event()
        self.released = threading.Event()
        self.sets: list[tuple[int, float]] = []
        self.args: tuple = ()
        self._current = None

    def isOpened(self) -> bool:  # noqa: N802 (OpenCV's name)
        return True

    def set(self, prop, value) -> bool:
        self.sets.append((prop, value))
        return True

    def grab(self) -> bool:
        if self.grabbed == self.hold_before:
            self.unblock.wait(5.0)
        if self.frames:
            self._current = self.frames.pop(0)
            self.grabbed += 1
            return True
        self.exhausted.set()
        if self.then_block:
            self.unblock.wait(5.0)
        return False

    def retrieve(self):
        data = self._current
        if isinstance(data, bytes):
            return True, np.frombuffer(data, dtype=np.uint8).copy()
        return True, data

    def release(self) -> None:
        self.released.set()


class _Captures(list):
    """The captures still to open; ``opened`` lists those opened."""

    def __init__(self):
        super().__init__()
        self.opened: list[ScriptedCapture] = []


@pytest.fixture
def captures(monkeypatch):
    """Each VideoCapture opened takes the next ScriptedCapture of the list the test fills."""
    queue = _Captures()
    opened = queue.opened

    def video_capture(source, *args):
        capture = queue.pop(0)
        capture.args = (source, *args)
        opened.append(capture)
        return capture

    monkeypatch.setattr(opencv_camera.cv2, "VideoCapture", video_capture)
    yield queue
    for capture in opened:
        capture.unblock.set()


def _camera(read_timeout_s: float = 0.2, **options):
    return make_camera(SensorSettings(camera_backend="opencv", camera_source="http://pi:8080/?action=stream"),
                       read_timeout_s=read_timeout_s, **options)


def test_a_full_queue_drops_the_oldest_frames_and_counts_them(captures):
    jpegs = [_jpeg(i) for i in range(10)]
    capture = ScriptedCapture(jpegs)
    captures.append(capture)
    with _camera(queue_frames=3) as camera:
        assert capture.exhausted.wait(2.0)  # every frame was queued before the stream ended
        frames = [camera.read(timeout_s=1.0) for _ in range(3)]
        assert [f.index for f in frames] == [7, 8, 9]  # the newest kept; the index jump shows the loss
        assert [f.encoded for f in frames] == jpegs[7:]
        assert camera.dropped == 7
        with pytest.raises(DeviceError, match="ended"):
            camera.read(timeout_s=1.0)


def test_a_reconnected_camera_counts_from_zero_and_serves_nothing_from_before(captures):
    first = [_jpeg(i) for i in range(3)]
    second = [_jpeg(100 + i) for i in range(2)]
    captures.append(ScriptedCapture(first, then_block=True))
    captures.append(ScriptedCapture(second, then_block=True))
    camera = _camera()
    with camera:
        assert captures.opened[0].exhausted.wait(2.0)  # all three queued
        assert camera.read(timeout_s=1.0).encoded == first[0]  # frames 1 and 2 are left unread
        captures.opened[0].unblock.set()
    with camera:
        frame = camera.read(timeout_s=1.0)
        assert (frame.index, frame.encoded) == (0, second[0])
        captures.opened[1].unblock.set()


def test_a_stream_that_ended_does_not_fail_the_next_connection(captures):
    captures.append(ScriptedCapture([_jpeg(0)]))  # ends after one frame
    later = ScriptedCapture([_jpeg(1)], then_block=True)  # stays open, quiet after one frame
    captures.append(later)
    camera = _camera()
    with camera:
        camera.read(timeout_s=1.0)
        with pytest.raises(DeviceError, match="ended"):
            camera.read(timeout_s=1.0)
    with camera:
        assert camera.read(timeout_s=1.0).encoded == _jpeg(1)
        assert later.exhausted.wait(2.0)
        with pytest.raises(DeviceTimeoutError):  # quiet, not ended: the old failure is gone
            camera.read(timeout_s=0.2)
        later.unblock.set()


def test_a_reader_left_from_the_last_connection_touches_nothing_of_the_next(captures):
    # close() waits read_timeout_s + 1 s for the reader; a grab stuck longer leaves it running.
    # When that grab returned after a reconnect, its frame went into the new connection's queue
    # and its stream's end failed the new connection with "ended or stalled".
    old = ScriptedCapture([_jpeg(0), _jpeg(1)], hold_before=1)  # its second grab outlives close()
    new = ScriptedCapture([_jpeg(2)], then_block=True)
    captures.extend([old, new])
    camera = _camera(read_timeout_s=0.05)
    with camera:
        camera.read(timeout_s=1.0)
    with camera:
        old.unblock.set()  # the stale grab returns a frame, and the old stream ends after it
        assert old.released.wait(2.0)  # the stale reader is done
        frame = camera.read(timeout_s=1.0)
        assert (frame.index, frame.encoded) == (0, _jpeg(2))
        assert new.exhausted.wait(2.0)
        with pytest.raises(DeviceTimeoutError):  # quiet, neither the old frame nor the old stream's end
            camera.read(timeout_s=0.2)


def test_a_source_that_opens_but_delivers_nothing_says_what_to_check(captures):
    captures.append(ScriptedCapture([]))
    with pytest.raises(DeviceError, match=r"delivered no frame: check the camera .*`camera_source` in \[sensors\.left\]"):
        _camera().connect()


def test_a_device_index_is_asked_for_the_sensors_raw_frame_size(captures):
    sensor = SensorSettings(camera_backend="opencv", camera_source="0", raw_width_px=800, raw_height_px=600)
    capture = ScriptedCapture([np.zeros((600, 800, 3), dtype=np.uint8)], then_block=True)
    captures.append(capture)
    with make_camera(sensor, read_timeout_s=0.2) as camera:
        frame = camera.read(timeout_s=1.0)
        capture.unblock.set()
    assert capture.args[0] == 0  # the index, as an int
    sets = dict(capture.sets)
    assert sets[cv2.CAP_PROP_FRAME_WIDTH] == 800 and sets[cv2.CAP_PROP_FRAME_HEIGHT] == 600
    assert frame.image().shape == (600, 800, 3) and not camera.passthrough


def test_the_stream_read_timeout_is_given_to_opencv_in_milliseconds(captures):
    capture = ScriptedCapture([_jpeg(0)], then_block=True)
    captures.append(capture)
    with _camera():
        capture.unblock.set()
    params = capture.args[2]
    pairs = dict(zip(params[::2], params[1::2], strict=True))
    assert pairs[cv2.CAP_PROP_READ_TIMEOUT_MSEC] == 200
