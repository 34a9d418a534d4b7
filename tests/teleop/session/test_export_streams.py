"""One finger's frames from a session log as a record's frame stream: what is refused before decoding."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from support.images import png_declaring

from teleop.session.export_streams import frame_stream
from teleop.settings import load_settings


def _refuse_to_decode(monkeypatch, bomb: bytes) -> None:
    """Fail the test if ``bomb`` reaches the decoder."""
    imdecode = cv2.imdecode

    def guarded(buffer, flags):
        if np.asarray(buffer).tobytes() == bomb:
            pytest.fail("decoded a frame declaring a larger image than any sensor's")
        return imdecode(buffer, flags)

    monkeypatch.setattr(cv2, "imdecode", guarded)


def _png(rows: int, cols: int) -> np.ndarray:
    ok, png = cv2.imencode(".png", np.zeros((rows, cols, 3), np.uint8))
    assert ok
    return png


@pytest.mark.parametrize("side", [8000, 60000])
def test_a_frame_declaring_a_huge_image_is_refused_before_it_is_decoded(monkeypatch, side):
    """A few bytes of a corrupt or hostile log may declare gigabytes: no grasp, a reason, nothing decoded."""
    bomb = png_declaring(side, side)
    _refuse_to_decode(monkeypatch, bomb)
    frames = [(0.0, "png", np.frombuffer(bomb, np.uint8)), (0.03, "png", np.frombuffer(bomb, np.uint8))]
    reason = frame_stream("left", frames)
    assert isinstance(reason, str) and "finger 'left': the first png frame is refused" in reason, reason
    assert f"{side}x{side}" in reason or "decompression bomb" in reason, reason
    # a frame of a sensor's size is kept
    sensor = load_settings().sensors[0]
    shape = (sensor.raw_height_px, sensor.raw_width_px)
    assert frame_stream("left", [(0.0, "png", _png(*shape))]).shape == (*shape, 3)


@pytest.mark.parametrize(("width", "height"), [(60000, 16), (16, 60000)])
def test_one_side_past_the_largest_a_sensor_allows_is_refused(monkeypatch, width, height):
    # Long and thin is still gigabytes when the other side is a few thousand pixels.
    bomb = png_declaring(width, height)
    _refuse_to_decode(monkeypatch, bomb)
    reason = frame_stream("left", [(0.0, "png", np.frombuffer(bomb, np.uint8))])
    assert isinstance(reason, str) and "the first png frame is refused" in reason, reason
    assert f"{width}x{height}" in reason


def test_a_frame_as_wide_as_a_sensor_allows_is_kept():
    # SensorSettings allow raw sides up to 4096 px.
    stream = frame_stream("left", [(0.0, "png", _png(2, 4096))])
    assert not isinstance(stream, str), stream
    assert stream.shape == (2, 4096, 3)


def test_the_first_frame_is_the_one_checked_and_it_gives_the_streams_shape(monkeypatch):
    bomb = png_declaring(60000, 60000)
    _refuse_to_decode(monkeypatch, bomb)
    small, larger = _png(24, 32), _png(48, 64)
    reason = frame_stream("left", [(0.0, "png", np.frombuffer(bomb, np.uint8)), (0.03, "png", small)])
    assert isinstance(reason, str) and "the first png frame is refused" in reason, reason
    assert frame_stream("left", [(0.0, "png", small), (0.03, "png", larger)]).shape == (24, 32, 3)


def test_frames_of_one_finger_in_two_encodings_are_refused_naming_both():
    # A record's stream has one encoding; each frame alone would decode.
    image = np.zeros((24, 32, 3), np.uint8)
    frames = [(0.0, "jpeg", cv2.imencode(".jpg", image)[1]), (0.03, "png", cv2.imencode(".png", image)[1])]
    assert frame_stream("left", frames) == "finger 'left' sent frames in several encodings (jpeg, png)"
