"""What the live processes share: endpoint options, the serving loop, signal handling and JSON-lines reports.

The live system is four long-running commands on the bus: ``teleop node`` (robot side),
``estimator serve``, ``haptics serve`` and ``teleop record``; ``teleop demo`` starts them as
separate processes. Each takes its endpoints from the settings' ``[bus]`` table, overridable
on the command line (:func:`add_endpoint_arguments`, :func:`bus_from_args`); each serves in
one loop (:class:`ServiceLoop`) and stops cleanly on SIGINT or SIGTERM, and on SIGHUP unless it has
something to reload on it (:class:`StopSignals`);
the services write one JSON object per grasp to a report file when asked (:class:`JsonLines`).
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import json
import logging
import math
import os
import signal
import threading
from collections.abc import Callable, Iterator
from pathlib import Path
from types import FrameType
from typing import IO, Any

from teleop.clikit import hangup_ignored
from teleop.errors import SettingsError
from teleop.settings import BusSettings, Settings

log = logging.getLogger(__name__)

__all__ = ["ENDPOINTS", "JsonLines", "ServiceLoop", "StopSignals", "add_endpoint_arguments", "bus_from_args",
           "check_duration_s", "sigint_ignored"]

#: Bus endpoint settings a live process may be told to use instead of the settings file's.
ENDPOINTS = BusSettings.ENDPOINTS


def add_endpoint_arguments(parser: argparse.ArgumentParser, *names: str) -> None:
    """``--robot-pub`` etc.: one option per bus endpoint setting in ``names``."""
    fields = {f.name: f for f in dataclasses.fields(BusSettings)}
    for name in names:
        if name not in ENDPOINTS:
            raise SettingsError(f"{name!r} is not a bus endpoint setting; expected one of {', '.join(ENDPOINTS)}")
        parser.add_argument(
            f"--{name.replace('_', '-')}", dest=f"bus_{name}", metavar="ENDPOINT", default=None,
            help=f"{fields[name].metadata['doc']} (default: [bus] {name} of the settings)",
        )


def bus_from_args(settings: Settings, args: argparse.Namespace) -> BusSettings:
    """``settings.bus`` with the endpoints given on the command line."""
    given = {name: getattr(args, f"bus_{name}") for name in ENDPOINTS if getattr(args, f"bus_{name}", None)}
    try:
        return dataclasses.replace(settings.bus, **given)
    except SettingsError as exc:
        raise SettingsError(f"command-line endpoint: {exc}") from None


def check_duration_s(duration_s: Any, error: type[Exception] = ValueError) -> None:
    """Refuse (``error``) a loop's ``duration_s`` that is not None or a finite number of seconds >= 0:
    a NaN deadline is never reached, a negative one passes at once."""
    if duration_s is not None and (isinstance(duration_s, bool) or not isinstance(duration_s, int | float)
                                   or not 0 <= duration_s < math.inf):
        raise error(f"duration_s = {duration_s!r}: expected a finite number of seconds >= 0 (or None: no limit)")


class ServiceLoop:
    """The loop of a long-running process (the robot node, the estimator and the renderer services):
    :meth:`run` takes :meth:`step` after step (each waits a little for work, heartbeats and does
    what is due) until ``stop`` is set or ``duration_s`` passed on the subclass's ``clock``, then
    :meth:`finish`, and returns the subclass's ``stats``."""

    clock: Callable[[], float]
    stats: Any

    def step(self) -> Any:
        raise NotImplementedError

    def finish(self) -> None:
        """What to do once the loop ends (nothing by default)."""

    def wire_stats(self) -> dict[str, Any]:
        """What the service's subscribers (``subscriber``, ``commands``, where it has them) refused on
        the wire, by reason, and the sequence gaps they saw: its summary's count of bad messages is of
        those that decoded."""
        out: dict[str, Any] = {}
        for name in ("subscriber", "commands"):
            sub = getattr(self, name, None)
            if sub is not None:
                stats = sub.stats
                out[name] = {"received": stats.received, "refused": dict(stats.refused), "gaps": stats.gaps,
                             "missed": stats.missed, "restarts": stats.restarts}
        return out

    def run(self, stop: threading.Event, *, duration_s: float | None = None) -> Any:
        """Serve until ``stop.is_set()`` or ``duration_s`` passed."""
        check_duration_s(duration_s)
        deadline = None if duration_s is None else self.clock() + duration_s
        while not stop.is_set() and (deadline is None or self.clock() < deadline):
            self.step()
        self.finish()
        return self.stats


