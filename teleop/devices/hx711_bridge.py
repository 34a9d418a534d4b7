"""The sending side of the framed-TCP load cell (served by ``teleop hx711-bridge``).

Runs where the HX711 is (e.g. a Raspberry Pi), with the standard library only (pyserial
for :class:`SerialCounts`). It takes readings from a source, stamps each with the bridge's
monotonic clock when it is taken, and sends it as one frame of the protocol in
:mod:`teleop.devices.hx711_protocol` to every connected host (the ``tcp`` load-cell
backend). Sources: :class:`FakeHx711` (a simulated cell, for tests and demos) and
:class:`SerialCounts` (an Arduino-style HX711 bridge, re-served framed over the network).
Any callable returning counts can be served.

Sending never blocks on one host: each host's socket is non-blocking with its own output
buffer, and a host that stops reading (its buffer holds data older than ``send_timeout_s``, or
more than ``max_buffered_bytes``) is dropped, so it cannot stall the others. At most
``max_clients`` hosts are served (a rig has a handful; the cap keeps a connection flood from
exhausting file descriptors), further connections are refused with a log line.
When the source fails (a serial device unplugged) the bridge stops serving and closes every
host's connection, so each sees its link fail rather than silence; :attr:`Hx711Bridge.failure`
says why, and ``on_failure`` is told at once.
"""

from __future__ import annotations

import errno
import logging
import random
import socket
import threading
import time
from collections import deque
from collections.abc import Callable

from teleop.devices.hx711_protocol import (
    COUNTS_MAX,
    COUNTS_MIN,
    LineSplitter,
    Unreadable,
    format_frame,
    import_pyserial,
    parse_serial_line,
)
from teleop.errors import DeviceError

__all__ = ["FakeHx711", "Hx711Bridge", "SerialCounts"]

log = logging.getLogger(__name__)

SKIP_BUDGET_S = 0.1  # SerialCounts returns None after this long of only skipped lines: the loop keeps control


def _is_decade(count: int) -> bool:
    """Whether the ``count``-th of a repeated event is logged: the 1st, 10th, 100th, ... (as
    :func:`teleop.bus.pubsub.is_decade`; not imported, as that module needs zmq and this one runs
    on the standard library alone)."""
    return count == 10 ** (len(str(count)) - 1)


class FakeHx711:
    """A simulated HX711: counts of ``force_n`` through the cell's calibration, paced at ``rate_hz``.

    Parameters
    ----------
    counts_per_n, tare_counts : float, int
        The calibration the host will undo (``LoadCellSettings``).
    rate_hz : float
        Readings per second; each call blocks until the next one is due.
    force_n : float or callable
        Force in newtons, constant or a function of seconds since the first reading.
    noise_counts : float
        Standard deviation of Gaussian noise added to each reading, in counts.
    seed : int
        Seed of the noise.
    """

    def __init__(
        self,
        *,
        counts_per_n: float,
        tare_counts: int = 0,
        rate_hz: float = 80.0,
        force_n: float | Callable[[float], float] = 0.0,
        noise_counts: float = 0.0,
        seed: int = 0,
    ):
        self.counts_per_n = counts_per_n
        self.tare_counts = tare_counts
        self.period_s = 1.0 / rate_hz
        self.force_n = force_n if callable(force_n) else (lambda _t, f=float(force_n): f)
        self.noise_counts = noise_counts
        self._random = random.Random(seed)
        self._start_s: float | None = None
        self._next_s = 0.0

    def __call__(self) -> int:
        now = time.monotonic()
        if self._start_s is None:
            self._start_s = self._next_s = now
        time.sleep(max(0.0, self._next_s - now))
        t = self._next_s - self._start_s
        self._next_s += self.period_s
        counts = self.force_n(t) * self.counts_per_n + self.tare_counts + self._random.gauss(0.0, self.noise_counts)
        return min(max(round(counts), COUNTS_MIN + 1), COUNTS_MAX - 1)


