"""How the console scripts (``teleop``, ``estimator``, ``haptics``) start: this module imports
nothing but what the interpreter has loaded before it (``sys``, ``os``), so a Ctrl-C while
the command-line framework (:mod:`teleop.clikit`) and the command table import says so in one line,
not with a traceback.

Before anything else, each closed standard stream (``2>&-``) is opened on the null device: else the
next file opened (a session log) would take its file descriptor and receive what is written to standard
error, by this process and by the child processes it starts."""

from __future__ import annotations

import os
import sys
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from collections.abc import Callable, Mapping, Sequence

    from teleop.clikit import Command

__all__ = ["start"]


def _open_closed_standard_fds() -> None:
    """Open each of file descriptors 0, 1 and 2 that is closed on the null device, and give the
    ``sys`` stream the interpreter left None for it one on that device."""
    for fd, name, mode in ((0, "stdin", "r"), (1, "stdout", "w"), (2, "stderr", "w")):
        try:
            os.fstat(fd)
        except OSError:
            opened = os.open(os.devnull, os.O_RDWR)  # the lowest free descriptor: fd itself, those below being open
            if opened != fd:
                os.dup2(opened, fd)
                os.close(opened)
            os.set_inheritable(fd, True)  # as a standard stream is: child processes write there too
        if getattr(sys, name) is None:
            # Nothing is read or seen there: any encoding does.
            stream = open(fd, mode, encoding="utf-8", errors="backslashreplace", closefd=False)  # noqa: SIM115
            setattr(sys, name, stream)
            setattr(sys, f"__{name}__", stream)


def start(prog: str, doc: str | None, commands: Callable[[], Mapping[str, Command]],
          argv: Sequence[str] | None) -> int:
    """Run ``prog`` (its ``doc``, the table ``commands()`` makes) on ``argv`` with
    :func:`~teleop.clikit.run_cli`; 130 after a Ctrl-C while these import. Closed standard streams
    are opened on the null device first."""
    _open_closed_standard_fds()
    try:
        from teleop.clikit import run_cli

        table = commands()
    except KeyboardInterrupt:
        print(f"{prog}: interrupted", file=sys.stderr)
        return 130
    return run_cli(prog, doc, table, argv)
