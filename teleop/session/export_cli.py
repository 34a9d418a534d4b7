"""``teleop export``: the grasps of a session log as .grasp records (for build-dataset)."""

from __future__ import annotations

import argparse
import json
import sys

from teleop.errors import ComplianceTeleopError
from teleop.session.export import export_session
from teleop.settings import load_settings


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.description = (
        "Write every complete grasp of a session log as a .grasp record named "
        "<log>_<session start>_<grasp id>.grasp, so sessions exported into one folder never "
        "share a name, and a grasp already in DIR from another log of the session (a log cut "
        "short, then recovered) is refused too. Untagged frames, force and width captured before "
        "a grasp's start are left out of it, and counted; stored messages the log reader refuses (corrupt, "
        "an unknown wire version) are counted, and records of grasps they may have belonged to flagged. Each record carries its sensors' calibration files and the gripper "
        "settings, so the folder can be moved or shared. Labels come from the log's label "
        "messages (`teleop label`, the operator's console), else from the object catalogue for "
        "grasps whose object the session named. Exits 1 when no record was written."
    )
    parser.add_argument("log", metavar="LOG", help="session log (.mcap) written by `teleop record`")
    parser.add_argument(
        "--out", required=True, metavar="DIR", help="directory for the .grasp records (created)"
    )
    parser.add_argument(
        "--overwrite",
        action="store_true",
        help="replace records of the same names already in DIR, and remove those of the same grasps "
        "exported from another log of the session (default: refuse, naming the files)",
    )
    parser.add_argument(
        "--settings",
        metavar="FILE",
        default=None,
        help="settings TOML whose sensors the records carry (default: the settings stored in the log)",
    )
    parser.add_argument(
        "--objects",
        metavar="PATH",
        default=None,
        help="object catalogue for labels (default: the catalogue stored in the log)",
    )
    parser.add_argument(
        "--source",
        choices=("simulated", "hardware"),
        default=None,
        help="provenance source of the records (default: what the log's session metadata says)",
    )
    parser.add_argument(
        "--json",
        action="store_true",
        help="print one JSON object on stdout: log, out, session_id, complete (nothing of the log is "
        "lost: not cut short or damaged, no message refused), refused ({reason: count}: stored messages "
        "refused), mendable (`teleop recover` would make a whole file of more of it), exported (count), records (paths written), written ([{grasp_id, path, object, "
        "modulus_pa, label_source, complete, refused}]: complete false when refused messages, received "
        "while the grasp was open, may have been its), unlabelled ([{grasp_id, path, reason}]: written without a "
        "modulus), skipped ([{grasp_id, reason}]: not written), dropped ([{grasp_id, stream, count}]: "
        "untagged messages captured before the grasp's start, left out), stray_labels, replaced (paths "
        "of the same grasps from another log, removed by --overwrite), error (null, or the message; an error "
        "that stops the export early leaves what it did not learn null)",
    )


def _recover_hint(log: str) -> str:
    return f"run `teleop recover {log} --out FIXED.mcap` first and export FIXED.mcap"


#: The keys of the --json object, in order; an error raised before anything is known (a log that does
#: not read, records already in DIR) leaves all but log, out and error null.
_JSON_KEYS = ("log", "out", "session_id", "complete", "refused", "mendable", "exported", "records", "written", "unlabelled",
              "skipped", "dropped", "stray_labels", "replaced", "error")


def _print_json(args: argparse.Namespace, error: str | None, **known: object) -> None:
    summary = dict.fromkeys(_JSON_KEYS)
    summary.update(log=args.log, out=args.out, **known, error=error)
    print(json.dumps(summary), flush=True)


