"""Tactile camera through OpenCV: the ``opencv`` camera backend.

The source is a device index (``"0"``: a USB camera such as a GelSight Mini) or a URL
(``http://pi:8080/?action=stream``: an MJPG-over-HTTP stream, as the published rig's
Raspberry Pis serve each Wedge). A reader thread grabs frames as they arrive, stamps
each on arrival (``time.monotonic()`` right after the grab returns) and queues it.

For a URL the FFmpeg backend runs in raw mode (``CAP_PROP_FORMAT = -1``): each packet of
an MJPG stream is the camera's own JPEG, kept byte for byte with no decode and re-encode.
A stream whose packets are not JPEG, and a device index, deliver decoded BGR images,
which are encoded as JPEG at ``jpeg_quality``.

Each connection has its own reader, frame queue, stop event and failure (:class:`_Stream`): a
reader that :meth:`~OpenCVCamera.close` stopped waiting for (a grab that outlived the wait)
ends on its own later and hands no frame or failure to a later connection (at most one more
count in ``dropped``).
"""

from __future__ import annotations

import logging
import queue
import threading
import time
from dataclasses import dataclass, field

import cv2

from teleop.devices.camera import CameraFrame, TactileCamera, opencv_fix
from teleop.errors import DeviceError
from teleop.redact import redact_url
from teleop.settings import SensorSettings

__all__ = ["OpenCVCamera"]

log = logging.getLogger(__name__)

JPEG_SOI = b"\xff\xd8"
OPEN_TIMEOUT_MS = 5000


@dataclass
class _Stream:
    """What one connection's reader thread shares with :meth:`OpenCVCamera.read`."""

    frames: queue.Queue[CameraFrame]
    stop: threading.Event = field(default_factory=threading.Event)
    failure: str | None = None  # why the stream ended, once it did
    next_index: int = 0


