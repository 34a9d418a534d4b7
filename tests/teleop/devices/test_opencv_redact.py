"""A stream URL's password opens the camera but never shows in what is said about it."""

from __future__ import annotations

import pytest

import teleop.devices.opencv_camera as opencv_camera
from teleop.devices.camera import make_camera
from teleop.errors import DeviceError
from teleop.settings import SensorSettings

URL = "http://admin:Hunter2Pass@127.0.0.1:9/?action=stream"


class _Unopened:
    """A capture of a source that does not answer."""

    def isOpened(self) -> bool:  # noqa: N802 (OpenCV's name)
        return False

    def release(self) -> None:
        pass


def test_the_camera_opens_the_real_url_and_its_messages_hide_the_password(monkeypatch):
    opened = []

    def capture(source, *args):
        opened.append(source)
        return _Unopened()

    monkeypatch.setattr(opencv_camera.cv2, "VideoCapture", capture)
    camera = make_camera(SensorSettings(camera_backend="opencv", camera_source=URL), read_timeout_s=0.5)
    assert repr(camera) == "<OpenCVCamera finger='left' source='http://admin:***@127.0.0.1:9/?action=stream'>"
    with pytest.raises(DeviceError) as raised:
        camera.connect()
    assert opened == [URL]
    assert "Hunter2Pass" not in str(raised.value)
    assert "http://admin:***@127.0.0.1:9/?action=stream" in str(raised.value)
