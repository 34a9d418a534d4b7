"""The session recorder: every bus message of a session, exactly as received, into one MCAP log.

The log's layout is documented in :mod:`teleop.session.logfile`. The recorder subscribes to
every topic of the endpoints it is given (non-conflating, so nothing a lossless publisher
sends is dropped), checks each message with :func:`teleop.bus.wire.decode` (as every
subscriber does: a refused message is counted, never stored) and stores its frames
verbatim, each after its Foxglove-decodable forms (:mod:`teleop.session.foxglove`), which
can also go to a live view as they are written (``on_foxglove``). A message on a new topic past
the log's channel cap (:data:`~teleop.session.foxglove_log.MAX_CHANNELS`: made-up fingers'
``frame/<finger>``; each type's own topic and the settings' fingers' frames always fit) is refused too, counted under :data:`TOO_MANY_TOPICS`.

Write failures (a full disk, a removed drive) never stop the session: the recorder logs
one clear error, cuts the file back to the end of its last complete record (so everything
already written stays readable), closes its subscription (so lossless publishers never
wait for it) and stops; ``teleop record`` then exits with :data:`RECORDING_STOPPED_STATUS`, which
``teleop demo`` takes as "the session carries on without a recorder". ``teleop recover`` then turns
the log into a complete file.

The recorder holds its log's lock while it records (:mod:`teleop.session.recordfile`): a second
recorder on the same file is refused, ``--overwrite`` or not, and cannot damage the first one's log.
"""

from __future__ import annotations

import json
import logging
import socket
import time
from collections import Counter, deque
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import IO, Any

import zmq
from mcap.writer import LIBRARY_IDENTIFIER, CompressionType, Writer

from teleop.bus.pubsub import DEFAULT_MAX_BYTES, Subscriber, is_decade
from teleop.bus.wire import SCHEMAS, Message, decode, default_topic, now_ns
from teleop.catalogue import load_catalogue
from teleop.devices.simulated import robot_is_simulated
from teleop.errors import BusError, SessionLogError
from teleop.progress import progress_bar
from teleop.record import software_version
from teleop.redact import redacted
from teleop.scene import scene_path
from teleop.session.foxglove import FoxgloveMessage
from teleop.session.foxglove_log import LogChannels, rig_metadata
from teleop.session.logfile import (
    CHUNK_BYTES,
    END_METADATA,
    FORMAT_VERSION,
    MESSAGE_ENCODING,
    PROFILE,
    RIG_METADATA,
    SESSION_METADATA,
    SETTINGS_ATTACHMENT,
    TIME_OFFSET_KEY,
)
from teleop.session.logframes import FRAMING
from teleop.session.recordfile import LogSink, create_log
from teleop.settings import Settings, load_settings, resolve_path, settings_to_mapping

__all__ = ["COMPRESSIONS", "RECORDING_STOPPED", "RECORDING_STOPPED_STATUS", "TOO_MANY_TOPICS", "RecorderStats",
           "SessionRecorder", "session_source"]

log = logging.getLogger(__name__)

# `teleop record`'s exit status after a write error stopped the recording: not 2 (a setup error),
# so that whoever runs it can tell "the session carries on, its log is partial" from a failure.
RECORDING_STOPPED_STATUS = 3
# How its last line begins, saying why; `teleop demo` reads the reason from there.
RECORDING_STOPPED = "recording stopped: "
# The refusal reason (RecorderStats.refused) of a message whose new topic the log's channel cap left out.
TOO_MANY_TOPICS = "too_many_topics"
# How long closing goes on storing what is already queued: a stop is honoured though a flood is queued.
PENDING_S = 5.0
# How long it then goes on counting, not storing, what is still queued (RecorderStats.not_stored).
UNSTORED_COUNT_S = 1.0

COMPRESSIONS = {
    "zstd": CompressionType.ZSTD,
    "lz4": CompressionType.LZ4,
    "none": CompressionType.NONE,
}


def session_source(settings: Settings) -> str:
    """``"simulated"`` when every device backend is simulated (:func:`robot_is_simulated`), else ``"hardware"``."""
    return "simulated" if robot_is_simulated(settings) else "hardware"


