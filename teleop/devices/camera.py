"""The tactile camera family: base class, frame type, backend table and :func:`make_camera`.

A camera hands out every frame it captured, in order, each stamped on arrival
(``time.monotonic()`` seconds) and kept encoded as captured (an MJPG stream's own JPEG
bytes), ready for the grasp record and the bus without re-encoding.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import cv2
import numpy as np

from teleop.devices.base import Device, check_timeout, load_backend
from teleop.errors import DeviceError, DeviceTimeoutError
from teleop.settings import SensorSettings

__all__ = ["BACKENDS", "CameraFrame", "TactileCamera", "make_camera", "opencv_fix"]

BACKENDS = {
    "sim": "teleop.devices.playback:SimulatedCamera",
    "opencv": "teleop.devices.opencv_camera:OpenCVCamera",
}


def make_camera(sensor: SensorSettings, *, backend: str | None = None, **options) -> TactileCamera:
    """An unconnected camera for ``sensor`` of ``backend`` (default ``sensor.camera_backend``).

    ``options`` go to the backend (``playback=`` for ``sim``; ``source=`` for ``opencv``).
    """
    cls = load_backend("camera", BACKENDS, backend or sensor.camera_backend)
    return cls(sensor, **options)


@dataclass(frozen=True)
class CameraFrame:
    """One captured frame.

    Parameters
    ----------
    finger : str
        Finger whose sensor took it.
    index : int
        Frame number since the camera connected (0, 1, ...); a jump means lost frames.
    t_s : float
        Capture time, ``time.monotonic()`` seconds on the load cell's clock: the arrival time less
        the sensor's calibrated ``camera_latency_s`` (``teleop calibrate camera --latency``).
    encoded : bytes
        The image as captured: JPEG or PNG bytes.
    encoding : {"jpeg", "png"}
    """

    finger: str
    index: int
    t_s: float
    encoded: bytes
    encoding: str

    def image(self) -> np.ndarray:
        """Decode to uint8 H x W x 3 BGR; DeviceError if the bytes do not decode."""
        image = cv2.imdecode(np.frombuffer(self.encoded, dtype=np.uint8), cv2.IMREAD_COLOR)
        if image is None:
            raise DeviceError(f"frame {self.index} of finger {self.finger!r}: {self.encoding} data does not decode")
        return image


class TactileCamera(Device):
    """The camera of one tactile sensor. Backends implement ``_connect``, ``_close``, ``_read``.

    ``dropped`` counts the frames captured but never read: a reader that fell behind loses the
    oldest (frame indices then jump), as a camera driver does.
    """

    family = "camera"

    def __init__(self, sensor: SensorSettings):
        super().__init__()
        self.sensor = sensor
        self.dropped = 0

    def __repr__(self) -> str:
        return f"<{type(self).__name__} finger={self.sensor.finger!r}>"

    def read(self, *, timeout_s: float = 1.0) -> CameraFrame:
        """The next frame in capture order, waiting up to ``timeout_s`` for it.

        Raises
        ------
        DeviceTimeoutError
            No frame arrived within ``timeout_s``.
        DeviceError
            The stream ended or failed.
        """
        self._require_connected()
        frame = self._read(check_timeout(timeout_s))
        if frame is None:
            self._require_connected()  # closed while waiting
            raise DeviceTimeoutError(f"{self!r}: no frame within {timeout_s} s")
        if self.sensor.camera_latency_s:  # onto the load cell's clock, as calibrated
            return dataclasses.replace(frame, t_s=frame.t_s - self.sensor.camera_latency_s)
        return frame

    def _read(self, timeout_s: float) -> CameraFrame | None:
        raise NotImplementedError


def opencv_fix(finger: str) -> str:
    """What to do when the ``opencv`` camera of ``finger`` does not open or deliver."""
    return f"check the camera or its stream server and `camera_source` in [sensors.{finger}]"
