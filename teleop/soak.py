"""A bounded soak test of the grasp data path on loopback.

This process plays the robot node: it publishes, through the real lossless
:class:`~teleop.bus.pubsub.Publisher`, two 30 Hz tactile streams (JPEG frames from the
simulated camera, :func:`soak_frames`), force batches at 80 Hz and width batches at 10 Hz,
on a schedule, for the time asked. A second process consumes them: the session recorder
(:class:`~teleop.session.recorder.SessionRecorder`, writing a real MCAP log, deleted at the
end unless ``log_path`` names where to keep it) with a monitor on every stored message.
However the run ends (Ctrl-C included), the consumer is stopped and the temporary log removed.

Reported (:class:`SoakResult`):

``lost_grasp_msgs``
    Grasp messages sent but never stored, plus sends that timed out (a lossless send that
    found no room): must be 0.
``rss_growth_mb``
    The consumer's resident memory at the end minus after the warm-up (``warmup_s``,
    default a fifth of the run, at most 60 s): the steady-state growth.
``p50_ms``, ``p99_ms``, ``max_ms``
    Send-to-receive latency (``t_send_ns`` of the header to the recorder's receive time,
    both ``time.monotonic_ns()`` of this host), from a fixed log-spaced histogram (bins
    0.5 % wide), so the monitor's own memory does not grow with the run.
"""

from __future__ import annotations

import contextlib
import multiprocessing
import os
import queue
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from teleop.bus.pubsub import Publisher
from teleop.bus.wire import Message
from teleop.errors import BusTimeoutError, SettingsError, TeleopError
from teleop.live import sigint_ignored
from teleop.progress import progress_bar
from teleop.settings import Settings, default_settings_path, load_settings

__all__ = ["GRASP_RATES_HZ", "LatencyHistogram", "SoakResult", "check_log_path", "rss_bytes", "run_soak",
           "soak_frames"]

#: Messages per second of each grasp topic, as the robot node publishes them.
GRASP_RATES_HZ = {"frame/left": 30.0, "frame/right": 30.0, "force": 80.0, "width": 10.0}
MIN_DURATION_S = 1.0 / min(GRASP_RATES_HZ.values())  # every topic sends at least once
DEFAULT_WARMUP_FRACTION = 0.2
MAX_DEFAULT_WARMUP_S = 60.0
RSS_SAMPLE_S = 1.0
CONSUMER_START_TIMEOUT_S = 30.0
CONSUMER_STOP_TIMEOUT_S = 60.0
CONSUMER_QUIT_S = 5.0  # a run cut short gives the consumer this long to close its log before it is killed


def rss_bytes(pid: int | str = "self") -> int:
    """Resident set size of process ``pid`` (bytes), from ``/proc/<pid>/statm`` (Linux)."""
    try:
        resident_pages = int(Path(f"/proc/{pid}/statm").read_text().split()[1])
    except (OSError, IndexError, ValueError) as exc:
        raise TeleopError(f"cannot read the memory of process {pid} from /proc: {exc}") from exc
    return resident_pages * os.sysconf("SC_PAGE_SIZE")


class LatencyHistogram:
    """Latencies in a fixed set of log-spaced bins: constant memory however long the run.

    Bins run from ``lo_ms`` to ``hi_ms`` with edges a factor ``1 + resolution`` apart;
    values outside land in the first or last bin. Quantiles are the upper edge of the
    bin they fall in (at most ``resolution`` above the true value).
    """

    def __init__(self, *, lo_ms: float = 1e-3, hi_ms: float = 1e5, resolution: float = 0.005):
        n = int(np.ceil(np.log(hi_ms / lo_ms) / np.log1p(resolution)))
        self.edges_ms = lo_ms * (1 + resolution) ** np.arange(n + 1)
        self.counts = np.zeros(n + 1, dtype=np.int64)
        self.max_ms = 0.0

    def add(self, latency_ms: float) -> None:
        self.counts[min(int(np.searchsorted(self.edges_ms, latency_ms)), len(self.counts) - 1)] += 1
        self.max_ms = max(self.max_ms, latency_ms)

    @property
    def count(self) -> int:
        return int(self.counts.sum())

    def quantile_ms(self, q: float) -> float | None:
        """The ``q`` quantile (0..1), or None with no values."""
        total = self.count
        if total == 0:
            return None
        index = int(np.searchsorted(np.cumsum(self.counts), q * total))
        # a bin's upper edge, but never above the largest value seen (the top bin's edge can be)
        return min(float(self.edges_ms[min(index, len(self.edges_ms) - 1)]), self.max_ms)


