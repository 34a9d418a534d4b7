"""What a grasp stream has received: timestamped samples, and the frames of each finger.

Live, each batch and frame comes from the bus and is checked as it is added (:meth:`Series.add`,
:meth:`~estimator.stream.GraspStream.add_frame`). Offline, a grasp record's streams are taken
whole, as recorded (:meth:`Series.of`, :meth:`Frames.of_record`): a record may hold samples and
frames with non-finite or repeated timestamps, which the segmentation skips
(:mod:`estimator.segment`), as it skips a frame captured no later than an earlier one of its
finger, live and offline alike.

A grasp keeps at most :data:`MAX_GRASP_FRAMES` frames of each finger, the first that came: live, later
ones are checked and counted but not kept; offline, a record's later ones are counted and never decoded.
A frame refused live (it does not decode, or has a bad time or encoding) takes its place among the first
all the same, as it does in the record it is in (offline it is skipped later), so both keep the same frames.
An operator may hold an object for minutes, and each frame kept costs its bytes and, on the estimator's
finger, its decoded image, depth and reduced depth: about 0.26 MB a frame of both fingers at the shipped
settings (66 kB, 88 kB and 23 kB, and 80 kB of JPEG), about three times that at ``depth_binning`` 1.
Without the cap a long hold would grow the service without bound; with it a grasp's frames take at most
about 470 MB at the shipped settings.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from estimator.errors import PerceptionError
from estimator.perception.grid import ENCODINGS, frame_on_grid, raw_frame, to_grid
from teleop.record import FrameStream, Samples
from teleop.settings import SensorSettings

__all__ = ["MAX_GRASP_FRAMES", "Frames", "Series"]

# Frames of one finger a grasp keeps: 60 s at 30 Hz, over ten times the longest of 40 simulated operator's
# grasps (156 frames) and a scripted one (a few seconds). Bounds a grasp's frames (module notes).
MAX_GRASP_FRAMES = 1800


@dataclass
class Series:
    """A growing timestamped scalar stream: the batches in the order they came."""

    t_s: list[np.ndarray] = field(default_factory=list)
    value: list[np.ndarray] = field(default_factory=list)
    last_t_s: float = -np.inf

    @classmethod
    def of(cls, samples: Samples, *, shift_s: float | None = None) -> Series:
        """A record's samples as recorded, their times earlier by ``shift_s`` (s) when given."""
        t = np.asarray(samples.t_s, dtype=np.float64)
        t = t if shift_s is None else t - shift_s
        finite = t[np.isfinite(t)]
        return cls([t], [np.asarray(samples.value, dtype=np.float64)],
                   float(finite.max()) if finite.size else -np.inf)

    def add(self, t_s: np.ndarray, value: np.ndarray, what: str) -> None:
        """Append a batch; PerceptionError naming ``what`` unless its times and values are finite
        and as many."""
        t = np.asarray(t_s, dtype=np.float64).ravel()
        v = np.asarray(value, dtype=np.float64).ravel()
        if t.shape != v.shape:
            raise PerceptionError(f"{what}: {t.size} timestamps but {v.size} values")
        if not (np.isfinite(t).all() and np.isfinite(v).all()):
            raise PerceptionError(f"{what}: timestamps and values must be finite")
        if t.size:
            self.t_s.append(t)
            self.value.append(v)
            self.last_t_s = max(self.last_t_s, float(t.max()))

    def samples(self) -> Samples:
        """Everything received, in the order it came."""
        if not self.t_s:
            return Samples(np.zeros(0), np.zeros(0))
        return Samples(np.concatenate(self.t_s), np.concatenate(self.value))

    def copy(self) -> Series:
        return Series(list(self.t_s), list(self.value), self.last_t_s)