class _CapturingSubscriber(Subscriber):
    """A Subscriber that also keeps each accepted message's frames, exactly as received."""

    def __init__(self, *args: Any, **kwargs: Any):
        super().__init__(*args, **kwargs)
        self.captured: deque[tuple[int, list[zmq.Frame]]] = deque()

    def _accept(self, frames: list[zmq.Frame]) -> Message | None:
        received_ns = now_ns()
        accepted_before = self.stats.received
        message = super()._accept(frames)  # decode, refusal counting, heartbeats, sequence gaps
        if self.stats.received != accepted_before:
            self.captured.append((received_ns, frames))
        return message

    def never_connected(self) -> dict[str, str]:
        """The endpoints no handshake succeeded with, each with why (:mod:`teleop.bus.handshakes`)."""
        return {} if self._handshakes is None else self._handshakes.never_connected()


@dataclass
class RecorderStats:
    """What a recorder stored and what it saw."""

    messages: int = 0
    saved_messages: int = 0  # of those, how many are in chunks already written to the file
    message_bytes: int = 0  # stored message data, framing and Foxglove forms included
    file_bytes: int = 0
    topics: Counter[str] = field(default_factory=Counter)
    refused: Counter[str] = field(default_factory=Counter)  # by wire reject reason, or TOO_MANY_TOPICS
    gaps: int = 0
    missed: int = 0  # messages the publishers sent that never arrived (sequence gaps)
    not_stored: int = 0  # messages that arrived but were still queued when a stop gave up storing them
    error: str | None = None  # the write error that stopped recording
    # endpoint -> why its last handshake failed, for those none succeeded with: nothing came from them
    never_connected: dict[str, str] = field(default_factory=dict)

    def as_dict(self) -> dict[str, Any]:
        return {
            "messages": self.messages,
            "saved_messages": self.saved_messages,
            "message_bytes": self.message_bytes,
            "file_bytes": self.file_bytes,
            "topics": dict(sorted(self.topics.items())),
            "refused": dict(self.refused),
            "gaps": self.gaps,
            "missed": self.missed,
            "not_stored": self.not_stored,
            "error": self.error,
            "never_connected": dict(self.never_connected),
        }


