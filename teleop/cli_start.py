"""How the console scripts (``teleop``, ``estimator``, ``haptics``) start: this module imports
nothing but ``sys``, so a Ctrl-C while the command-line framework (:mod:`teleop.clikit`) and the
command table import says so in one line, not with a traceback."""

from __future__ import annotations

import sys
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from collections.abc import Callable, Mapping, Sequence

    from teleop.clikit import Command

__all__ = ["start"]


def start(prog: str, doc: str | None, commands: Callable[[], Mapping[str, Command]],
          argv: Sequence[str] | None) -> int:
    """Run ``prog`` (its ``doc``, the table ``commands()`` makes) on ``argv`` with
    :func:`~teleop.clikit.run_cli`; 130 after a Ctrl-C while these import."""
    try:
        from teleop.clikit import run_cli

        table = commands()
    except KeyboardInterrupt:
        print(f"{prog}: interrupted", file=sys.stderr)
        return 130
    return run_cli(prog, doc, table, argv)
