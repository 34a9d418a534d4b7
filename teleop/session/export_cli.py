"""``teleop export``: the grasps of a session log as .grasp records (for build-dataset)."""

from __future__ import annotations

import argparse
import json
import sys

from teleop.session.export import export_session
from teleop.settings import load_settings


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("log", metavar="LOG", help="session log (.mcap) written by `teleop record`")
    parser.add_argument(
        "--out", required=True, metavar="DIR", help="directory for the .grasp records (created)"
    )
    parser.add_argument(
        "--settings",
        metavar="FILE",
        default=None,
        help="settings TOML whose sensors the records carry; None: the settings stored in the log",
    )
    parser.add_argument(
        "--objects",
        metavar="PATH",
        default=None,
        help="object catalogue for labels; None: the catalogue stored in the log",
    )
    parser.add_argument(
        "--source",
        choices=("simulated", "hardware"),
        default=None,
        help="provenance source of the records; None: what the log's session metadata says",
    )
    parser.add_argument(
        "--json",
        action="store_true",
        help="print one JSON object (log, out, exported, skipped: [{grasp_id, reason}], "
        "records: [paths]) as the last stdout line",
    )


def run(args: argparse.Namespace) -> int:
    settings = load_settings(args.settings) if args.settings else None
    results = export_session(
        args.log,
        args.out,
        settings=settings,
        catalogue=args.objects,
        source=args.source,
        progress=True,
    )
    written = [str(r.path) for r in results if r]
    skipped = [{"grasp_id": r.grasp_id, "reason": r.reason} for r in results if not r]
    print(
        f"exported {len(written)} grasp records into {args.out}; {len(skipped)} grasps skipped",
        file=sys.stderr,
    )
    for item in skipped:
        print(f"skipped grasp {item['grasp_id']}: {item['reason']}", file=sys.stderr)
    if args.json:
        print(
            json.dumps(
                {
                    "log": args.log,
                    "out": args.out,
                    "exported": len(written),
                    "skipped": skipped,
                    "records": written,
                }
            )
        )
    return 0
