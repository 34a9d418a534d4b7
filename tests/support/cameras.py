"""A camera that delivers a list of frames, for the rig calibrations' tests."""

from __future__ import annotations

import numpy as np

from teleop.errors import DeviceTimeoutError


class FakeFrame:
    """A frame captured at ``t_s`` whose image is one grey ``level``."""

    def __init__(self, t_s, level):
        self.t_s, self.level = t_s, level

    def image(self):
        return np.full((4, 6, 3), self.level, np.uint8)


class ListCamera:
    """Delivers ``frames`` in order, then times out."""

    def __init__(self, frames):
        self.frames = list(frames)

    def read(self, timeout_s=None):
        if not self.frames:
            raise DeviceTimeoutError("no frame")
        return self.frames.pop(0)
