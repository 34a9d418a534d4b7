"""``haptics``: the operator's side: softness display (mapping, HID protocol, devices), console."""

from __future__ import annotations

import sys
from typing import TYPE_CHECKING

from teleop.cli_start import start

if TYPE_CHECKING:
    from collections.abc import Sequence

    from teleop.clikit import Command

# Nothing else is imported here: the console script imports this module before main() runs, and a
# Ctrl-C meanwhile would end in a traceback. teleop.clikit is imported by start(), under its guard.


def commands() -> dict[str, Command]:
    """The ``haptics`` subcommands, by name (each one's module imported only when it runs)."""
    from teleop.clikit import Command

    return {
        "devices": Command("haptics.devices_cli", "list the softness displays plugged in over USB HID"),
        "protocol": Command("haptics.protocol_cli", "print the HID report layouts and descriptor"),
        "encode": Command("haptics.encode_cli", "print a set-stiffness output report in hex"),
        "try": Command("haptics.try_cli", "map one modulus and write it to a display"),
        "serve": Command("haptics.service_cli", "render live estimates from the bus on the softness display"),
        "operate": Command("haptics.operate_cli", "the operator console: drive the gripper (a grasp at a chosen force, "
                                                  "or following the grip while the enable is held) and watch the "
                                                  "force, the live estimate and the display"),
    }


def main(argv: Sequence[str] | None = None) -> int:
    return start("haptics", __doc__, commands, argv)


if __name__ == "__main__":  # `python -m haptics.cli`, as the console script runs main()
    sys.exit(main())