@contextlib.contextmanager
def sigint_ignored(*, stop_signals: bool = False) -> Iterator[None]:
    """SIGINT ignored meanwhile (in the main thread; elsewhere a no-op). A process started meanwhile
    keeps ignoring it, from its first instruction: a Ctrl-C at the terminal reaches the whole process
    group, and such a child is to be stopped by this process (its files closed, not cut mid-write).
    With ``stop_signals`` SIGTERM and SIGHUP too: a stop under way is not to be cut short by another."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    ignored = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP) if stop_signals else (signal.SIGINT,)
    previous = {signum: signal.signal(signum, signal.SIG_IGN) for signum in ignored}
    try:
        yield
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)


class StopSignals:
    """SIGINT, SIGTERM and SIGHUP set :attr:`stop` instead of killing the process (main thread only).

    ``on_hangup`` (optional) is called on SIGHUP instead: the services with something to reload
    (what they read from files) use it. Without it SIGHUP (a closed terminal, an SSH drop) stops the
    process as SIGTERM does, unless SIGHUP was ignored on entry (``nohup``): then it stays ignored.
    Once stopping, further stop signals are ignored: enter this before the services it stops and
    leave it after they closed, so a second signal cannot cut their closing short. The previous
    handlers are restored on exit.
    """

    def __init__(self, *, on_hangup: Callable[[], None] | None = None):
        self.stop = threading.Event()
        self.on_hangup = on_hangup
        self._previous: dict[int, Any] = {}
        self._stop_requested = False

    def _handle(self, signum: int, frame: FrameType | None) -> None:
        if signum == signal.SIGHUP and self.on_hangup is not None:
            self.on_hangup()
        elif not self._stop_requested:
            # A second signal can interrupt this handler inside Event.set(), which holds a plain lock:
            # it must not call set() again (a child of a dying multi-threaded parent gets its
            # parent-death SIGTERM once per parent thread, and deadlocked here).
            self._stop_requested = True
            self.stop.set()

    def __enter__(self) -> StopSignals:
        hangup = self.on_hangup is not None or not hangup_ignored()
        wanted = [signal.SIGINT, signal.SIGTERM] + ([signal.SIGHUP] if hangup else [])
        for signum in wanted:
            self._previous[signum] = signal.signal(signum, self._handle)
        return self

    def __exit__(self, *exc: Any) -> None:
        for signum, handler in self._previous.items():
            signal.signal(signum, handler)
        self._previous.clear()


class JsonLines:
    """A report file with one JSON object per line, each flushed as it is written.

    ``path`` None makes every :meth:`write` a no-op, so callers need no branches. A write that
    fails (a full disk) is logged once and ends the reporting, not the service: the report is a
    by-product, and a service that died of it would take the live session down with it. The
    records written before stay, whole; a report opened on a line such a failure cut short starts
    on a new line.
    """

    def __init__(self, path: str | Path | None):
        self.path = None if path is None else Path(path)
        self._file: IO[str] | None = None
        if self.path is not None:
            try:
                self._file = self.path.open("a", encoding="utf-8")
                if _ends_mid_line(self.path):  # (never cut back: another writer may append to it too)
                    self._file.write("\n")
            except OSError as exc:
                raise SettingsError(f"cannot open report file {self.path}: {exc.strerror or exc}") from exc

    def write(self, record: dict[str, Any]) -> None:
        if self._file is not None:
            try:
                self._file.write(json.dumps(record, allow_nan=False) + "\n")
                self._file.flush()
            except OSError as exc:
                log.error("report %s: %s: reporting stopped, the service carries on", self.path,
                          exc.strerror or exc)
                self.close()

    def close(self) -> None:
        if self._file is not None:
            file, self._file = self._file, None
            # Every write was flushed: all closing can fail on is a write's leftover, whose failure was logged.
            with contextlib.suppress(OSError):
                file.close()

    def __enter__(self) -> JsonLines:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()


def _ends_mid_line(path: Path) -> bool:
    """Whether the file at ``path`` ends without a newline (a write a full disk cut short); a pipe or
    an empty file does not."""
    with path.open("rb") as file:
        if not file.seekable() or file.seek(0, os.SEEK_END) == 0:
            return False
        file.seek(-1, os.SEEK_END)
        return file.read(1) != b"\n"
