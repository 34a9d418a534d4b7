"""``haptics protocol``: print the HID report layouts and the report descriptor bytes."""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import asdict

from haptics.protocol import (
    DESCRIPTOR_ITEMS,
    LAYOUTS,
    PROTOCOL_VERSION,
    PROTOCOL_VERSIONS,
    REPORT_DESCRIPTOR,
    USAGE_PAGE,
    layout_markdown,
    report_descriptor,
)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--json", action="store_true",
                        help="print one JSON object (layouts and descriptor hex) on stdout, the layouts as text on stderr")


def run(args: argparse.Namespace) -> int:
    out = sys.stderr if args.json else sys.stdout  # with --json, stdout is the JSON alone
    versions = " and ".join(str(v) for v in PROTOCOL_VERSIONS)
    print(f"softness display HID protocol, version {PROTOCOL_VERSION} (this host speaks "
          f"versions {versions}; a display states its own in the FEATURE report), "
          f"usage page 0x{USAGE_PAGE:04X}", file=out)
    print("multi-byte fields are little-endian; sizes include the report ID byte\n", file=out)
    for layout in LAYOUTS:
        since = f", version {layout.version} and later" if layout.version > 1 else ""
        print(f"{layout.kind.upper()} report 0x{layout.report_id:02X}: {layout.name} "
              f"({layout.size} bytes{since})", file=out)
        print(layout_markdown(layout), end="\n\n", file=out)
    print(f"report descriptor, version {PROTOCOL_VERSION} ({len(REPORT_DESCRIPTOR)} bytes): "
          f"{REPORT_DESCRIPTOR.hex(' ')}", file=out)
    for item, meaning in DESCRIPTOR_ITEMS:
        print(f"  {item.hex(' '):<10} {meaning}", file=out)
    descriptors = {version: report_descriptor(version) for version in PROTOCOL_VERSIONS}
    for version, descriptor in descriptors.items():
        if version != PROTOCOL_VERSION:
            print(f"report descriptor, version {version} ({len(descriptor)} bytes): "
                  f"{descriptor.hex(' ')}", file=out)
    if args.json:
        reports = [
            {"name": layout.name, "kind": layout.kind, "report_id": layout.report_id,
             "size": layout.size, "since_version": layout.version,
             "fields": [{"offset": offset, "size": size, **asdict(f)}
                        for offset, size, f in layout.offsets()]}
            for layout in LAYOUTS
        ]
        print(json.dumps({"protocol_version": PROTOCOL_VERSION,
                          "protocol_versions": list(PROTOCOL_VERSIONS), "usage_page": USAGE_PAGE,
                          "reports": reports, "descriptor_hex": REPORT_DESCRIPTOR.hex(),
                          "descriptors_hex": {str(v): d.hex() for v, d in descriptors.items()}}))
    return 0