def run(args: argparse.Namespace) -> int:
    try:
        settings = load_settings(args.settings) if args.settings else None
        results = export_session(
            args.log,
            args.out,
            settings=settings,
            catalogue=args.objects,
            source=args.source,
            overwrite=args.overwrite,
            progress=True,
        )
    except ComplianceTeleopError as exc:
        if args.json:  # the error line on stderr and exit status 2 stay run_cli's
            _print_json(args, str(exc))
        raise
    written = [r for r in results if r]
    skipped = [{"grasp_id": r.grasp_id, "reason": r.reason} for r in results if not r]
    unlabelled = [
        {"grasp_id": r.grasp_id, "path": str(r.path), "reason": r.unlabelled}
        for r in written
        if r.unlabelled
    ]
    reasons = ", ".join(f"{n} {reason}" for reason, n in sorted(results.refused.items()))
    refused = f"{sum(results.refused.values())} stored messages refused ({reasons})" if reasons else ""
    print(
        f"exported {len(written)} grasp records of session {results.session_id} into {args.out}; "
        f"{len(skipped)} grasps skipped, {len(unlabelled)} records without a modulus"
        + (f"; {refused}, {sum(1 for r in written if r.refused)} records may miss data" if refused else ""),
        file=sys.stderr,
    )
    for item in skipped:
        print(f"skipped grasp {item['grasp_id']}: {item['reason']}", file=sys.stderr)
    for r in written:
        if r.refused:
            print(f"incomplete grasp {r.grasp_id} ({r.path}): {r.refused} stored message(s) received while it "
                  "was open were refused; its record may miss data", file=sys.stderr)
    for item in unlabelled:
        print(f"no modulus for grasp {item['grasp_id']} ({item['path']}): {item['reason']}",
              file=sys.stderr)
    dropped = [{"grasp_id": r.grasp_id, "stream": stream, "count": count}
               for r in results for stream, count in r.dropped.items()]
    for item in dropped:
        print(f"dropped {item['count']} {item['stream']} message(s) of grasp {item['grasp_id']}: captured "
              "before the grasp's start without a grasp id (a camera or sensor that delivers late?)",
              file=sys.stderr)
    for other in results.replaced:
        print(f"removed {other}: the same grasp, exported from another log of the session (--overwrite)",
              file=sys.stderr)
    for line in results.stray_labels:
        print(f"unused label: {line}", file=sys.stderr)
    error = None
    if refused and not results.read:  # nothing to find grasps in: say why, not "no grasp_event"
        error = (f"no grasp record exported: no grasp event, frame, force or width message of {args.log} "
                 f"could be read: {refused}")
    elif not results.complete:
        lost = []
        if results.damage is not None or not refused:  # else the refusals alone make it incomplete
            lost.append(f"{args.log} is cut short or damaged ({results.damage})")
        if refused:
            lost.append(refused)
        cut = "; ".join(lost)
        recover = _recover_hint(args.log) if results.mendable else ""  # not for earlier losses or an attachment
        if written:
            print(f"note: {cut}; grasps in what is lost are skipped or flagged (above)"
                  + (f"; {recover}" if recover else ""), file=sys.stderr)
        else:
            error = f"no grasp record exported: {cut}" + (f"; {recover}" if recover else "")
    elif not written:
        error = (
            f"no grasp record exported: {args.log} holds no complete grasp"
            + (" (every grasp was skipped, above)" if skipped else " (no grasp_event start/end)")
        )
    if error:
        print(f"teleop export: error: {error}", file=sys.stderr)
    if args.json:
        _print_json(
            args,
            error,
            session_id=results.session_id,
            complete=results.complete,
            refused=results.refused,
            mendable=results.mendable,
            exported=len(written),
            records=[str(r.path) for r in written],
            written=[
                {
                    "grasp_id": r.grasp_id,
                    "path": str(r.path),
                    "object": r.record.label.object_name if r.record.label else None,
                    "modulus_pa": r.record.label.modulus_pa if r.record.label else None,
                    "label_source": r.record.label.source if r.record.label else None,
                    "complete": not r.refused,
                    "refused": r.refused,
                }
                for r in written
            ],
            unlabelled=unlabelled,
            skipped=skipped,
            dropped=dropped,
            stray_labels=results.stray_labels,
            replaced=[str(p) for p in results.replaced],
        )
    return 1 if error else 0