def check_log_path(path: str | Path, *, name: str = "session log") -> Path:
    """``path`` as a :class:`Path` when a new session log can be created there (the consumer process
    creates it, and its error would come as that process's traceback).

    Raises
    ------
    SettingsError
        ``path`` exists, or its folder does not exist or cannot be written to; the message starts
        with ``name`` and the path.
    """
    path = Path(path)
    folder = path.parent
    if os.path.lexists(path):
        raise SettingsError(f"{name} {path} exists: name a new file")
    if not folder.is_dir():
        what = "is not a folder" if folder.exists() else "does not exist"
        raise SettingsError(f"{name} {path}: its folder {folder} {what}")
    if not os.access(folder, os.W_OK | os.X_OK):
        raise SettingsError(f"{name} {path}: cannot create files in the folder {folder} (permission denied)")
    return path


def soak_frames(settings: Settings, *, count: int = 30, seed: int = 0) -> dict[str, list[bytes]]:
    """``count`` JPEG frames per sensor from the simulated camera: a ball pressed ever deeper.

    The frames are what the sensors' simulated cameras deliver (raw size, noise, JPEG at
    ``simulation.jpeg_quality``), so their sizes are those of a live grasp.
    """
    from teleop.sim.optics import OpticsRenderer

    frames = {}
    weights = np.linspace(0.0, 1.0, count)[:, None]
    for sensor in settings.sensors:
        camera = OpticsRenderer(sensor, sim=settings.simulation, rng=np.random.default_rng(seed))
        rows, cols = sensor.image_shape
        y_m, x_m = np.mgrid[:rows, :cols] * sensor.pixel_pitch_m
        r2_m2 = (x_m - x_m.mean()) ** 2 + (y_m - y_m.mean()) ** 2
        radius_m, depth_m = 0.01, 1e-3  # a 10 mm ball pressed 1 mm deep
        dent_m = np.clip(depth_m - r2_m2 / (2 * radius_m), 0.0, None)
        frames[sensor.finger] = camera.capture_series(dent_m[None], weights)
    return frames


# --------------------------------------------------------------------------- consumer process


class _Monitor:
    """The recorder's hook: latency histogram and stored grasp messages per topic."""

    def __init__(self) -> None:
        self.latency = LatencyHistogram()
        self.received: dict[str, int] = dict.fromkeys(GRASP_RATES_HZ, 0)

    def __call__(self, message: Message, received_ns: int) -> None:
        if message.topic in self.received:
            self.received[message.topic] += 1
            self.latency.add((received_ns - message.t_send_ns) * 1e-6)


def _consume(endpoint: str, log_path: str, settings_path: str, warmup_s: float, ready: Any, stop: Any,
             results: Any) -> None:
    """The consumer process: record ``endpoint`` into ``log_path`` until ``stop``; results to the queue."""
    from teleop.session.recorder import SessionRecorder

    parent = multiprocessing.parent_process()
    monitor = _Monitor()
    recorder = SessionRecorder(log_path, endpoint, settings=load_settings(settings_path), source="simulated", on_message=monitor)
    rss = {"start": rss_bytes(), "warm": None, "peak": 0}
    started = time.monotonic()
    next_sample = started
    try:
        recorder.open()
        ready.set()
        # A parent that died without stopping this process (SIGKILL) publishes nothing more.
        while not stop.is_set() and not recorder.failed and (parent is None or parent.is_alive()):
            recorder.poll(0.05)
            now = time.monotonic()
            if now >= next_sample:
                current = rss_bytes()
                rss["peak"] = max(rss["peak"], current)
                if rss["warm"] is None and now - started >= warmup_s:
                    rss["warm"] = current
                next_sample = now + RSS_SAMPLE_S
    finally:
        stats = recorder.close()
    end = rss_bytes()
    results.put({
        "received": monitor.received,
        "latency_counts": monitor.latency.counts.tolist(),
        "max_ms": monitor.latency.max_ms,
        "rss_start": rss["start"],
        "rss_warm": end if rss["warm"] is None else rss["warm"],
        "rss_end": end,
        "rss_peak": max(rss["peak"], end),
        "recorder": stats.as_dict(),
    })


# --------------------------------------------------------------------------- producer