@dataclass
class Frames:
    """Frames of one finger as received: capture times and the bytes as captured.

    ``source`` is the record's frame stream they came from offline (it decodes them, and holds
    them decoded when the record was: :class:`~estimator.inference.sampling.DecodedFrameStream`);
    None live. ``refused`` counts the frames refused live before :data:`MAX_GRASP_FRAMES` had come, and
    ``not_kept`` the frames, refused or not, that came after.
    """

    t_s: list[float] = field(default_factory=list)
    encoded: list[bytes] = field(default_factory=list)
    encoding: str | None = None
    source: FrameStream | None = None
    not_kept: int = 0
    refused: int = 0

    @classmethod
    def of_record(cls, stream: FrameStream, *, shift_s: float | None = None) -> Frames:
        """A record's frame stream as recorded, its times earlier by ``shift_s`` (s) when given: its
        first :data:`MAX_GRASP_FRAMES` frames, the others counted (``not_kept``), as live."""
        t = stream.t_s if shift_s is None else stream.t_s - shift_s
        kept = t[:MAX_GRASP_FRAMES]
        return cls([float(x) for x in kept], list(stream.encoded[:MAX_GRASP_FRAMES]), stream.encoding, stream,
                   not_kept=len(t) - len(kept))

    @property
    def arrived(self) -> int:
        """Frames that came: kept, refused and not kept (a frame's index in the record it is in)."""
        return len(self.t_s) + self.refused + self.not_kept

    @property
    def full(self) -> bool:
        """Whether :data:`MAX_GRASP_FRAMES` frames came (refused ones included): later ones are only counted."""
        return len(self.t_s) + self.refused >= MAX_GRASP_FRAMES

    def count_refused(self) -> None:
        """Count a frame refused live, where a record would hold it: among the first :data:`MAX_GRASP_FRAMES`
        or past them."""
        if self.full:
            self.not_kept += 1
        else:
            self.refused += 1

    def check(self, t_s: float, encoding: str, *, where: str) -> None:
        """Raise PerceptionError naming ``where`` unless a frame captured at ``t_s`` in ``encoding``
        can be added: a finite time, a known encoding, the one of the earlier frames."""
        if not np.isfinite(t_s):
            raise PerceptionError(f"{where}: capture time {t_s!r} is not finite")
        if encoding not in ENCODINGS:
            raise PerceptionError(f"{where}: encoding {encoding!r}, expected one of {', '.join(ENCODINGS)}")
        stored = "png" if encoding == "raw" else encoding
        if self.encoding not in (None, stored):
            raise PerceptionError(f"{where}: {encoding} after {self.encoding} frames")

    def add(self, t_s: float, data: np.ndarray | bytes, encoding: str, *, where: str) -> None:
        """Keep a frame as captured (checked: :meth:`check`); a ``raw`` one as lossless PNG, as a
        grasp record stores raw frames."""
        if encoding == "raw":
            data = cv2.imencode(".png", raw_frame(data, where=where), [cv2.IMWRITE_PNG_COMPRESSION, 1])[1]
            encoding = "png"
        self.encoding = encoding
        self.t_s.append(float(t_s))
        self.encoded.append(bytes(data) if isinstance(data, bytes | bytearray) else np.ascontiguousarray(data).tobytes())

    def times(self) -> np.ndarray:
        """Capture times (s), in the order the frames came."""
        return np.asarray(self.t_s, dtype=np.float64)

    def on_grid(self, index: int, sensor: SensorSettings, *, binning: int, where: str) -> np.ndarray:
        """Frame ``index`` on ``sensor``'s depth grid binned by ``binning``
        (:func:`~estimator.perception.grid.frame_on_grid`). Raises RecordError (a record's
        frame) or PerceptionError (one received live) for a frame that does not decode."""
        if self.source is not None:
            try:
                return to_grid(self.source.frame(index, reduce=binning), sensor, binning=binning)
            except PerceptionError as exc:
                raise PerceptionError(f"{where}: {exc}") from exc
        return frame_on_grid(self.encoded[index], self.encoding or "jpeg", sensor, binning=binning, where=where)

    def copy(self) -> Frames:
        return Frames(list(self.t_s), list(self.encoded), self.encoding, self.source, self.not_kept, self.refused)