class SerialCounts:
    """Readings from an Arduino-style serial HX711 bridge (serial line protocol); pyserial."""

    def __init__(self, port: str, baud: int = 115200):
        serial = import_pyserial("the serial HX711 source (--serial)")
        self.port = port
        try:
            self._port = serial.Serial(port, baud, timeout=0.5)
        except (serial.SerialException, ValueError) as exc:
            raise DeviceError(f"serial HX711 at {port}: cannot open the port: {exc}") from exc
        self._lines = LineSplitter(skip_first=True)
        self._ready: deque[int] = deque()
        self.skipped: dict[str, int] = {}  # lines skipped, by reason

    def __call__(self) -> int | None:
        """The next valid reading, or None when the line stayed idle for 0.5 s or carried only
        skipped lines for :data:`SKIP_BUDGET_S`; DeviceError when the port failed (e.g. the device
        was unplugged)."""
        give_up_s = time.monotonic() + SKIP_BUDGET_S
        while not self._ready:
            if time.monotonic() >= give_up_s:
                return None  # garbage only so far: let the bridge loop check its hosts and stop
            try:
                data = self._port.read(max(1, self._port.in_waiting))
            except OSError as exc:  # pyserial's SerialException is one; in_waiting's ioctl raises a bare one
                raise DeviceError(f"serial HX711 at {self.port}: the port failed: {exc}: check the cable, then start "
                                  "the bridge again") from exc
            if not data:
                return None
            for line in self._lines.feed(data):
                try:
                    self._ready.append(parse_serial_line(line))
                except Unreadable as exc:
                    n = self.skipped[exc.reason] = self.skipped.get(exc.reason, 0) + 1
                    if _is_decade(n):
                        log.warning("serial HX711 at %s: skipped a line (%s, %d so far): %s", self.port, exc.reason, n, exc)
        return self._ready.popleft()

    def close(self) -> None:
        self._port.close()


class _Host:
    """One connected host: its non-blocking socket and the bytes not yet taken by it."""

    def __init__(self, sock: socket.socket, peer: str):
        self.sock, self.peer = sock, peer
        self.out = bytearray()
        self.behind_since_s: float | None = None  # when data began waiting for it, if it does

    def flush(self, now_s: float) -> None:
        """Send what the socket takes now; OSError when the host is gone."""
        if self.out:
            try:
                sent = self.sock.send(self.out)
            except (BlockingIOError, InterruptedError):
                sent = 0
            del self.out[:sent]
        if not self.out:
            self.behind_since_s = None
        elif self.behind_since_s is None:
            self.behind_since_s = now_s

    def departed(self) -> bool:
        """Whether the host left: hosts never send, so a readable socket has reached EOF or failed."""
        try:
            return not self.sock.recv(1, socket.MSG_PEEK | socket.MSG_DONTWAIT)  # data: a host that talks is there
        except (BlockingIOError, InterruptedError):
            return False
        except OSError:
            return True