@dataclass
class SoakResult:
    """What a soak run measured (see the module docstring)."""

    duration_s: float
    sent: dict[str, int]
    received: dict[str, int]
    send_timeouts: int
    lost_grasp_msgs: int
    gaps: int
    refused: int
    frame_bytes_mean: float
    p50_ms: float | None
    p99_ms: float | None
    max_ms: float
    rss_start_mb: float
    rss_warm_mb: float
    rss_end_mb: float
    rss_peak_mb: float
    rss_growth_mb: float
    log_bytes: int
    recorder_error: str | None

    def as_dict(self) -> dict[str, Any]:
        return dict(self.__dict__)


def _round(value: float | None, digits: int = 3) -> float | None:
    return None if value is None else round(value, digits)


def run_soak(settings: Settings, *, duration_s: float, warmup_s: float | None = None,
             settings_path: str | Path | None = None, log_path: str | Path | None = None,
             progress: bool = False) -> SoakResult:
    """Publish the grasp streams for ``duration_s`` into a recorder process; measure it.

    Parameters
    ----------
    settings : Settings
        Sensors (for the frames) and the bus size limit.
    duration_s : float
        How long to publish (s), > 0.
    warmup_s : float, optional
        When the consumer's memory is first taken (s after it started); default a fifth
        of ``duration_s``, at most 60 s.
    settings_path : path, optional
        The settings file the consumer loads (the shipped one by default).
    log_path : path, optional
        Keep the session log here; by default it goes to a temporary directory and is deleted.
    progress : bool
        A tqdm bar on stderr.

    Raises
    ------
    SettingsError
        ``duration_s`` or ``warmup_s`` out of range, or no new file can be created at ``log_path``.
    TeleopError
        The consumer does not start or does not report.
    """
    if not (np.isfinite(duration_s) and duration_s >= MIN_DURATION_S):
        raise SettingsError(f"soak duration {duration_s!r} s: expected a finite number of at least {MIN_DURATION_S:g} s "
                            "(one period of the slowest topic)")
    if warmup_s is None:
        warmup_s = min(MAX_DEFAULT_WARMUP_S, DEFAULT_WARMUP_FRACTION * duration_s)
    if not (np.isfinite(warmup_s) and 0 <= warmup_s < duration_s):
        raise SettingsError(f"warm-up {warmup_s!r} s: expected 0 <= warm-up < the duration {duration_s} s")
    if log_path is not None:
        log_path = check_log_path(log_path)
    frames = soak_frames(settings)
    fingers = [s.finger for s in settings.sensors]
    if sorted(f"frame/{f}" for f in fingers) != sorted(t for t in GRASP_RATES_HZ if t.startswith("frame/")):
        raise SettingsError(f"the soak streams the fingers left and right; the settings have {fingers}")
    with contextlib.ExitStack() as stack:
        if log_path is None:
            log_path = Path(stack.enter_context(tempfile.TemporaryDirectory(prefix="soak-"))) / "soak.mcap"
        publisher = stack.enter_context(Publisher("tcp://127.0.0.1:*", lossless=True, source="robot",
                                                  max_bytes=settings.bus.max_message_bytes))
        spawn = multiprocessing.get_context("spawn")  # no forked ZeroMQ context in the child
        ready, stop, results = spawn.Event(), spawn.Event(), spawn.Queue()
        consumer = spawn.Process(
            target=_consume, name="soak-consumer", daemon=True,
            args=(publisher.endpoint, str(log_path), str(settings_path or default_settings_path()), warmup_s,
                  ready, stop, results))
        with sigint_ignored():  # the consumer is stopped by this process (_stop_consumer)
            consumer.start()
        stack.callback(_stop_consumer, consumer, stop)  # if something below raised (Ctrl-C too); a no-op after join
        deadline = time.monotonic() + CONSUMER_START_TIMEOUT_S
        while not ready.wait(0.1):
            if not consumer.is_alive() or time.monotonic() > deadline:
                raise TeleopError(f"the soak consumer did not start (exit status {consumer.exitcode}; its "
                                  "error, if any, is above)")
        publisher.wait_for_subscriber("frame", timeout_s=CONSUMER_START_TIMEOUT_S)
        sent, timeouts, elapsed_s = _publish(publisher, frames, duration_s, progress=progress)
        stop.set()
        report = _report(results, consumer)
        consumer.join(timeout=CONSUMER_STOP_TIMEOUT_S)
    histogram = LatencyHistogram()
    histogram.counts[:] = report["latency_counts"]
    histogram.max_ms = report["max_ms"]
    received = report["received"]
    recorder = report["recorder"]
    mb = 1 / 2**20
    frame_sizes = [len(f) for stream in frames.values() for f in stream]
    return SoakResult(
        duration_s=round(elapsed_s, 3),
        sent=sent,
        received=received,
        send_timeouts=timeouts,
        lost_grasp_msgs=timeouts + sum(sent.values()) - sum(received.values()),
        gaps=recorder["gaps"],
        refused=sum(recorder["refused"].values()),
        frame_bytes_mean=round(float(np.mean(frame_sizes)), 1),
        p50_ms=_round(histogram.quantile_ms(0.5)),
        p99_ms=_round(histogram.quantile_ms(0.99)),
        max_ms=_round(report["max_ms"]),
        rss_start_mb=_round(report["rss_start"] * mb),
        rss_warm_mb=_round(report["rss_warm"] * mb),
        rss_end_mb=_round(report["rss_end"] * mb),
        rss_peak_mb=_round(report["rss_peak"] * mb),
        rss_growth_mb=_round((report["rss_end"] - report["rss_warm"]) * mb),
        log_bytes=recorder["file_bytes"],
        recorder_error=recorder["error"],
    )


