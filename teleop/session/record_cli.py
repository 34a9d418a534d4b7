"""``teleop record``: record every bus message of a session into an MCAP log.

Stops after --duration-s, or on Ctrl-C / SIGTERM / SIGHUP, and then writes the log's summary and
footer. A recorder killed outright leaves a log without them: ``teleop recover`` fixes it.
A write error (a full disk) stops the recording, not the session: the command then exits with
status 3 (:data:`~teleop.session.recorder.RECORDING_STOPPED_STATUS`), its last line saying why.
An endpoint whose handshake failed and never succeeded (its client key not authorised, keys on one
end only) gave nothing: the summary names each with the fix, and the command exits with status 1
(:data:`NEVER_CONNECTED_STATUS`; 3 when a write error stopped it too), the log keeping what the
other endpoints sent.
With ``--foxglove`` it also serves what it records live to Foxglove.
An --out that another recorder is still writing is refused, --overwrite or not
(:mod:`teleop.session.recordfile`).
"""

from __future__ import annotations

import argparse
import json
import signal
import sys
import threading
from pathlib import Path

from teleop.bus.security import security_from_settings
from teleop.catalogue import default_catalogue_path, load_catalogue
from teleop.clikit import hangup_ignored, positive_int, positive_number
from teleop.errors import SessionLogError, SettingsError
from teleop.scene import load_scene
from teleop.session.foxglove_live import LiveServer, add_foxglove_argument
from teleop.session.logfile import CHUNK_BYTES
from teleop.session.recorder import (
    COMPRESSIONS,
    RECORDING_STOPPED,
    RECORDING_STOPPED_STATUS,
    RecorderStats,
    SessionRecorder,
)
from teleop.settings import load_settings

# `teleop record`'s exit status when it ran but an endpoint never connected: the log lacks all of it.
NEVER_CONNECTED_STATUS = 1


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", required=True, metavar="FILE.mcap", help="session log to create")
    parser.add_argument(
        "--overwrite", action="store_true", help="replace --out if it exists instead of refusing (never one another recorder is writing)"
    )
    parser.add_argument(
        "--settings",
        metavar="FILE",
        default=None,
        help="settings TOML the session runs with (stored in the log, a URL's password as ***; bus keys, size limit "
        "and default endpoints come from it; default: the shipped one)",
    )
    parser.add_argument(
        "--endpoint",
        action="append",
        metavar="ENDPOINT",
        default=None,
        help="publisher endpoint to subscribe to, every topic (repeatable); default: the "
        "settings' bus.robot_pub, bus.estimate_pub, bus.command and bus.display_pub",
    )
    parser.add_argument(
        "--duration-s",
        type=float,
        default=None,
        metavar="S",
        help="stop after S seconds (default: run until Ctrl-C or SIGTERM)",
    )
    parser.add_argument(
        "--scene",
        default="",
        metavar="NAME",
        help="scene name or TOML path the session runs (recorded, and its file attached; default: none recorded)",
    )
    parser.add_argument(
        "--source",
        choices=("auto", "simulated", "hardware"),
        default="auto",
        help="what produced the data; auto: simulated when every backend in the settings is 'sim'",
    )
    parser.add_argument(
        "--objects",
        metavar="PATH",
        default=None,
        help="object catalogue attached to the log, so `teleop export` can label grasps "
        "(default: the --scene's catalogue, else the shipped configs/objects.toml)",
    )
    parser.add_argument(
        "--chunk-kib",
        type=positive_int,
        default=CHUNK_BYTES // 1024,
        metavar="KIB",
        help="MCAP chunk size in KiB: a killed recorder loses at most one chunk",
    )
    parser.add_argument(
        "--flush-interval-s",
        type=positive_number,
        default=0.5,
        metavar="S",
        help="write the open chunk at the latest S seconds after its first message",
    )
    parser.add_argument(
        "--compression", choices=sorted(COMPRESSIONS), default="zstd", help="chunk compression"
    )
    add_foxglove_argument(parser, what="the messages as they are recorded")
    parser.add_argument(
        "--json",
        action="store_true",
        help="print one JSON object (out, messages, saved_messages, message_bytes, file_bytes, "
        "topics, refused, gaps, missed, not_stored, error, never_connected) as the last stdout line",
    )


