"""HX711 load cell over a serial line or framed TCP: the ``serial`` and ``tcp`` backends.

The line protocols are documented in :mod:`teleop.devices.hx711_protocol`. Counts become
newtons with ``LoadCellSettings`` (see :mod:`teleop.devices.loadcell`). Readings that are
not valid (partial or overlong lines, garbage, counts out of range or at a rail) are
logged (a warning the first time per reason), counted in ``skipped`` and skipped. Serial
readings are stamped on arrival.

A cell that gives no valid reading for :data:`STALL_S` (the first one after connecting may take
the cell's ``timeout_s``, as a tare waits for it) is down: a read that finds nothing then raises
:class:`~teleop.errors.DeviceStalledError` saying why (silent, or what its readings were skipped for,
e.g. counts at a rail: saturated) rather than :class:`~teleop.errors.DeviceTimeoutError`, until a
valid reading comes.

Framed TCP readings carry the bridge's sampling time. The host maps it to its own clock
as ``t_s = t_bridge_s + offset``, where ``offset`` is the smallest ``arrival - t_bridge_s``
seen on the connection: the least-delayed frame bounds the clock offset best, so once one
quick frame has arrived, network jitter and batching no longer move the timestamps. (Until
then they are arrival times: a burst right after connecting is stamped as it arrives.
Clock drift between hosts, ~50 ppm, is ignored: ~3 ms a minute.) A frame whose
``t_bridge_s`` goes back from the last accepted one's, or would lower the offset by more
than :data:`CLOCK_MARGIN_S` at once, cannot be a sampling time of that clock: it is skipped
as ``implausible``, so one bogus time cannot shift every later timestamp. When
:data:`CLOCK_RESYNC_FRAMES` frames in a row are skipped yet agree with one another (the
first frame's time was the bogus one, or the bridge's clock jumped), the clock starts over
from them. Each connection starts a new clock: a restarted bridge's clock starts afresh.
Sequence jumps are counted in ``gaps`` and ``missed``; a reading whose number does not rise (a
repeated or reordered line) is logged, neither a gap nor a loss.
"""

from __future__ import annotations

import logging
import math
import socket
import threading
import time
from collections import Counter
from dataclasses import dataclass, replace

from teleop.devices.base import SampleQueue
from teleop.devices.hx711_protocol import (
    LineSplitter,
    Unreadable,
    import_pyserial,
    parse_frame,
    parse_serial_line,
)
from teleop.devices.loadcell import FIXES, LoadCell
from teleop.errors import DeviceError, DeviceStalledError
from teleop.record import Samples
from teleop.redact import redact_url
from teleop.settings import LoadCellSettings
from teleop.settings_fields import tcp_host_port

__all__ = ["CLOCK_MARGIN_S", "CLOCK_RESYNC_FRAMES", "STALL_S", "BridgeClock", "SerialHx711", "TcpHx711", "parse_tcp_address"]

log = logging.getLogger(__name__)

STALL_S = 0.5  # no valid reading for this long and the cell is down: 40 periods at 80 Hz, 5 at 10 Hz
# Network delay and bridge clock jitter are milliseconds, and a delayed frame raises the offset, never
# lowers it: a frame lowering it by seconds at once carries a bogus time (or the bridge's clock jumped).
CLOCK_MARGIN_S = 2.0
CLOCK_RESYNC_FRAMES = 4  # that many skipped frames agreeing with one another restart the clock: 0.4 s at 10 Hz
_SKIPPED = {"out_of_range": "saturated or out of range", "implausible": "implausible bridge time"}


@dataclass(frozen=True)
class _Quiet:
    """Since when a cell has given no valid reading and what it skipped meanwhile: one value the reader
    thread replaces whole, so a read in another thread never sees a skip counted without its reason, or
    a valid reading's time with the skips before it."""

    since_s: float  # the last valid reading's arrival; before the first, the connection's start
    valid: bool = False  # whether a valid reading came on this connection
    skipped: int = 0  # readings skipped since then
    last_skip: str = ""  # the last one's reason and detail


