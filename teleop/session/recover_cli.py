"""``teleop recover``: every complete message of a log cut short or damaged, salvaged into a complete
file; exit status 1, and no ``--out`` file, when there was none to salvage."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from teleop.clikit import output_file
from teleop.errors import SessionLogError
from teleop.session.recordfile import held_by, refuse_if_held, rewriting
from teleop.session.recover import RecoveryReport, check_not_source, recover


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "log", metavar="LOG", help="session log (.mcap), e.g. one a killed recorder left"
    )
    parser.add_argument(
        "--out", required=True, metavar="FIXED.mcap", help="complete MCAP file to write"
    )
    parser.add_argument(
        "--overwrite", action="store_true", help="replace --out if it exists instead of refusing"
    )
    parser.add_argument(
        "--json",
        action="store_true",
        help="print one JSON object (source, out, complete, closed_cleanly, damage, damaged, "
        "cut_short, messages, "
        "topics, undecodable, dropped, rebuilt_channels, attachments, damaged_attachments, metadata, salvaged_bytes, "
        "source_bytes, trailing_bytes, lost) as the last stdout line",
    )


def run(args: argparse.Namespace) -> int:
    out = output_file("--out", args.out)
    check_not_source(Path(args.log), out)
    if out.exists() and not args.overwrite:
        raise SessionLogError(f"--out {out} exists: choose another name or pass --overwrite")
    refuse_if_held(out, "write the recovered log elsewhere")
    if (pid := held_by(args.log)) is not None:
        print(f"warning: {args.log} is held by another process{f' (PID {pid})' if pid else ''}, a recorder "
              "still writing it or `teleop label` rewriting it: what is salvaged is what the log holds now",
              file=sys.stderr)
    # Staged beside --out: a recovery that salvages nothing must not replace a file already there.
    staged = out.with_name(f".{out.name}.recovering")
    try:
        report = recover(args.log, staged, progress=True)
    except SessionLogError as exc:  # the staged name is this command's detail: say the --out asked for
        raise SessionLogError(str(exc).replace(str(staged), str(out))) from exc
    if report.messages == 0 and not report.complete:
        staged.unlink(missing_ok=True)
    else:
        try:
            # A recorder or a rewrite (`teleop label`) that took --out meanwhile keeps it.
            with rewriting(out, "write the recovered log elsewhere"):
                staged.replace(out)
        except SessionLogError:
            staged.unlink(missing_ok=True)
            raise
    report.out = str(out)
    print(
        f"{args.log}: {_state(report)}; salvaged {report.messages} messages, "
        f"{len(report.attachments)} attachments, read to byte {report.salvaged_bytes} of "
        f"{report.source_bytes}" + (" past the damage" if report.damaged else "") + f", into {args.out}",
        file=sys.stderr,
    )
    if report.damaged_attachments:
        print(
            f"damaged attachments copied as they are, with their stored CRC-32 (so readers of "
            f"{args.out} see the damage too): {', '.join(report.damaged_attachments)}",
            file=sys.stderr,
        )
    if report.rebuilt_channels:
        print(
            f"channels rebuilt from their messages (their records were lost with the damage): "
            f"{', '.join(report.rebuilt_channels)}",
            file=sys.stderr,
        )
    if report.undecodable:
        print(
            f"{report.undecodable} salvaged messages are not valid bus messages "
            "(kept verbatim; readers skip them)",
            file=sys.stderr,
        )
    if report.dropped:
        print(
            f"{report.dropped} messages dropped: their channel's record was lost with the damage and "
            "they are neither bus messages nor the Foxglove forms of one",
            file=sys.stderr,
        )
    if args.json:
        print(json.dumps(report.as_dict()))
    if report.messages == 0 and not report.complete:
        why = (
            "no message of the log could be read (see the damage above)"
            if report.damaged
            else "the log is cut short before its first message"
        )
        print(f"{args.log}: nothing salvaged: {why}; {args.out} not written", file=sys.stderr)
        return 1
    return 0


def _state(report: RecoveryReport) -> str:
    """The source's state, as what happened: complete, damaged, cut short (and where)."""
    if report.complete and report.trailing_bytes:
        return (f"complete up to its footer at byte {report.source_bytes - report.trailing_bytes}, but "
                f"{report.trailing_bytes} bytes of trailing data follow it, not read (another writer's: "
                "two recorders on one file?)" + (f"; {report.damage}" if report.damage else ""))
    if report.complete:  # a recovered log's earlier losses are still lost
        return "complete" + (f" (though {report.damage})" if report.damage else "")
    said = [word for word, yes in (("damaged", report.damaged), ("cut short", report.cut_short)) if yes]
    return f"{' and '.join(said) or 'incomplete'} ({report.damage})"