class OpenCVCamera(TactileCamera):
    """A camera OpenCV can open.

    Parameters
    ----------
    sensor : SensorSettings
        The sensor; ``camera_source`` names the source unless ``source`` is given.
    source : str, optional
        Device index or stream URL, overriding ``sensor.camera_source``. A URL may carry the
        stream server's login (``http://user:password@pi:8080/?action=stream``); messages show it
        with the password hidden (:func:`teleop.redact.redact_url`).
    jpeg_quality : int
        Quality for frames that must be encoded (decoded sources only).
    queue_frames : int
        Frames buffered between the reader and :meth:`read`; when full the oldest is
        dropped and counted in :attr:`dropped`.
    read_timeout_s : float
        A stream silent this long counts as ended (OpenCV's read timeout); also bounds
        how long :meth:`close` waits for the reader.
    """

    def __init__(
        self,
        sensor: SensorSettings,
        *,
        source: str | None = None,
        jpeg_quality: int = 95,
        queue_frames: int = 256,
        read_timeout_s: float = 2.0,
    ):
        super().__init__(sensor)
        self.source = sensor.camera_source if source is None else source
        if not self.source:
            raise DeviceError(f"camera of finger {sensor.finger!r}: no source (set camera_source to an index or a URL)")
        self.jpeg_quality = jpeg_quality
        self.read_timeout_s = read_timeout_s
        self.passthrough = False  # True while the stream's own JPEG bytes are kept
        self.queue_frames = queue_frames
        self._stream: _Stream | None = None
        self._reader: threading.Thread | None = None

    def __repr__(self) -> str:
        # Every message about the camera says this: a stream URL's password stays out of it.
        return f"<OpenCVCamera finger={self.sensor.finger!r} source={redact_url(self.source)!r}>"

    def _failed(self, what: str) -> DeviceError:
        """An open that failed, with the setting to check: every command opening the camera says it."""
        return DeviceError(f"{self!r}: {what}: {opencv_fix(self.sensor.finger)}")

    def _open_capture(self, *, raw: bool) -> cv2.VideoCapture:
        params = [
            cv2.CAP_PROP_OPEN_TIMEOUT_MSEC, OPEN_TIMEOUT_MS,
            cv2.CAP_PROP_READ_TIMEOUT_MSEC, round(self.read_timeout_s * 1000),
        ]
        if self.source.isdigit():
            capture = cv2.VideoCapture(int(self.source), cv2.CAP_ANY, params)
            capture.set(cv2.CAP_PROP_FRAME_WIDTH, self.sensor.raw_width_px)
            capture.set(cv2.CAP_PROP_FRAME_HEIGHT, self.sensor.raw_height_px)
        else:
            capture = cv2.VideoCapture(self.source, cv2.CAP_FFMPEG, params)
            if raw and capture.isOpened():
                self.passthrough = bool(capture.set(cv2.CAP_PROP_FORMAT, -1))
        if not capture.isOpened():
            capture.release()
            raise self._failed("OpenCV cannot open the source")
        return capture

    def _connect(self) -> None:
        self.passthrough = False
        capture = self._open_capture(raw=True)
        first = self._grab(capture)
        if first is None:
            capture.release()
            raise self._failed("the source opened but delivered no frame")
        if self.passthrough and not first[1].startswith(JPEG_SOI):
            # Not an MJPG stream (e.g. H.264): reopen decoding, and encode frames ourselves.
            capture.release()
            self.passthrough = False
            capture = self._open_capture(raw=False)
            first = self._grab(capture)
            if first is None:
                capture.release()
                raise self._failed("the source delivered no decodable frame")
        self._stream = _Stream(queue.Queue(maxsize=self.queue_frames))
        self._enqueue(self._stream, *first)
        # The reader owns the capture from here on and releases it when it ends.
        self._reader = threading.Thread(target=self._read_forever, args=(capture, self._stream), name=repr(self),
                                        daemon=True)
        self._reader.start()

    def _close(self) -> None:
        if self._stream is not None:
            self._stream.stop.set()
        if self._reader is not None:
            self._reader.join(timeout=self.read_timeout_s + 1.0)

    def _grab(self, capture: cv2.VideoCapture) -> tuple[float, bytes] | None:
        """Next frame as (arrival time, JPEG bytes), or None when the stream ended."""
        if not capture.grab():
            return None
        t_s = time.monotonic()
        ok, data = capture.retrieve()
        if not ok or data is None:
            return None
        if self.passthrough:
            return t_s, data.tobytes()
        ok, encoded = cv2.imencode(".jpg", data, [cv2.IMWRITE_JPEG_QUALITY, self.jpeg_quality])
        if not ok:
            return None
        return t_s, encoded.tobytes()

    def _enqueue(self, stream: _Stream, t_s: float, encoded: bytes) -> None:
        frame = CameraFrame(self.sensor.finger, stream.next_index, t_s, encoded, "jpeg")
        stream.next_index += 1
        while True:
            try:
                stream.frames.put_nowait(frame)
                return
            except queue.Full:
                stream.frames.get_nowait()  # keep the newest frames; the index jump shows the loss
                self.dropped += 1

    def _read_forever(self, capture: cv2.VideoCapture, stream: _Stream) -> None:
        try:
            while not stream.stop.is_set():
                grabbed = self._grab(capture)
                if grabbed is None and stream.stop.is_set():
                    return  # closing while the stream was quiet: not a failure
                if grabbed is None:
                    stream.failure = f"{self!r}: the stream ended or stalled for {self.read_timeout_s} s"
                    log.warning(stream.failure)
                    return
                self._enqueue(stream, *grabbed)
        finally:
            capture.release()

    def _read(self, timeout_s: float) -> CameraFrame | None:
        stream = self._stream
        deadline = time.monotonic() + timeout_s
        while True:
            try:  # short slices, so a reader that failed meanwhile is noticed
                return stream.frames.get(timeout=min(0.05, max(0.0, deadline - time.monotonic())))
            except queue.Empty:
                if stream.failure is not None:
                    raise DeviceError(stream.failure) from None
                if stream.stop.is_set() or time.monotonic() >= deadline:  # closed meanwhile, or timed out
                    return None