class _StreamingHx711(LoadCell):
    """A reader thread turning a byte stream into force samples; links implement the rest."""

    skip_first_line = False

    def __init__(self, settings: LoadCellSettings):
        super().__init__(settings)
        self.skipped: Counter[str] = Counter()
        self._queue = SampleQueue()
        self._stop = threading.Event()
        self._reader: threading.Thread | None = None
        self._failure: str | None = None
        self._quiet = _Quiet(0.0)
        # Held by the reader thread to check its connection is current and update the stall state as one step.
        self._lock = threading.Lock()

    def _connect(self) -> None:
        self._open_link()
        self._failure = None
        with self._lock:
            self._quiet = _Quiet(time.monotonic())
        # Per connection: a reader the last close left in a slow receive stops, and writes only its own queue.
        self._stop, self._queue = threading.Event(), SampleQueue()
        self._reader = threading.Thread(target=self._read_forever, args=(self._stop, self._queue), name=repr(self),
                                        daemon=True)
        self._reader.start()

    def _close(self) -> None:
        self._stop.set()
        self._queue.close()  # wake a read waiting in another thread
        if self._reader is not None:
            self._reader.join(timeout=2.0)
        self._close_link()

    def _read_forever(self, stop: threading.Event, queue: SampleQueue) -> None:
        lines = LineSplitter(skip_first=self.skip_first_line)
        while not stop.is_set():
            try:
                data = self._receive()
            except (OSError, DeviceError) as exc:
                if not stop.is_set():
                    self._failure = f"{self!r}: link failed: {exc}"
                    log.warning(self._failure)
                    queue.close()  # a waiting read hears of the failure now, not at its timeout
                return
            if stop.is_set():
                return  # closed during the receive: its bytes belong to no connection now
            arrived = time.monotonic()
            overlong = lines.overlong
            for line in lines.feed(data):
                if stop.is_set():
                    return  # closed meanwhile: what is left belongs to no connection
                try:
                    t_s, counts = self._sample(line, arrived)
                except Unreadable as exc:
                    self._skip(stop, exc.reason, str(exc))
                    continue
                with self._lock:
                    if stop.is_set():
                        return
                    self._quiet = _Quiet(arrived, valid=True)
                queue.put(t_s, float(self.counts_to_force_n(counts)))
            for _ in range(lines.overlong - overlong):
                self._skip(stop, "overlong", f"a line longer than {lines.max_bytes} bytes")

    def _skip(self, stop: threading.Event, reason: str, detail: str) -> None:
        with self._lock:
            if stop.is_set():  # a reader the last close left behind: the next connection's state is not its own
                return
            first = not self.skipped[reason]
            self.skipped[reason] += 1
            quiet = self._quiet
            self._quiet = replace(quiet, skipped=quiet.skipped + 1, last_skip=f"{_SKIPPED.get(reason, reason)}: {detail}")
        # Warn once per reason, then quietly count: a noisy line must not flood the log.
        log.log(logging.WARNING if first else logging.DEBUG, "%r: skipped a reading (%s): %s", self, reason, detail)

    def _take(self, timeout_s: float) -> Samples:
        samples = self._queue.take(timeout_s)
        if not len(samples) and self._failure is not None:
            raise DeviceError(self._failure)
        if not len(samples) and not self._stop.is_set() and (stalled := self._stalled()):
            raise DeviceStalledError(stalled)
        return samples

    def _stalled(self) -> str | None:
        """Why the cell is down when no valid reading came for too long (module docstring); None otherwise."""
        quiet = self._quiet  # one snapshot: the reader thread may replace it meanwhile
        allowed = STALL_S if quiet.valid else max(STALL_S, self.settings.timeout_s)
        quiet_s = time.monotonic() - quiet.since_s
        if quiet_s < allowed:
            return None
        why = (f"{quiet.skipped} readings skipped (the last: {quiet.last_skip})" if quiet.skipped
               else "silent: nothing arrived")
        return f"{self!r}: no valid reading for {quiet_s:.1f} s: {why}"

    # link hooks
    def _open_link(self) -> None:
        raise NotImplementedError

    def _close_link(self) -> None:
        raise NotImplementedError

    def _receive(self) -> bytes:
        """Bytes that arrived (b"" after a short idle wait); OSError or DeviceError when the link is gone."""
        raise NotImplementedError

    def _sample(self, line: bytes, arrived_s: float) -> tuple[float, int]:
        raise NotImplementedError


class SerialHx711(_StreamingHx711):
    """HX711 behind a serial bridge at ``settings.port`` / ``settings.baud`` (pyserial)."""

    skip_first_line = True

    def __init__(self, settings: LoadCellSettings):
        super().__init__(settings)
        # On building, as the backend table does for a missing library: `teleop doctor` says so in its row.
        self._serial = import_pyserial("load cell backend 'serial'")
        self._port = None

    def __repr__(self) -> str:
        return f"<SerialHx711 {self.settings.port}>"

    def _open_link(self) -> None:
        if not self.settings.port:
            raise DeviceError("serial load cell: LoadCellSettings.port is empty; set the serial device path")
        try:
            self._port = self._serial.Serial(self.settings.port, self.settings.baud, timeout=0.1)
        except (self._serial.SerialException, ValueError) as exc:
            raise DeviceError(f"{self!r}: cannot open the port: {exc}: {FIXES['serial']}") from exc

    def _close_link(self) -> None:
        if self._port is not None:
            self._port.close()
            self._port = None

    def _receive(self) -> bytes:
        try:
            return self._port.read(max(1, self._port.in_waiting))
        except self._serial.SerialException as exc:
            raise DeviceError(str(exc)) from exc

    def _sample(self, line: bytes, arrived_s: float) -> tuple[float, int]:
        return arrived_s, parse_serial_line(line)