def run(args: argparse.Namespace) -> int:
    out = Path(args.out)
    if args.duration_s is not None and not args.duration_s > 0:
        raise SessionLogError(f"--duration-s {args.duration_s}: expected a number > 0")
    settings = load_settings(args.settings)
    bus = settings.bus
    endpoints = args.endpoint or [bus.robot_pub, bus.estimate_pub, bus.command, bus.display_pub]
    live = None if args.foxglove is None else LiveServer(*args.foxglove, fingers=[s.finger for s in settings.sensors])
    try:
        if live is not None:
            print(f"Foxglove live view: {live.url}", file=sys.stderr, flush=True)
        recorder = SessionRecorder(
            out,
            endpoints,
            settings=settings,
            scene=args.scene,
            source=None if args.source == "auto" else args.source,
            catalogue=_catalogue(args),
            chunk_bytes=args.chunk_kib * 1024,
            flush_interval_s=args.flush_interval_s,
            compression=args.compression,
            max_bytes=settings.bus.max_message_bytes,
            security=security_from_settings(settings.bus),
            on_foxglove=None if live is None else live.log,
            overwrite=args.overwrite,
        )
        stats = _record_until_stopped(recorder, args.duration_s)
    finally:
        if live is not None:
            live.close()
    reasons = ", ".join(f"{n} {reason}" for reason, n in sorted(stats.refused.items()))
    # After a write error only the chunks written before it hold messages: the open one's never reached the file.
    stored = stats.saved_messages if stats.error else stats.messages
    lost = f", and lost {stats.messages - stored} with the chunk that could not be written" if stored < stats.messages else ""
    print(
        f"recorded {stored} messages ({stats.file_bytes / 1e6:.1f} MB) from {', '.join(endpoints)} into {out}{lost}; "
        f"refused {sum(stats.refused.values())}{f' ({reasons})' if reasons else ''}, missed {stats.missed}"
        + (f", not stored {stats.not_stored} (still queued when the stop gave up storing them)"
           if stats.not_stored else ""),
        file=sys.stderr,
    )
    for endpoint, why in stats.never_connected.items():
        print(f"nothing recorded from {endpoint}, no handshake with it succeeded: {why}", file=sys.stderr)
    if args.json:
        print(json.dumps({"out": str(out), **stats.as_dict()}))
    if stats.error:
        # The last line: `teleop demo` shows it as the reason its session log is partial.
        print(
            f"{RECORDING_STOPPED}{stats.error}; the log is readable up to there: "
            f"`teleop recover {out} --out FIXED.mcap`",
            file=sys.stderr,
        )
        return RECORDING_STOPPED_STATUS
    return NEVER_CONNECTED_STATUS if stats.never_connected else 0


def _catalogue(args: argparse.Namespace) -> Path:
    """The catalogue to attach: the one the session's objects come from (``teleop demo`` and
    ``bench-latency`` start the recorder with their --scene alone), so export labels them by it."""
    if args.objects is not None:
        try:
            load_catalogue(args.objects)  # before the recording, not by its export
        except SettingsError as exc:
            raise SettingsError(f"--objects: {exc}") from exc
        return Path(args.objects)
    return load_scene(args.scene).catalogue_path if args.scene else default_catalogue_path()


def _record_until_stopped(recorder: SessionRecorder, duration_s: float | None) -> RecorderStats:
    """Run ``recorder`` until ``duration_s`` passed or Ctrl-C / SIGTERM / SIGHUP (its terminal closed;
    unless ignored, as under ``nohup``): each stops it, and the log gets its summary and footer."""
    stop = threading.Event()
    signals = (signal.SIGINT, signal.SIGTERM) + (() if hangup_ignored() else (signal.SIGHUP,))
    previous = {sig: signal.signal(sig, lambda *_: stop.set()) for sig in signals}
    try:
        return recorder.run(duration_s=duration_s, stop=stop, progress=True)
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
