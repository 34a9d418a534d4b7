"""What a grasp stream has received: timestamped samples, and the frames of each finger.

Live, each batch and frame comes from the bus and is checked as it is added (:meth:`Series.add`,
:meth:`~estimator.stream.GraspStream.add_frame`). Offline, a grasp record's streams are taken
whole, as recorded (:meth:`Series.of`, :meth:`Frames.of_record`): a record may hold samples and
frames with non-finite or repeated timestamps, which the segmentation skips
(:mod:`estimator.segment`), as it skips a frame captured no later than an earlier one of its
finger, live and offline alike.

A grasp keeps at most :data:`MAX_GRASP_FRAMES` frames of each finger, the first that came from shortly before
its contact onset: once that many came, the oldest is dropped to make room for each new one while it was captured
before the contact onset (:meth:`Frames.make_room`), as long as :data:`PRE_CONTACT_FRAMES` frames from before the
onset stay for the no-contact reference; past that, later ones are checked and counted but not kept (offline, a
record's are counted and never decoded). So an operator holding the dead-man for minutes before touching the
object still has the contact measured. Live, the onset is the one in the force that has come when a frame does;
offline, the record's: the same as long as the force shows the contact before a frame captured about
``MAX_GRASP_FRAMES`` frames later comes. A frame refused live (it does not decode, or has a bad time or
encoding) takes its place among those kept all the same, as it does in the record it is in (offline it is
skipped later), so both keep the same frames.
An operator may hold an object for minutes, and each frame kept costs its bytes and, on the estimator's
finger, its decoded image, depth and reduced depth: about 0.26 MB a frame of both fingers at the shipped
settings (66 kB, 88 kB and 23 kB, and 80 kB of JPEG), about three times that at ``depth_binning`` 1.
Without the cap a long hold would grow the service without bound; with it a grasp's frames take at most
about 470 MB at the shipped settings.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import cv2
import numpy as np

from estimator.errors import PerceptionError
from estimator.measurements import REFERENCE_FRAMES
from estimator.perception.grid import ENCODINGS, frame_on_grid, raw_frame, to_grid
from teleop.record import FrameStream, Samples
from teleop.settings import SensorSettings

__all__ = ["MAX_GRASP_FRAMES", "PRE_CONTACT_FRAMES", "Frames", "Series"]

# Frames of one finger a grasp keeps: 60 s at 30 Hz, over ten times the longest of 40 simulated operator's
# grasps (156 frames) and a scripted one (a few seconds). Bounds a grasp's frames (module notes).
MAX_GRASP_FRAMES = 1800
# Frames from before the no-contact reference's cut a grasp past MAX_GRASP_FRAMES keeps: the reference's
# REFERENCE_FRAMES, and a second's more at 30 Hz should the onset found move earlier.
PRE_CONTACT_FRAMES = max(30, REFERENCE_FRAMES)


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
    None live. ``dropped`` counts the first frames, refused or not, dropped to make room (:meth:`make_room`);
    ``refused`` holds the arrival index and capture time of each frame refused live that takes a place among
    those kept, and ``not_kept`` counts the frames, refused or not, that came once no room was made.
    """

    t_s: list[float] = field(default_factory=list)
    encoded: list[bytes] = field(default_factory=list)
    encoding: str | None = None
    source: FrameStream | None = None
    not_kept: int = 0
    refused: list[tuple[int, float]] = field(default_factory=list)
    dropped: int = 0

    @classmethod
    def of_record(cls, stream: FrameStream, *, shift_s: float | None = None, keep_from_s: float = np.inf) -> Frames:
        """A record's frame stream as recorded, its times earlier by ``shift_s`` (s) when given: the
        :data:`MAX_GRASP_FRAMES` frames live would keep, as if each came in turn with the no-contact
        reference's cut at ``keep_from_s`` (s: :meth:`make_room`), the others counted (``dropped``, ``not_kept``)."""
        t = np.asarray(stream.t_s if shift_s is None else stream.t_s - shift_s, dtype=np.float64)
        before = np.concatenate([[0], np.cumsum(t < keep_from_s)])  # frames before the cut, up to each
        first = 0
        for new in range(MAX_GRASP_FRAMES, len(t)):  # frames first..new-1 kept when frame new comes
            if not Frames._room(t[first], int(before[new] - before[first]), keep_from_s):
                break
            first += 1
        last = first + min(len(t), MAX_GRASP_FRAMES)
        return cls([float(x) for x in t[first:last]], list(stream.encoded[first:last]), stream.encoding, stream,
                   not_kept=len(t) - last, dropped=first)

    @staticmethod
    def _room(oldest_t_s: float, count_before: int, keep_from_s: float) -> bool:
        """Whether the oldest frame kept, captured at ``oldest_t_s``, can be dropped with ``count_before`` frames
        kept captured before the no-contact reference's cut at ``keep_from_s`` (it among them)."""
        return not oldest_t_s >= keep_from_s and count_before > PRE_CONTACT_FRAMES

    @property
    def arrived(self) -> int:
        """Frames that came: kept, refused, dropped and not kept (a frame's index in the record it is in)."""
        return len(self.t_s) + len(self.refused) + self.dropped + self.not_kept

    @property
    def full(self) -> bool:
        """Whether :data:`MAX_GRASP_FRAMES` frames are kept (refused ones included): a later one makes room
        (:meth:`make_room`) or is only counted."""
        return len(self.t_s) + len(self.refused) >= MAX_GRASP_FRAMES

    def make_room(self, keep_from_s: Callable[[], float]) -> bool:
        """Once :attr:`full`, drop the oldest frame (``dropped``) for a new one: whether it was dropped. It is
        while no frame was counted not kept, it was captured before ``keep_from_s()`` (s, the no-contact
        reference's cut before the contact onset; infinite before contact) or at no finite time, and more than
        :data:`PRE_CONTACT_FRAMES` frames kept were."""
        if not self.full or self.not_kept:  # frames past those kept stay past them
            return False
        cut_s = keep_from_s()
        refused = bool(self.refused) and self.refused[0][0] == self.dropped  # the oldest frame was refused
        times = np.array([*self.t_s, *(t for _, t in self.refused)])
        if not self._room(self.refused[0][1] if refused else self.t_s[0], int(np.sum(times < cut_s)), cut_s):
            return False
        if refused:
            self.refused.pop(0)
        else:
            del self.t_s[0], self.encoded[0]
        self.dropped += 1
        return True

    def count_refused(self, t_s: float) -> None:
        """Count a frame captured at ``t_s`` refused live where a record would hold it: among those kept
        (room made by :meth:`make_room` first) or past them."""
        if self.full:
            self.not_kept += 1
        else:
            self.refused.append((self.arrived, float(t_s)))

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
                return to_grid(self.source.frame(self.dropped + index, reduce=binning), sensor, binning=binning)
            except PerceptionError as exc:
                raise PerceptionError(f"{where}: {exc}") from exc
        return frame_on_grid(self.encoded[index], self.encoding or "jpeg", sensor, binning=binning, where=where)

    def copy(self) -> Frames:
        return Frames(list(self.t_s), list(self.encoded), self.encoding, self.source, self.not_kept, list(self.refused),
                      self.dropped)