def parse_tcp_address(address: str) -> tuple[str, int]:
    """``("host", port)`` from ``tcp://host:port``; DeviceError naming the address otherwise."""
    host_port = tcp_host_port(address)
    if host_port is None:
        raise DeviceError(f"load-cell address {address!r}: expected tcp://host:port")
    return host_port


class BridgeClock:
    """Maps bridge sampling times to this host's clock by the least-delayed frame, refusing
    implausible times (see above)."""

    def __init__(self) -> None:
        self.offset_s = math.inf
        self.last_t_bridge_s: float | None = None  # the last accepted frame's
        self._run: list[tuple[float, float]] = []  # (t_bridge_s, offset) of the skipped frames in a row

    def to_host(self, t_bridge_s: float, arrived_s: float) -> float:
        """Host time of a reading taken at ``t_bridge_s`` that arrived at ``arrived_s``; Unreadable
        (``implausible``) for a time this clock cannot have given."""
        offset_s = arrived_s - t_bridge_s
        why = self._implausible(t_bridge_s, offset_s)
        if why is None:
            self._run = []
            self.offset_s = min(self.offset_s, offset_s)
            self.last_t_bridge_s = t_bridge_s
            return t_bridge_s + self.offset_s
        run = self._run
        if run and (t_bridge_s < run[-1][0] or abs(offset_s - min(o for _, o in run)) > CLOCK_MARGIN_S):
            run.clear()  # not the same clock as the frames skipped before it
        run.append((t_bridge_s, offset_s))
        if len(run) < CLOCK_RESYNC_FRAMES:
            raise Unreadable("implausible", why)
        log.warning("bridge clock: %d frames in a row disagree with it but agree with one another: starting over",
                    len(run))
        self.offset_s, self.last_t_bridge_s, self._run = min(o for _, o in run), t_bridge_s, []
        return t_bridge_s + self.offset_s

    def _implausible(self, t_bridge_s: float, offset_s: float) -> str | None:
        if self.last_t_bridge_s is None:
            return None
        if t_bridge_s < self.last_t_bridge_s:
            return f"t_bridge_s {t_bridge_s!r} goes back from the last reading's {self.last_t_bridge_s!r}"
        if offset_s < self.offset_s - CLOCK_MARGIN_S:
            return f"t_bridge_s {t_bridge_s!r} would move the clock by {self.offset_s - offset_s:.6g} s"
        return None


class TcpHx711(_StreamingHx711):
    """HX711 behind a framed-TCP bridge at ``settings.address`` (``tcp://host:port``)."""

    def __init__(self, settings: LoadCellSettings):
        super().__init__(settings)
        self.gaps = 0
        self.missed = 0
        self._socket: socket.socket | None = None
        self._last_seq: int | None = None
        self._clock = BridgeClock()

    def __repr__(self) -> str:
        return f"<TcpHx711 {redact_url(self.settings.address)}>"

    def _open_link(self) -> None:
        host, port = parse_tcp_address(self.settings.address)
        try:
            self._socket = socket.create_connection((host, port), timeout=self.settings.timeout_s)
        except OSError as exc:
            raise DeviceError(f"{self!r}: cannot connect to the bridge: {exc}: {FIXES['tcp']}") from exc
        self._socket.settimeout(0.1)
        self._last_seq, self._clock = None, BridgeClock()  # a new connection, maybe a restarted bridge: a new clock

    def _close_link(self) -> None:
        if self._socket is not None:
            self._socket.close()
            self._socket = None

    def _receive(self) -> bytes:
        try:
            data = self._socket.recv(65536)
        except TimeoutError:
            return b""
        if not data:
            raise DeviceError("the bridge closed the connection")
        return data

    def _sample(self, line: bytes, arrived_s: float) -> tuple[float, int]:
        seq, t_bridge_s, counts = parse_frame(line)
        if self._last_seq is not None and seq <= self._last_seq:
            # One connection is one bridge run: a repeated or reordered line, not a loss.
            log.warning("%r: reading %d came after reading %d (repeated or out of order)", self, seq, self._last_seq)
        else:
            if self._last_seq is not None and seq != self._last_seq + 1:
                self.gaps += 1
                self.missed += seq - self._last_seq - 1
                log.warning("%r: readings %d..%d lost", self, self._last_seq + 1, seq - 1)
            self._last_seq = seq  # the reading arrived, even when its time is refused below
        return self._clock.to_host(t_bridge_s, arrived_s), counts

