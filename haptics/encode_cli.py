"""``haptics encode``: print the OUTPUT (set stiffness) report for given fields, in hex.

For driving a display by hand, e.g. with ``hidapitester`` or a firmware test bench.
"""

from __future__ import annotations

import argparse
import json
import sys

from haptics.errors import ProtocolError
from haptics.protocol import (
    FLAG_BITS,
    PROTOCOL_VERSION,
    PROTOCOL_VERSIONS,
    StiffnessCommand,
    encode_output_report,
)


def _integer(text: str) -> int:
    """Decimal or, as PROTOCOL.md writes the report's bytes, hexadecimal (0x1234)."""
    try:
        return int(text, 0)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: expected an integer, decimal or 0x hexadecimal") from None


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--level", type=_integer, required=True,
                        help="stiffness level, 0 (free) to the display's level_max (<= 65535)")
    parser.add_argument("--uncertainty", type=_integer, default=0,
                        help="interval width in counts of 1/20 decade of E, 0-255")
    parser.add_argument("--sequence", type=_integer, default=0, help="sequence number, 0-255")
    parser.add_argument("--protocol-version", type=int, choices=PROTOCOL_VERSIONS,
                        default=PROTOCOL_VERSION,
                        help="the display's protocol version (its FEATURE report says it), "
                             f"carried in the report's second byte (default {PROTOCOL_VERSION})")
    for flag in FLAG_BITS:
        parser.add_argument(f"--{flag}", action="store_true", help=f"set the {flag} flag "
                            f"(bit {FLAG_BITS[flag]} of the flags byte)")
    parser.add_argument("--json", action="store_true",
                        help="print one JSON object (the report's hex and fields) on stdout, the spaced hex on stderr")


#: Each integer option and its largest value (the report's field widths).
_RANGES = {"level": 0xFFFF, "uncertainty": 255, "sequence": 255}


def run(args: argparse.Namespace) -> int:
    for name, high in _RANGES.items():
        value = getattr(args, name)
        if not 0 <= value <= high:
            raise ProtocolError(f"--{name} {value}: expected an integer in [0, {high}]")
    command = StiffnessCommand(
        level=args.level,
        uncertainty=args.uncertainty,
        **{flag: getattr(args, flag) for flag in FLAG_BITS},
    )
    report = encode_output_report(command, sequence=args.sequence, version=args.protocol_version)
    print(report.hex(" "), file=sys.stderr if args.json else sys.stdout)  # with --json, stdout is the JSON alone
    if args.json:
        print(json.dumps({"report_hex": report.hex(), "length": len(report), "level": command.level,
                          "uncertainty": command.uncertainty, "flags": command.flags,
                          "sequence": args.sequence, "protocol_version": args.protocol_version}))
    return 0
