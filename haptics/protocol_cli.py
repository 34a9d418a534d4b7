"""``haptics protocol``: print the HID report layouts and the report descriptor bytes."""

from __future__ import annotations

import argparse
import json
from dataclasses import asdict

from haptics.protocol import (
    DESCRIPTOR_ITEMS,
    LAYOUTS,
    PROTOCOL_VERSION,
    REPORT_DESCRIPTOR,
    USAGE_PAGE,
    layout_markdown,
)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--json", action="store_true",
                        help="print one JSON object (layouts and descriptor hex) on the last line")


def run(args: argparse.Namespace) -> int:
    print(f"softness display HID protocol, version {PROTOCOL_VERSION}, "
          f"usage page 0x{USAGE_PAGE:04X}")
    print("multi-byte fields are little-endian; sizes include the report ID byte\n")
    for layout in LAYOUTS:
        print(f"{layout.kind.upper()} report 0x{layout.report_id:02X}: {layout.name} "
              f"({layout.size} bytes)")
        print(layout_markdown(layout), end="\n\n")
    print(f"report descriptor ({len(REPORT_DESCRIPTOR)} bytes): {REPORT_DESCRIPTOR.hex(' ')}")
    for item, meaning in DESCRIPTOR_ITEMS:
        print(f"  {item.hex(' '):<10} {meaning}")
    if args.json:
        reports = [
            {"name": layout.name, "kind": layout.kind, "report_id": layout.report_id,
             "size": layout.size,
             "fields": [{"offset": offset, "size": size, **asdict(f)}
                        for offset, size, f in layout.offsets()]}
            for layout in LAYOUTS
        ]
        print(json.dumps({"protocol_version": PROTOCOL_VERSION, "usage_page": USAGE_PAGE,
                          "reports": reports, "descriptor_hex": REPORT_DESCRIPTOR.hex()}))
    return 0
