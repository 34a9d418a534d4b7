"""One finger's frames from a session log as a record's frame stream: what is refused before decoding."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from support.images import png_declaring

from teleop.session.export_streams import frame_stream
from teleop.settings import load_settings


@pytest.mark.parametrize("side", [8000, 60000])
def test_a_frame_declaring_a_huge_image_is_refused_before_it_is_decoded(monkeypatch, side):
    """A few bytes of a corrupt or hostile log may declare gigabytes: no grasp, a reason, nothing decoded."""
    bomb = png_declaring(side, side)
    imdecode = cv2.imdecode

    def guarded(buffer, flags):
        if np.asarray(buffer).tobytes() == bomb:
            pytest.fail(f"decoded a frame declaring {side}x{side} px")
        return imdecode(buffer, flags)

    monkeypatch.setattr(cv2, "imdecode", guarded)
    frames = [(0.0, "png", np.frombuffer(bomb, np.uint8)), (0.03, "png", np.frombuffer(bomb, np.uint8))]
    reason = frame_stream("left", frames)
    assert isinstance(reason, str) and "finger 'left': the first png frame is refused" in reason, reason
    assert f"{side}x{side}" in reason or "decompression bomb" in reason, reason
    # a frame of a sensor's size is kept
    sensor = load_settings().sensors[0]
    shape = (sensor.raw_height_px, sensor.raw_width_px)
    ok, png = cv2.imencode(".png", np.zeros((*shape, 3), np.uint8))
    assert ok and frame_stream("left", [(0.0, "png", png)]).shape == (*shape, 3)


def test_frames_of_one_finger_in_two_encodings_are_refused_naming_both():
    # A record's stream has one encoding; each frame alone would decode.
    image = np.zeros((24, 32, 3), np.uint8)
    frames = [(0.0, "jpeg", cv2.imencode(".jpg", image)[1]), (0.03, "png", cv2.imencode(".png", image)[1])]
    assert frame_stream("left", frames) == "finger 'left' sent frames in several encodings (jpeg, png)"
