"""``haptics devices``: list the softness displays plugged in over USB HID."""

from __future__ import annotations

import argparse
import json
import sys

from haptics.devices.hid import list_hid_displays
from haptics.settings import display_settings
from teleop.settings import load_settings

#: hidapi's keys reported for each device, in print order.
_KEYS = (
    "path", "vendor_id", "product_id", "serial_number", "manufacturer_string", "product_string",
    "release_number", "interface_number", "usage_page", "usage",
)


def _usb_id(text: str) -> int:
    try:
        value = int(text, 0)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not an integer (e.g. 0x1209)") from None
    if not 0 <= value <= 0xFFFF:
        raise argparse.ArgumentTypeError(f"{text!r} is outside 0x0000-0xFFFF")
    return value


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--settings", default=None,
        help="settings TOML whose [display] vendor_id and product_id are searched "
             "(default: the shipped configs/settings.toml)",
    )
    parser.add_argument("--vendor-id", type=_usb_id, default=None,
                        help="USB vendor ID to search, e.g. 0x1209 (overrides the settings)")
    parser.add_argument("--product-id", type=_usb_id, default=None,
                        help="USB product ID to search, e.g. 0x5EF7 (overrides the settings)")
    parser.add_argument("--json", action="store_true",
                        help="print one JSON object (the devices found) on stdout, the listing as text on stderr")


def _plain(value: object) -> object:
    return value.decode(errors="backslashreplace") if isinstance(value, bytes) else value


def run(args: argparse.Namespace) -> int:
    display = display_settings(load_settings(args.settings))
    vendor_id = display.vendor_id if args.vendor_id is None else args.vendor_id
    product_id = display.product_id if args.product_id is None else args.product_id
    found = [
        {key: _plain(d.get(key)) for key in _KEYS}
        for d in list_hid_displays(vendor_id, product_id)
    ]
    out = sys.stderr if args.json else sys.stdout  # with --json, stdout is the JSON alone
    if not found:
        print(
            f"no softness display {vendor_id:04X}:{product_id:04X} is plugged in "
            "(hid.enumerate found none: check the cable and, on Linux, read/write access "
            "to /dev/hidraw*)",
            file=out,
        )
    for d in found:
        print(
            f"{d['path']}  {d['vendor_id']:04X}:{d['product_id']:04X}  "
            f"serial {d['serial_number']!r}  "
            f"{d['manufacturer_string'] or '?'} / {d['product_string'] or '?'}  "
            f"usage page 0x{d['usage_page'] or 0:04X}",
            file=out,
        )
    if args.json:
        print(json.dumps({"vendor_id": vendor_id, "product_id": product_id, "count": len(found),
                          "devices": found}))
    return 0