class SessionRecorder:
    """Records every bus message from ``endpoints`` into an MCAP session log.

    Nothing happens until :meth:`open` (or :meth:`run`, or ``with``), so a recorder can be
    built in one process and run in another (``multiprocessing.Process(target=rec.run,
    kwargs={"stop": event})``). Use it from one thread.

    Parameters
    ----------
    out : str, Path or binary file object
        The ``.mcap`` file to create, or an open binary stream to write to (left open, not locked).
    endpoints : str or iterable of str
        Publisher endpoints to subscribe to (every topic).
    settings : Settings, optional
        The settings the session runs with; stored in the log (a URL's password as ``***``).
        Default: the shipped file.
    scene : str
        Scene name or path, recorded (and its TOML attached when it is a file).
    source : {"simulated", "hardware"}, optional
        What produced the data; default from the settings' backends (:func:`session_source`).
    catalogue : str or Path, optional
        Object catalogue to attach, so exported grasps can be labelled; one that does not load
        (:func:`~teleop.catalogue.load_catalogue`) is refused.
    chunk_bytes : int
        MCAP chunk size; a killed recorder loses at most one chunk.
    flush_interval_s : float
        A chunk is closed and written at the latest this long after its first message.
    compression : {"zstd", "lz4", "none"}
        Chunk compression.
    max_bytes : int
        Largest bus message accepted.
    on_message : callable, optional
        Called as ``on_message(message, received_ns)`` after each message is stored (a
        monitor's hook, e.g. ``teleop soak`` measuring latency); keep it quick.
    on_foxglove : callable, optional
        Called as ``on_foxglove(converted, log_time_ns)`` with the Foxglove forms of each
        message stored and its log time (ns since the Unix epoch, as stored), e.g.
        :meth:`teleop.session.foxglove_live.LiveServer.log`.
    overwrite : bool
        Replace an existing ``out`` file (False: refuse it); either way a file another recorder
        is writing is refused (:func:`~teleop.session.recordfile.create_log`).
    **subscriber_options
        Passed on to :class:`~teleop.bus.pubsub.Subscriber` (``context``, ...).
    """

    def __init__(
        self,
        out: str | Path | IO[bytes],
        endpoints: str | Iterable[str],
        *,
        settings: Settings | None = None,
        scene: str = "",
        source: str | None = None,
        catalogue: str | Path | None = None,
        chunk_bytes: int = CHUNK_BYTES,
        flush_interval_s: float = 0.5,
        compression: str = "zstd",
        max_bytes: int = DEFAULT_MAX_BYTES,
        on_message: Callable[[Message, int], None] | None = None,
        on_foxglove: Callable[[Sequence[FoxgloveMessage], int], None] | None = None,
        overwrite: bool = True,
        **subscriber_options: Any,
    ):
        self.endpoints = [endpoints] if isinstance(endpoints, str) else list(endpoints)
        if not self.endpoints:
            raise SessionLogError("the recorder needs at least one endpoint to subscribe to")
        self.settings = settings if settings is not None else load_settings()
        self.source = source or session_source(self.settings)
        if self.source not in ("simulated", "hardware"):
            raise SessionLogError(f"source {self.source!r}: expected 'simulated' or 'hardware'")
        if compression not in COMPRESSIONS:
            raise SessionLogError(
                f"compression {compression!r}: expected one of {', '.join(COMPRESSIONS)}"
            )
        if chunk_bytes < 1024:
            raise SessionLogError(f"chunk_bytes = {chunk_bytes}: expected at least 1024")
        if not flush_interval_s > 0:
            raise SessionLogError(f"flush_interval_s = {flush_interval_s}: expected > 0")
        self.out = out if hasattr(out, "write") else Path(out)
        self.name = (
            str(self.out) if isinstance(self.out, Path) else getattr(out, "name", "<stream>")
        )
        self.scene = scene
        self.catalogue = Path(catalogue) if catalogue is not None else None
        if self.catalogue is not None:
            load_catalogue(self.catalogue)  # refused now, naming it, not by the export of the log
        self.chunk_bytes = chunk_bytes
        self.flush_interval_s = flush_interval_s
        self.compression = compression
        self.max_bytes = max_bytes
        self.on_message = on_message
        self.on_foxglove = on_foxglove
        self.overwrite = overwrite
        self.subscriber_options = subscriber_options
        self.stats = RecorderStats()
        self._file: IO[bytes] | None = None
        self._owns_file = False
        self._sink: LogSink | None = None
        self._writer: Writer | None = None
        self._log: LogChannels | None = None
        self._subscriber: _CapturingSubscriber | None = None
        self._chunk_opened_s: float | None = None
        self._state = "new"  # new -> open -> closed, or open -> failed -> closed

    # ------------------------------------------------------------------ lifecycle

    @property
    def failed(self) -> bool:
        """Whether a write error stopped the recording."""
        return self.stats.error is not None

    def open(self) -> SessionRecorder:
        """Create the log (header, attachments, session metadata) and subscribe.

        Raises
        ------
        SessionLogError
            The log cannot be created (it exists and ``overwrite`` is False, or another
            recorder holds it) or its start cannot be written (the log is then removed again), or
            the recorder was already closed.
        BusError
            The subscription cannot be set up (bad endpoint, missing CURVE keys); the
            log is then removed again.
        """
        if self._state != "new":
            if self._state == "closed":
                raise SessionLogError(f"recorder of {self.name} is closed")
            return self
        attachments = self._attachments()  # read inputs before creating anything
        if isinstance(self.out, Path):
            self._file = create_log(self.out, overwrite=self.overwrite)
            self._owns_file = True
        else:
            self._file = self.out
        self._sink = LogSink(self._file)
        self._writer = Writer(
            self._sink, chunk_size=self.chunk_bytes, compression=COMPRESSIONS[self.compression]
        )
        # One reading of both clocks: log times are monotonic receive times plus this offset.
        start_wall_ns, start_monotonic_ns = time.time_ns(), now_ns()
        reserved = {*SCHEMAS, *(default_topic("frame", {"finger": s.finger}) for s in self.settings.sensors)}
        self._log = LogChannels(self._writer, start_wall_ns - start_monotonic_ns, reserved=reserved)
        try:
            self._writer.start(
                PROFILE, f"compliance-teleop {software_version()}; {LIBRARY_IDENTIFIER}"
            )
            for name, media_type, data, create_ns in attachments:
                self._writer.add_attachment(
                    create_ns or start_wall_ns, now_ns() + self._log.offset_ns, name, media_type, data
                )
            self._writer.add_metadata(
                SESSION_METADATA, self._session_metadata(start_wall_ns, start_monotonic_ns)
            )
            self._writer.add_metadata(RIG_METADATA, rig_metadata(self.settings))
        except OSError as exc:
            self._discard_log()
            raise SessionLogError(
                f"cannot write the start of session log {self.name}: {exc.strerror or exc}"
            ) from exc
        try:
            self._subscriber = _CapturingSubscriber(
                self.endpoints, ("",), max_bytes=self.max_bytes, **self.subscriber_options
            )
        except BusError:
            self._discard_log()
            raise
        self._state = "open"
        log.info("recording %s from %s into %s", self.source, ", ".join(self.endpoints), self.name)
        return self

    def close(self) -> RecorderStats:
        """Write the log's summary and footer and unsubscribe; calling twice is fine."""
        if self._state == "open":
            self._receive_pending(time.monotonic() + PENDING_S)
            self._guarded(self._finish)
        self._stop_receiving()
        self._close_file()
        self._state = "closed"
        return self.stats

    def __enter__(self) -> SessionRecorder:
        return self.open()

    def __exit__(self, *exc: Any) -> None:
        self.close()

    # ------------------------------------------------------------------ recording

    def poll(self, timeout_s: float = 0.1) -> int:
        """Receive for up to ``timeout_s`` and store what arrived; the number of messages stored.

        Also closes the open chunk once it is ``flush_interval_s`` old. Returns 0 at once
        when the recorder is not open (never opened, closed, or stopped by a write error).
        """
        if self._state != "open":
            return 0
        if self._chunk_opened_s is not None:
            due = self._chunk_opened_s + self.flush_interval_s - time.monotonic()
            timeout_s = max(0.0, min(timeout_s, due))
        self._subscriber.recv(timeout_s=timeout_s)
        stored = self._drain()
        if (
            self._state == "open"
            and self._chunk_opened_s is not None
            and time.monotonic() - self._chunk_opened_s >= self.flush_interval_s
        ):
            self._guarded(self._flush_chunk)
        return stored

    def run(
        self, *, duration_s: float | None = None, stop: Any = None, progress: bool = False
    ) -> RecorderStats:
        """Open, record until ``duration_s`` passed, ``stop.is_set()`` or a write error, close.

        ``stop`` is anything with ``is_set()`` (``threading.Event``, ``multiprocessing.Event``).
        Returns the statistics; a write error is in ``stats.error``, not raised.
        """
        deadline = None if duration_s is None else time.monotonic() + duration_s
        self.open()
        try:
            with progress_bar(desc=f"record {self.name}", unit="msg", enabled=progress) as bar:
                while self._state == "open" and not (stop is not None and stop.is_set()):
                    remaining = None if deadline is None else deadline - time.monotonic()
                    if remaining is not None and remaining <= 0:
                        break
                    bar.update(self.poll(0.1 if remaining is None else min(0.1, remaining)))
        finally:
            self.close()
        return self.stats

    def _receive_pending(self, deadline: float) -> None:
        """Store what is already queued on this side of the socket, without waiting, until ``deadline``."""
        while self._state == "open":
            self._drain()
            if self._state != "open":
                break
            if time.monotonic() > deadline:
                self._count_unstored(time.monotonic() + UNSTORED_COUNT_S)
                break
            if self._subscriber.recv(timeout_s=0) is None and not self._subscriber.captured:
                break

    def _count_unstored(self, deadline: float) -> None:
        """Count, without storing, what is still queued until ``deadline``: what the stop loses, in the stats."""
        captured = self._subscriber.captured
        while True:
            self.stats.not_stored += len(captured)
            captured.clear()
            more = time.monotonic() > deadline
            if more or (self._subscriber.recv(timeout_s=0) is None and not captured):
                break
        log.warning("stopped with %d message(s) still queued after %.0f s of storing them: not recorded%s",
                    self.stats.not_stored, PENDING_S, " (and more still queued, not counted)" if more else "")

    def _drain(self) -> int:
        stored = 0
        while self._state == "open" and self._subscriber.captured:
            received_ns, frames = self._subscriber.captured.popleft()
            if self._guarded(self._store, received_ns, frames):
                stored += 1
        return stored

    def _store(self, received_ns: int, frames: list[zmq.Frame]) -> bool:
        # The subscriber accepted these frames: decoding them again cannot fail.
        message = decode(frames, max_bytes=self.max_bytes)
        converted = self._log.convert(message)
        if not self._log.admits(message, converted):
            self.stats.refused[TOO_MANY_TOPICS] += 1
            count = self.stats.refused[TOO_MANY_TOPICS]
            if is_decade(count):
                log.warning("refused %d message(s) on new topics (the latest %r from %r): the log holds at most "
                            "%d channels; further ones are counted", count, message.topic, message.source,
                            self._log.max_channels)
            return False
        before = self._sink.position
        converted = self._log.write_foxglove(message, received_ns, converted)
        self._log.bus_channel(message)  # a new topic's records may fill the chunk: before the message, counted so
        between = self._sink.position
        size = self._log.write_bus(
            message, frames, received_ns, elide_image=LogChannels.carries_image(converted)
        )
        self.stats.messages += 1
        # A full chunk goes to the file inside add_message: the one holding this message, or
        # (written between) one with only its Foxglove forms, this message opening the next.
        if self._sink.position != between:
            self._chunk_opened_s = None
            self.stats.saved_messages = self.stats.messages
        elif between != before or self._chunk_opened_s is None:
            self._chunk_opened_s = time.monotonic()
            self.stats.saved_messages = self.stats.messages - 1
        self.stats.message_bytes += size + sum(len(item.data) for item in converted)
        self.stats.topics[message.topic] += 1
        if self.on_message is not None:
            self.on_message(message, received_ns)
        if self.on_foxglove is not None:
            self.on_foxglove(converted, received_ns + self._log.offset_ns)
        return True

    def _flush_chunk(self) -> None:
        self._writer.flush()
        self._chunk_opened_s = None
        self.stats.saved_messages = self.stats.messages

    def _finish(self) -> None:
        self._flush_chunk()
        self._sync_stats()
        self._writer.add_metadata(
            END_METADATA,
            {
                "stop_utc": datetime.now(UTC).isoformat(),
                "stop_monotonic_ns": str(now_ns()),
                # not file_bytes: the file's size is known only once the summary and footer after this are written
                **{key: json.dumps(value) for key, value in self.stats.as_dict().items() if key != "file_bytes"},
            },
        )
        self._writer.finish()
        self.stats.file_bytes = self._sink.position

    # ------------------------------------------------------------------ failure

    def _guarded(self, action: Any, *args: Any) -> Any:
        """Run a write; on OSError stop recording cleanly instead of raising."""
        try:
            return action(*args)
        except OSError as exc:
            self._fail(exc)
            return None

    def _fail(self, exc: OSError) -> None:
        self.stats.error = f"writing {self.name} failed: {exc.strerror or exc}"
        cut = self._sink.cut_back()
        self._sync_stats()
        self.stats.file_bytes = self._sink.position
        self._writer = None
        self._state = "failed"
        self._stop_receiving()
        self._close_file()
        log.error(
            "%s; recording stopped, the session carries on without it. The log keeps every record "
            "up to byte %d%s; run `teleop recover %s --out FIXED.mcap` to make it a complete file",
            self.stats.error,
            self.stats.file_bytes,
            "" if cut else " (the bytes after it are damaged)",
            self.name,
        )

    # ------------------------------------------------------------------ helpers

    def _sync_stats(self) -> None:
        if self._subscriber is not None:
            seen, over = self._subscriber.stats, self.stats.refused[TOO_MANY_TOPICS]
            self.stats.refused = Counter(seen.refused) + Counter({TOO_MANY_TOPICS: over})
            self.stats.gaps, self.stats.missed = seen.gaps, seen.missed
            self.stats.never_connected = self._subscriber.never_connected()

    def _stop_receiving(self) -> None:
        if self._subscriber is not None:
            self._sync_stats()
            self._subscriber.close()  # a closed peer is one no lossless publisher waits for
            self._subscriber = None

    def _discard_log(self) -> None:
        """Close the log :meth:`open` failed to start and remove it when created here: it holds no
        message, and left behind it would refuse the next ``--out`` of its name and read as no MCAP log."""
        if self._owns_file:  # removed while it is still locked
            try:
                self.out.unlink(missing_ok=True)
            except OSError as exc:
                log.warning("cannot remove the unstarted session log %s: %s", self.name, exc.strerror or exc)
        self._close_file()
        self._state = "closed"

    def _close_file(self) -> None:
        if self._file is not None and self._owns_file:
            try:
                self._file.close()
            except OSError as exc:
                log.warning("closing %s: %s", self.name, exc)
        self._file = None

    def _attachments(self) -> list[tuple[str, str, bytes, int]]:
        """(name, media type, data, create time) of all the log carries besides messages.

        Create times are file modification times (ns since the Unix epoch); 0 for what the
        recorder makes itself (the settings): the session's start time is written instead.
        """
        # Logs are shared: a URL's password (a camera stream's login) is stored as ***.
        settings_json = json.dumps(redacted(settings_to_mapping(self.settings)), indent=1, sort_keys=True)
        out = [(SETTINGS_ATTACHMENT, "application/json", settings_json.encode("utf-8"), 0)]
        for sensor in self.settings.sensors:
            if not sensor.calibration:
                continue
            path = resolve_path(sensor.calibration)
            try:
                out.append((f"calibration/{sensor.finger}/{path.name}", "application/octet-stream",
                            path.read_bytes(), path.stat().st_mtime_ns))
            except OSError as exc:
                log.warning(
                    "calibration of finger %r not attached: %s: %s",
                    sensor.finger,
                    path,
                    exc.strerror or exc,
                )
        if self.catalogue is not None:
            out.append(
                (
                    f"catalogue{self.catalogue.suffix.lower()}",
                    "text/plain",
                    self._read(self.catalogue, "catalogue"),
                    self.catalogue.stat().st_mtime_ns,
                )
            )
        if self.scene:
            path = scene_path(self.scene)
            out.append(("scene.toml", "application/toml", self._read(path, "scene"), path.stat().st_mtime_ns))
        return out

    @staticmethod
    def _read(path: Path, what: str) -> bytes:
        try:
            return path.read_bytes()
        except OSError as exc:
            raise SessionLogError(
                f"cannot read the {what} to attach, {path}: {exc.strerror or exc}"
            ) from exc

    def _session_metadata(self, start_wall_ns: int, start_monotonic_ns: int) -> dict[str, str]:
        return {
            "software_version": software_version(),
            "scene": self.scene,
            "source": self.source,
            "start_utc": datetime.fromtimestamp(start_wall_ns / 1e9, UTC).isoformat(),
            "start_wall_ns": str(start_wall_ns),
            "start_monotonic_ns": str(start_monotonic_ns),
            TIME_OFFSET_KEY: str(start_wall_ns - start_monotonic_ns),
            "log_time_clock": "receive time, ns since the Unix epoch: time.monotonic_ns() of the "
            f"recording host + {TIME_OFFSET_KEY}",
            "publish_time_clock": f"header t_send_ns + {TIME_OFFSET_KEY} (the sending host's "
            "time.monotonic_ns(): on the epoch only when it is the recording host)",
            "endpoints": json.dumps(self.endpoints),
            "host": socket.gethostname(),
            "log_format": str(FORMAT_VERSION),
            "message_encoding": MESSAGE_ENCODING,
            "framing": FRAMING,
            "chunk_bytes": str(self.chunk_bytes),
            "flush_interval_s": str(self.flush_interval_s),
        }
