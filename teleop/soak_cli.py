"""``teleop soak``: a bounded soak test of the grasp data path on loopback (:mod:`teleop.soak`).

``--json`` prints the :class:`~teleop.soak.SoakResult` as one object on the last stdout line;
the exit status is 1 when a grasp message was lost or the recorder failed. SIGTERM stops it as
Ctrl-C does: the consumer process is stopped and the temporary log removed.
"""

from __future__ import annotations

import argparse
import json
import math
import sys

from teleop.errors import SettingsError
from teleop.settings import default_settings_path, load_settings
from teleop.soak import MAX_DEFAULT_WARMUP_S, MIN_DURATION_S, check_log_path, run_soak

MIN_MINUTES = MIN_DURATION_S / 60.0  # --minutes: every topic sends at least once


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.description = (
        "Soak the grasp data path on loopback: publish two 30 Hz JPEG tactile streams, force at 80 Hz and "
        "width at 10 Hz through the lossless publisher into a session recorder in another process for the "
        "time given, then report lost grasp messages (must be 0), the recorder's memory growth after the "
        "warm-up and the send-to-receive latency."
    )
    parser.add_argument("--minutes", type=float, required=True, metavar="M",
                        help="how long to publish, in minutes (e.g. 0.05 for a 3 s check, 10 for a soak; at "
                             f"least {MIN_MINUTES:.2g}, {MIN_DURATION_S:g} s)")
    parser.add_argument("--warmup-s", type=float, default=None, metavar="S",
                        help="seconds after the consumer starts at which its memory is first taken "
                             f"(default: a fifth of the run, at most {MAX_DEFAULT_WARMUP_S:g} s)")
    parser.add_argument("--settings", metavar="FILE", default=str(default_settings_path()),
                        help="settings TOML (sensors for the frames, bus size limit)")
    parser.add_argument("--log", metavar="FILE", default=None,
                        help="keep the session log here (default: a temporary file, deleted at the end)")
    parser.add_argument("--json", action="store_true",
                        help="print one JSON object (lost_grasp_msgs, rss_growth_mb, p50_ms, p99_ms, ...) as "
                             "the last stdout line")


def run(args: argparse.Namespace) -> int:
    if not (math.isfinite(args.minutes) and args.minutes >= MIN_MINUTES):
        finite = "" if math.isfinite(args.minutes) else "a finite number of "
        raise SettingsError(f"--minutes {args.minutes:g}: expected {finite}at least {MIN_MINUTES:.2g} "
                            f"({MIN_DURATION_S:g} s)")
    if args.log is not None:
        check_log_path(args.log, name="--log")  # here, not as a traceback of the consumer process
    settings = load_settings(args.settings)
    result = run_soak(settings, duration_s=args.minutes * 60.0, warmup_s=args.warmup_s,
                      settings_path=args.settings, log_path=args.log, progress=True)
    print(f"soak: {result.duration_s:.0f} s, {sum(result.sent.values())} grasp messages sent, "
          f"{result.lost_grasp_msgs} lost; latency p50 {result.p50_ms} ms, p99 {result.p99_ms} ms; "
          f"recorder memory {result.rss_warm_mb:.1f} MB after warm-up, {result.rss_end_mb:.1f} MB at the end "
          f"({result.rss_growth_mb:+.2f} MB)", file=sys.stderr)
    if args.json:
        print(json.dumps(result.as_dict()))
    return 0 if result.lost_grasp_msgs == 0 and result.recorder_error is None else 1