def _stop_consumer(consumer: Any, stop: Any) -> None:
    """Ask the consumer to close its log and quit; kill it if it does not within ``CONSUMER_QUIT_S``."""
    stop.set()
    try:
        consumer.join(timeout=CONSUMER_QUIT_S)
    finally:  # a second Ctrl-C during the wait must still not leave it running
        if consumer.is_alive():
            consumer.kill()
            consumer.join(timeout=1.0)


def _report(results: Any, consumer: Any) -> dict[str, Any]:
    """The consumer's report, once it has drained and closed its log."""
    deadline = time.monotonic() + CONSUMER_STOP_TIMEOUT_S
    while time.monotonic() < deadline:
        with contextlib.suppress(queue.Empty):
            return results.get(timeout=0.1)
        if not consumer.is_alive():
            break
    raise TeleopError(f"the soak consumer did not report (exit status {consumer.exitcode}; its error, if any, "
                      "is above)")


def _publish(publisher: Publisher, frames: dict[str, list[bytes]], duration_s: float, *,
             progress: bool) -> tuple[dict[str, int], int, float]:
    """Send every topic of :data:`GRASP_RATES_HZ` on its schedule; (sent per topic, timeouts, seconds)."""
    topics = list(GRASP_RATES_HZ)
    period_s = np.array([1.0 / GRASP_RATES_HZ[t] for t in topics])
    start = time.monotonic()
    due = start + period_s * np.arange(len(topics)) / len(topics)  # staggered, as devices are
    sent = dict.fromkeys(topics, 0)
    timeouts = 0
    with progress_bar(total=round(duration_s), unit="s", desc="soak", enabled=progress) as bar:
        while True:
            k = int(np.argmin(due))
            t_due = float(due[k])
            if t_due - start >= duration_s:
                break
            if (wait := t_due - time.monotonic()) > 0:
                time.sleep(wait)
            publisher.heartbeat_if_due()
            topic, n = topics[k], sent[topics[k]]
            try:
                _send(publisher, topic, n, t_due, frames)
                sent[topic] += 1
            except BusTimeoutError:
                timeouts += 1
            due[k] += period_s[k]
            if (whole_s := int(time.monotonic() - start)) > bar.n:
                bar.update(whole_s - bar.n)
        bar.update(bar.total - bar.n)  # the last whole second may not have passed: the run is done
    return sent, timeouts, time.monotonic() - start


def _send(publisher: Publisher, topic: str, n: int, t_s: float, frames: dict[str, list[bytes]]) -> None:
    """Message ``n`` of ``topic`` captured at ``t_s``, as the robot node sends it during a grasp."""
    if topic.startswith("frame/"):
        finger = topic.split("/", 1)[1]
        stream = frames[finger]
        publisher.send("frame", t_capture_s=t_s, finger=finger, grasp_id="soak", index=n, encoding="jpeg",
                       data=stream[n % len(stream)])
    elif topic == "force":  # one load-cell reading per batch, a slow squeeze-and-release
        publisher.send("force", t_capture_s=t_s, grasp_id="soak", t_s=[t_s],
                       value_n=[5.0 + 4.0 * np.sin(0.5 * t_s)])
    else:
        publisher.send("width", t_capture_s=t_s, grasp_id="soak", t_s=[t_s],
                       value_m=[0.04 + 0.01 * np.sin(0.5 * t_s)])
