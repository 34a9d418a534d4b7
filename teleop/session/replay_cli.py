"""``teleop replay``: publish a recorded session back onto the bus, at recorded or faster speed."""

from __future__ import annotations

import argparse
import json
import sys
import time

from teleop.bus.pubsub import Publisher
from teleop.errors import BusAddressInUseError, BusTimeoutError, SessionLogError
from teleop.session.logfile import LogReader
from teleop.session.replay import ReplayStats, replay
from teleop.settings import load_settings

MIN_SPEED = 1e-3  # --speed: a thousand times slower than recorded at most
MAX_WAIT_S = 86400.0  # --wait-subscriber-s: a day
MAX_LINGER_S = 3600.0  # --linger-s: an hour


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("log", metavar="LOG", help="session log (.mcap) written by `teleop record`")
    pace = parser.add_mutually_exclusive_group()
    pace.add_argument(
        "--speed",
        type=float,
        default=1.0,
        metavar="X",
        help=f"replay X times as fast as recorded (paced by the receive times; X >= {MIN_SPEED:g})",
    )
    pace.add_argument(
        "--as-fast-as-possible",
        action="store_true",
        help="send without pacing (a slow subscriber still holds the replay back: "
        "nothing is dropped)",
    )
    parser.add_argument(
        "--endpoint",
        default=None,
        metavar="ENDPOINT",
        help="endpoint to bind and publish on (e.g. tcp://127.0.0.1:5560 when the default one is in use); "
        "default: the settings' bus.robot_pub",
    )
    parser.add_argument(
        "--settings",
        metavar="FILE",
        default=None,
        help="settings TOML for the default endpoint, message size limit, heartbeat and bus keys; "
        "default: the shipped one",
    )
    parser.add_argument(
        "--topics",
        nargs="+",
        default=None,
        metavar="PREFIX",
        help="replay only topics starting with these prefixes (e.g. frame force width "
        "grasp_event); default: all but heartbeats",
    )
    parser.add_argument(
        "--recorded-from",
        nargs="+",
        default=None,
        metavar="NAME",
        help="replay only messages recorded from these publishers (robot: what `teleop node` sent; "
        "estimator, renderer, ...): `--recorded-from robot` onto a running `estimator serve` "
        "estimates a session's grasps again, without its recorded estimates and grasp ends; "
        "default: every publisher",
    )
    parser.add_argument(
        "--source",
        default="replay",
        metavar="NAME",
        help="node name in the replayed messages' headers",
    )
    parser.add_argument(
        "--wait-subscriber-s",
        type=float,
        default=5.0,
        metavar="S",
        help=f"wait up to S seconds (at most {MAX_WAIT_S:g}) for a bus subscriber to connect before "
        "sending; none within S seconds is an error (nothing is sent). 0: do not wait, replay even to "
        "nobody",
    )
    parser.add_argument(
        "--linger-s",
        type=float,
        default=1.0,
        metavar="S",
        help=f"keep the endpoint open S seconds (at most {MAX_LINGER_S:g}) after the last message, so "
        "queued messages reach slow subscribers before it closes",
    )
    parser.add_argument(
        "--json",
        action="store_true",
        help="print one JSON object (log, endpoint, sent, topics, heartbeats_skipped, other_sources, "
        "refused, log_span_s, wall_s, damage, stopped) as the last stdout line",
    )


def run(args: argparse.Namespace) -> int:
    if not args.as_fast_as_possible and not args.speed >= MIN_SPEED:
        raise SessionLogError(
            f"--speed {args.speed}: expected a number >= {MIN_SPEED:g} (slower would take "
            "thousands of times the recording's length)"
        )
    for option, value, most in (
        ("--linger-s", args.linger_s, MAX_LINGER_S),
        ("--wait-subscriber-s", args.wait_subscriber_s, MAX_WAIT_S),
    ):
        if not 0 <= value <= most:
            raise SessionLogError(f"{option} {value}: expected a number >= 0 (seconds, at most {most:g})")
    settings = load_settings(args.settings)
    LogReader(args.log).info()  # a missing or unreadable log is named before the bus is set up
    endpoint = args.endpoint or settings.bus.robot_pub
    # the settings' size limit, heartbeat period and CURVE keys
    try:
        publisher = Publisher.from_settings(settings.bus, endpoint, lossless=True, source=args.source)
    except BusAddressInUseError as exc:
        raise BusAddressInUseError(
            f"{exc}; or replay on another endpoint with --endpoint (default: the settings' bus.robot_pub)"
        ) from exc
    with publisher:
        if args.wait_subscriber_s > 0:  # every bus Subscriber subscribes to heartbeats, whatever else it wants
            try:
                publisher.wait_for_subscriber("heartbeat", timeout_s=args.wait_subscriber_s)
            except BusTimeoutError as exc:
                raise BusTimeoutError(
                    f"--wait-subscriber-s {args.wait_subscriber_s:g}: no subscriber connected to "
                    f"{publisher.endpoint} within {args.wait_subscriber_s:g} s; start one, or pass "
                    "--wait-subscriber-s 0 to replay to nobody"
                ) from exc
        stats = replay(
            args.log,
            publisher,
            speed=None if args.as_fast_as_possible else args.speed,
            topics=args.topics,
            recorded_from=args.recorded_from,
            progress=True,
        )
        endpoint = publisher.endpoint
        # Publisher.close() discards what is still queued: give subscribers time to take it.
        deadline = time.monotonic() + args.linger_s
        while (remaining := deadline - time.monotonic()) > 0:
            time.sleep(min(remaining, publisher.heartbeat_s))
            publisher.heartbeat_if_due()
    print(
        f"replayed {stats.sent} messages ({stats.log_span_s:.2f} s recorded) "
        f"in {stats.wall_s:.2f} s on {endpoint}; refused {sum(stats.refused.values())}"
        + (f"; left out {sum(stats.other_sources.values())} from other publishers "
           f"({', '.join(f'{n} from {name}' for name, n in sorted(stats.other_sources.items()))})"
           if stats.other_sources else ""),
        file=sys.stderr,
    )
    if stats.damage:
        said = "the log stops early" if stats.stopped else "the log is damaged; replay read on past it"
        print(f"{said}: {stats.damage}", file=sys.stderr)
    if args.json:
        print(json.dumps({"log": args.log, "endpoint": endpoint, **stats.as_dict()}))
    if stats.sent == 0:
        print(f"nothing replayed: {_why_nothing(args, stats)}", file=sys.stderr)
        return 1
    return 0


def _why_nothing(args: argparse.Namespace, stats: ReplayStats) -> str:
    """Why a replay sent nothing, as what happened."""
    filtered = args.topics is not None or args.recorded_from is not None
    if filtered and (stats.other_sources or not stats.damage):  # a typo, most likely
        return "no message of the log matches --recorded-from and --topics"
    refused = sum(stats.refused.values())
    if refused or stats.heartbeats_skipped:
        return (
            f"the log holds no readable message to replay ({refused} stored messages do not decode, "
            f"{stats.heartbeats_skipped} heartbeats are never replayed)"
        )
    where = f" ({stats.damage})" if stats.damage else ""
    return f"the log holds no readable message{where}"