class Hx711Bridge:
    """Serves readings from ``read_counts`` as framed TCP to every connected host.

    Parameters
    ----------
    read_counts : callable
        Blocks until the next reading and returns its counts (None: nothing this time).
    host, port : str, int
        Where to listen; port 0 picks a free one (see :attr:`address`).
    send_timeout_s : float
        A host that has left data untaken for this long is dropped.
    max_buffered_bytes : int
        A host with more than this many bytes untaken is dropped.
    max_clients : int
        Hosts served at once; further connections are refused (closed at once, logged).
    on_failure : callable, optional
        Called with :attr:`failure` from the sending thread when the source fails (without one,
        the failure is logged).
    """

    def __init__(
        self,
        read_counts: Callable[[], int | None],
        *,
        host: str = "0.0.0.0",
        port: int = 5601,
        send_timeout_s: float = 1.0,
        max_buffered_bytes: int = 64 * 1024,
        max_clients: int = 64,
        on_failure: Callable[[str], None] | None = None,
    ):
        self.read_counts = read_counts
        self.on_failure = on_failure
        self.failure: str | None = None  # why the source failed, once it has
        self.host, self.port = host, port
        self.send_timeout_s = send_timeout_s
        self.max_buffered_bytes = max_buffered_bytes
        self.max_clients = max_clients
        self.sent = 0  # readings taken and framed (sent to however many hosts were there)
        self.refused = 0  # connections refused: max_clients were served
        self.accept_errors = 0  # accept() failures (e.g. out of file descriptors), each retried
        self._server: socket.socket | None = None
        self._clients: list[_Host] = []
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []

    @property
    def address(self) -> str:
        """``tcp://host:port`` the bridge listens on (the real port once started)."""
        return f"tcp://{self.host}:{self.port}"

    @property
    def clients(self) -> int:
        with self._lock:
            return len(self._clients)

    def start(self) -> Hx711Bridge:
        try:
            server = socket.create_server((self.host, self.port))
        except OSError as exc:
            fix = (": another program (a bridge still running?) holds the port: stop it or choose another "
                   "(teleop hx711-bridge --port PORT, or --port 0 for any free one)"
                   if exc.errno == errno.EADDRINUSE else "")
            raise DeviceError(f"HX711 bridge cannot listen on {self.address}: {exc}{fix}") from exc
        server.settimeout(0.2)
        self._server = server
        self.port = server.getsockname()[1]
        self._stop.clear()
        self._threads = [
            threading.Thread(target=self._accept_forever, args=(server,), name="hx711-bridge-accept", daemon=True),
            threading.Thread(target=self._serve_forever, name="hx711-bridge-send", daemon=True),
        ]
        for thread in self._threads:
            thread.start()
        return self

    def close(self) -> None:
        self._stop.set()
        for thread in self._threads:
            thread.join(timeout=2.0)
        self._threads = []
        if self._server is not None:
            self._server.close()
            self._server = None
        with self._lock:
            for client in self._clients:
                client.sock.close()
            self._clients.clear()

    def __enter__(self) -> Hx711Bridge:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _accept_forever(self, server: socket.socket) -> None:
        while not self._stop.is_set():
            try:
                client, peer = server.accept()
            except TimeoutError:
                continue
            except OSError as exc:
                if self._stop.is_set() or server.fileno() == -1:
                    return  # closed: nothing more to accept
                # e.g. EMFILE, out of file descriptors: the listening socket is fine, so keep accepting
                self.accept_errors += 1
                if _is_decade(self.accept_errors):
                    log.warning("HX711 bridge: cannot accept a host (%d so far), retrying: %s", self.accept_errors, exc)
                time.sleep(0.1 if exc.errno in (errno.EMFILE, errno.ENFILE, errno.ENOBUFS, errno.ENOMEM) else 0.01)
                continue
            where = f"{peer[0]}:{peer[1]}"
            try:
                client.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)  # one reading, one packet
                client.setblocking(False)  # never wait on one host: see _Host.flush
            except OSError:  # gone already
                client.close()
                continue
            with self._lock:
                if self._stop.is_set():  # closed, or the source failed, meanwhile: nothing to serve
                    client.close()
                    return
                full = len(self._clients) >= self.max_clients
                if not full:
                    self._clients.append(_Host(client, where))
            if full:
                self.refused += 1  # counted before the host can see the refusal
                client.close()
                if _is_decade(self.refused):
                    log.warning("HX711 bridge: refused host %s: already serving %d hosts (%d refused so far)",
                                where, self.max_clients, self.refused)
                continue
            log.info("HX711 bridge: host %s connected", where)

    def _serve_forever(self) -> None:
        seq = 0
        while not self._stop.is_set():
            try:  # any failure, the source's or the loop's: this thread's end would leave the hosts on silence
                counts = self.read_counts()
                frame = None
                if counts is not None:
                    frame = format_frame(seq, time.monotonic(), counts)
                    seq += 1
                    self.sent += 1
                self._send(frame)
            except Exception as exc:
                self._fail(exc)
                return

    def _send(self, frame: bytes | None) -> None:
        """Queue ``frame`` (if any) for every host and send what each takes now; drop hosts that
        left, failed, or fell behind (see the class's parameters)."""
        now_s = time.monotonic()
        with self._lock:
            for client in list(self._clients):
                why = None
                if client.departed():
                    why = "it left"
                else:
                    if frame is not None:
                        client.out += frame
                    try:
                        client.flush(now_s)
                    except OSError as exc:
                        why = f"the connection failed: {exc}"
                    else:
                        if len(client.out) > self.max_buffered_bytes:
                            why = f"it fell behind by more than {self.max_buffered_bytes} bytes"
                        elif client.behind_since_s is not None and now_s - client.behind_since_s > self.send_timeout_s:
                            why = f"it took no data for {self.send_timeout_s:g} s"
                if why is not None:
                    log.info("HX711 bridge: dropped host %s: %s", client.peer, why)
                    client.sock.close()
                    self._clients.remove(client)

    def _fail(self, exc: Exception) -> None:
        """Stop serving and close every host's connection: each sees its link fail."""
        self.failure = str(exc) if isinstance(exc, DeviceError) else f"the source failed: {exc!r}"
        with self._lock:
            self._stop.set()
            for client in self._clients:
                client.sock.close()
            self._clients.clear()
        if self.on_failure is None:
            log.error("HX711 bridge: stopped serving: %s", self.failure)
        else:  # it reports the failure: said once
            self.on_failure(self.failure)
